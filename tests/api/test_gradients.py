"""Gradients of `jaxpose.solve` (in its batch-first form `solve_many`): exact (implicit
function theorem at the Eq. 8 optimum), forward and reverse mode alike, and never NaN.

The reference is a five-point central difference of the WHOLE solve (every problem
re-solved from scratch at each of the four perturbed inputs, triplet choice and all),
along a random direction of the joint input (intrinsics `k = (fx, fy, cx, cy)`, the
extrinsic part `E` of the camera `C = K(k) E`, model points, image points), and per
input group on a subset. The relative error of a directional derivative is the max-norm
of the difference over the max-norm of the derivative, separately for the rotation block
(`R`, 9 entries) and the translation block (`t`, 3 entries): tiny entries are judged at
the scale of their block, not on their own.

One compiled function per method and dtype (`_evaluator`: `solve_many`, its outputs
and their Jacobians) serves every test (float32: without the fallback, see
`test_float32_gradients_are_finite_and_close_to_float64`), for the Jacobians and for the
re-solves alike: problems are padded to `N_MAX` matches with a mask (n = 4 to 7) and
evaluated in chunks of `CHUNK` problems. (`vmap(solve)` gives the same answers and
derivatives, computed one problem at a time: `test_api.py`, `test_fuzz.py`.)
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.flatten_util import ravel_pytree

import jaxpose as jp

N_MAX = 7
COUNTS = (4, 5, 6, 7)
CHUNK = 64
STEP = 0.0025  # along directions that move the reprojections by ~1 px per unit
POSE = slice(0, 12)  # rows of the output vector: R.ravel(), t
ROT, TRANS = slice(0, 9), slice(9, 12)


class Batch(NamedTuple):
    k: np.ndarray  # (B, 4): fx, fy, cx, cy
    E: np.ndarray  # (B, 3, 4): C = K(k) E
    M: np.ndarray  # (B, N_MAX, 3)
    I: np.ndarray  # (B, N_MAX, 2)
    mask: np.ndarray  # (B, N_MAX)


def _K(k):
    z, o = jnp.zeros_like(k[0]), jnp.ones_like(k[0])
    return jnp.stack([jnp.stack([k[0], z, k[2]]), jnp.stack([z, k[1], k[3]]), jnp.stack([z, z, o])])


def _pad(x, n):
    return np.concatenate([x, np.repeat(x[:1], n - len(x), axis=0)], axis=0)


def make_batch(seed: int, size: int, *, noise=(0.1, 1.0), kinds=("ordinary", "planar")):
    """`size` random problems (`random_scene`, focal 500-1500 px, noisy), n cycling
    through COUNTS, padded to N_MAX."""
    rng = np.random.default_rng(seed)
    ks, Es, Ms, Is, masks = [], [], [], [], []
    for i in range(size):
        n = COUNTS[i % len(COUNTS)]
        focal = rng.uniform(500, 1500)
        kind = kinds[i % len(kinds)]
        s = jp.apps.random_scene(rng, n, noise=rng.uniform(*noise), focal=focal, kind=kind)
        k = np.array([focal, focal, 320.0, 240.0])
        ks.append(k)
        Es.append(np.linalg.solve(np.asarray(_K(k)), s.camera))
        Ms.append(_pad(s.model_points, N_MAX))
        Is.append(_pad(s.image_points, N_MAX))
        masks.append(np.arange(N_MAX) < n)
    return Batch(*(np.stack(x) for x in (ks, Es, Ms, Is, masks)))


def directions(batch: Batch, seed: int, groups=("k", "E", "M", "I")) -> Batch:
    """Random directions in `groups` (zero elsewhere), each scaled to move the
    reprojections by about 1 px per unit step."""
    rng = np.random.default_rng(seed)
    B = batch.k.shape[0]
    f = batch.k[:, :1]
    depth = 6.0  # random_scene's points lie 4-8 units in front of the camera
    m = batch.mask.astype(float)[..., None]
    d = {
        "k": rng.normal(size=(B, 4)) * np.concatenate([f / 500, f / 500, np.ones((B, 2))], 1),
        "E": rng.normal(size=(B, 3, 4)) * np.array([1, 1, 1, depth]) / f[:, :, None] * 0.5,
        "M": rng.normal(size=batch.M.shape) * depth / f[:, :, None] * m,
        "I": rng.normal(size=batch.I.shape) * m,
    }
    d = {name: v if name in groups else np.zeros_like(v) for name, v in d.items()}
    return Batch(**d, mask=batch.mask)


def _vector(sol):
    """(R.ravel(), t, rotvec(R), error, pose_error) of one Solution: 17 values."""
    rv = jp.matrix_to_rotvec(sol.pose.R)
    extra = jnp.stack([sol.error, sol.pose_error])
    return jnp.concatenate([sol.pose.R.ravel(), sol.pose.t, rv, extra])


GROUPS = {"k": slice(0, 4), "E": slice(4, 16), "M": slice(16, 37), "I": slice(37, 51)}


def _solve_batch(method, k, E, M, I, mask, fallback=True):
    """`solve_many` of a batch given as `(k, E, M, I, mask)`, and `_vector` of each
    answer."""
    sol = jp.solve_many(jax.vmap(_K)(k) @ E, M, I, mask, method=method, fallback=fallback)
    return jax.vmap(_vector)(sol), sol


@functools.cache
def _evaluator(method: str, fallback: bool = True):
    """Compiled `(k, E, M, I, mask) -> (outputs (B, 17), Solution, J_fwd, J_rev)` of a
    batch: the Jacobians (B, 17, 51) of each problem's outputs w.r.t. its flattened
    `(k, E, M, I)` (columns in `GROUPS`), in forward mode (`jvp` of every input direction,
    as `jax.jacfwd`) and in reverse mode (its transpose, `vjp` of every output, as
    `jax.jacrev`), from one linearisation of the batch-first `solve_many`, so that the
    solver is traced and compiled once. The problems are independent (the batch's
    Jacobian is block-diagonal): one direction given to every problem at once gives each
    problem's column."""

    def many(k, E, M, I, mask):
        x = jax.vmap(lambda *a: ravel_pytree(a)[0])(k, E, M, I)  # (B, 51)
        _, unravel = ravel_pytree((k[0], E[0], M[0], I[0]))
        y, f_jvp, sol = jax.linearize(
            lambda x: _solve_batch(method, *jax.vmap(unravel)(x), mask, fallback),
            x,
            has_aux=True,
        )
        f_vjp = jax.linear_transpose(f_jvp, x)
        fwd = jax.vmap(lambda e: f_jvp(jnp.broadcast_to(e, x.shape)), out_axes=2)(
            jnp.eye(x.shape[1], dtype=x.dtype)
        )
        rev = jax.vmap(lambda c: f_vjp(jnp.broadcast_to(c, y.shape))[0], out_axes=1)(
            jnp.eye(y.shape[1], dtype=y.dtype)
        )
        return y, sol, fwd, rev

    return jax.jit(many)


def evaluate(method: str, batch: Batch, fallback: bool = True):
    """`_evaluator(method, fallback)` over `batch` in chunks of CHUNK problems (padded by
    repetition, so that every call has the same shapes and reuses one compilation)."""
    B = batch.k.shape[0]
    size = -(-B // CHUNK) * CHUNK
    padded = [np.concatenate([x, np.repeat(x[:1], size - B, axis=0)]) for x in batch]
    fn = _evaluator(method, fallback)
    parts = [fn(*(jnp.asarray(x[i : i + CHUNK]) for x in padded)) for i in range(0, size, CHUNK)]
    return jax.tree.map(lambda *xs: np.concatenate([np.asarray(x) for x in xs])[:B], *parts)


def _flat(d: Batch):
    B = d.k.shape[0]
    return np.concatenate([x.reshape(B, -1) for x in d[:4]], axis=1)


def _contract(J, d: Batch):
    """Directional derivatives `J . d`, (B, 17)."""
    return np.einsum("bij,bj->bi", J, _flat(d))


def _shift(batch: Batch, d: Batch, h: float) -> Batch:
    return Batch(*(x + h * dx for x, dx in zip(batch[:4], d[:4], strict=True)), batch.mask)


def _relative(a, b, axes):
    """max|a - b| / max|b| over `axes` (b the reference)."""
    scale = np.max(np.abs(b), axis=axes)
    return np.max(np.abs(a - b), axis=axes) / np.maximum(scale, np.finfo(float).tiny)


def central_difference_errors(method, batch, d, h=STEP, base=None):
    """Five-point central difference of the full solve along `d`, against `J . d`.

    The Jacobians and the re-solves at the four shifted inputs are `evaluate`'s (`base`:
    its result for `batch`, when already computed).

    Returns `(errors, compared, J_fwd, J_rev)`: the relative errors (rotation and
    translation blocks, the worse of the two) of the problems whose base and perturbed
    solves were all accepted, which problems those are, and the Jacobians."""
    y0, sol0, J, Jr = evaluate(method, batch) if base is None else base
    ad = _contract(J, d)
    values, accepted = [], [sol0.accepted]
    for s in (2, 1, -1, -2):
        shifted = _shift(batch, d, s * h)
        y, sol, _, _ = evaluate(method, shifted)
        values.append(y)
        accepted.append(sol.accepted)
    fd = (-values[0] + 8 * values[1] - 8 * values[2] + values[3]) / (12 * h)
    errors = np.maximum(
        _relative(fd[:, ROT], ad[:, ROT], 1), _relative(fd[:, TRANS], ad[:, TRANS], 1)
    )
    ok = np.all(accepted, axis=0)
    return errors[ok], ok, J, Jr


def forward_reverse_disagreement(J, Jr, ok):
    """Worst relative difference of the forward- and reverse-mode Jacobians over the
    compared problems, per input group and output block (rotation, translation)."""
    worst = 0.0
    for cols in GROUPS.values():
        for rows in (ROT, TRANS):
            a, b = J[ok][:, rows, cols], Jr[ok][:, rows, cols]
            worst = max(worst, float(np.max(_relative(b, a, (1, 2)))))
    return worst


# --------------------------------------------------------------------------- exactness


@pytest.mark.slow
def test_mixed_gradients_match_central_differences_on_1000_problems():
    batch = make_batch(0, 17 * CHUNK)
    errors, ok, J, Jr = central_difference_errors("mixed", batch, directions(batch, 1))
    # Every problem is solved, and re-solved at the perturbed inputs; a perturbation
    # that moved one to another local optimum (or made it fail) would leave it out.
    assert errors.size >= 1000, f"only {errors.size} of {ok.size} problems compared"
    assert np.max(errors) < 1e-6, np.sort(errors)[-5:]
    assert forward_reverse_disagreement(J, Jr, ok) < 1e-9
    assert np.all(np.isfinite(J)) and np.all(np.isfinite(Jr))


@pytest.mark.slow
def test_mixed_gradients_per_input_group():
    """Each input group on its own, so that a wrong derivative of one group cannot hide
    behind the others: intrinsics, extrinsics, model points, image points."""
    batch = make_batch(2, CHUNK)
    base = evaluate("mixed", batch)
    for g, group in enumerate(("k", "E", "M", "I")):
        d = directions(batch, 10 + g, groups=(group,))
        errors, ok, _, _ = central_difference_errors("mixed", batch, d, base=base)
        assert errors.size >= CHUNK - 3, (group, errors.size)
        assert np.max(errors) < 1e-6, (group, np.sort(errors)[-3:])


@pytest.mark.slow
@pytest.mark.parametrize("method", ["linear", "nonlinear"])
def test_other_methods_gradients_match_central_differences(method):
    batch = make_batch(3, 2 * CHUNK)
    errors, ok, J, Jr = central_difference_errors(method, batch, directions(batch, 4))
    assert errors.size >= 2 * CHUNK - 4, errors.size
    assert np.max(errors) < 1e-6, np.sort(errors)[-5:]
    assert forward_reverse_disagreement(J, Jr, ok) < 1e-9


# --------------------------------------------------------------------------- NaN-free


def _problem(rng, n, *, R=None, noise=0.0, edit=None):
    """A random problem `(C, model, image)`; the true pose has rotation `R` (default
    random); `edit` may change the world points first (degenerate configurations)."""
    s = jp.apps.random_scene(rng, n)
    world = s.model_points @ s.R.T + s.t
    if edit is not None:
        world = edit(world)
    R = s.R if R is None else R
    model = (world - s.t) @ R  # world = R m + t
    h = np.c_[world, np.ones(n)] @ s.camera.T
    image = h[:, :2] / h[:, 2:] + (rng.normal(scale=noise, size=(n, 2)) if noise else 0)
    return s.camera, model, image


def _as_batch(cases, dtype=np.float64):
    """Cases `(C, M, I[, mask])` of up to N_MAX matches as a padded Batch, with
    `k = (1, 1, 0, 0)` (so `K(k) = I` and `E = C`)."""
    ks, Es, Ms, Is, masks = [], [], [], [], []
    for case in cases:
        C, M, I = case[:3]
        n = len(M)
        mask = case[3] if len(case) > 3 else np.ones(n, bool)
        ks.append(np.array([1.0, 1.0, 0.0, 0.0]))
        Es.append(np.asarray(C, float))
        Ms.append(_pad(np.asarray(M, float), N_MAX))
        Is.append(_pad(np.asarray(I, float), N_MAX))
        masks.append(np.concatenate([mask, np.zeros(N_MAX - n, bool)]))
    arrays = [np.stack(x).astype(dtype) for x in (ks, Es, Ms, Is)]
    return Batch(*arrays, np.stack(masks))


def _half_turn(axis):
    u = np.asarray(axis, float) / np.linalg.norm(axis)
    return 2 * np.outer(u, u) - np.eye(3)


def _assert_finite(*trees):
    for leaf in jax.tree.leaves(trees):
        assert np.all(np.isfinite(np.asarray(leaf, dtype=float)))


def test_no_nan_at_rotation_angle_zero_and_pi_and_noise_free():
    """Outputs include the absolute rotation vector, singular at 0 and pi, and the
    Eq. 8 error, whose square root is singular at a zero residual."""
    rng = np.random.default_rng(7)
    rotations = [np.eye(3), _half_turn([1, 0, 0]), _half_turn([1, 2, 3]), _half_turn([0, 0, 1])]
    cases = [_problem(rng, 6, R=R, noise=noise) for R in rotations for noise in (0.0, 0.5)]
    y, sol, J, Jr = evaluate("mixed", _as_batch(cases))
    assert np.all(sol.accepted)
    _assert_finite(y, sol, J, Jr)
    for i, R in enumerate(np.repeat(rotations, 2, axis=0)):
        assert np.abs(sol.pose.R[i] - R).max() < 1e-2
        assert all(np.any(J[i, POSE, cols] != 0) for cols in GROUPS.values())
    assert np.all(sol.error[0::2] < 1e-9)  # noise-free: zero residual at the optimum


def test_no_nan_with_degenerate_triplets_present():
    """Collinear model points (their images aligned) and a duplicated point: the triplets
    they form are flagged and skipped, the answer's gradient is finite and non-zero."""
    rng = np.random.default_rng(8)

    def degenerate(world):
        world = world.copy()
        world[2] = 0.5 * (world[0] + world[1])
        world[3] = world[0] + 1e-9
        return world

    cases = [_problem(rng, 7, noise=noise, edit=degenerate) for noise in (0.0, 0.3, 0.3, 1.0)]
    y, sol, J, Jr = evaluate("mixed", _as_batch(cases))
    assert np.all(sol.accepted)
    _assert_finite(y, sol, J, Jr)
    assert all(np.all(np.any(J[:, POSE, cols] != 0, axis=(1, 2))) for cols in GROUPS.values())


def test_not_accepted_problems_have_zero_gradient():
    """No pose accepted (two usable matches, three collinear ones, a zero camera): the
    identity placeholder, finite values, a zero gradient of the pose and of the error,
    a finite one of the pose error (which measures the placeholder)."""
    rng = np.random.default_rng(9)
    C, M, I = _problem(rng, 6, noise=0.3)

    def collinear(world):
        world = world.copy()
        world[2] = 0.3 * world[0] + 0.7 * world[1]
        return world

    C3, M3, I3 = _problem(rng, 6, noise=0.3, edit=collinear)
    first = lambda k: np.arange(6) < k
    cases = [(C, M, I, first(2)), (C3, M3, I3, first(3)), (np.zeros((3, 4)), M, I), (C, M, I)]
    y, sol, J, Jr = evaluate("mixed", _as_batch(cases))
    assert list(sol.accepted) == [False, False, False, True]
    _assert_finite(y, sol, J, Jr)
    np.testing.assert_array_equal(sol.pose.R[:3], np.broadcast_to(np.eye(3), (3, 3, 3)))
    for G in (J, Jr):
        assert np.all(G[:3, :16] == 0)  # pose, its rotation vector, the error
        assert all(np.any(G[3, :12, cols] != 0) for cols in GROUPS.values())


@pytest.mark.slow
def test_float32_gradients_are_finite_and_close_to_float64():
    """float32 derivatives of the answers of the best roots (every case is accepted there,
    so the float32 program leaves out the fallback, the whole mixed algorithm, which
    carries no derivative: a smaller program to compile) against float64's."""
    rng = np.random.default_rng(10)
    cases = [_problem(rng, 7, noise=0.5) for _ in range(6)]
    cases += [_problem(rng, 7, R=np.eye(3)), _problem(rng, 7, R=_half_turn([0, 1, 1]))]
    y64, s64, J64, _ = evaluate("mixed", _as_batch(cases))
    y32, s32, J32, Jr32 = evaluate("mixed", _as_batch(cases, np.float32), fallback=False)
    assert np.all(s32.accepted) and s32.pose.R.dtype == np.float32
    _assert_finite(y32, s32, J32, Jr32)
    for cols in GROUPS.values():
        for rows in (ROT, TRANS):
            err = _relative(J32[:, rows, cols].astype(float), J64[:, rows, cols], (1, 2))
            assert np.max(err) < 5e-2, err
