"""The batch-first three-point kernel against the single-problem reference (`_p3p`,
`p3p`, `three_point`), slot by slot, on fresh random and on near-degenerate instances.

Few shapes are compiled: every `p3p` comparison runs one padded batch of `BATCH`
triplets through one jitted kernel and one jitted `jax.vmap` of the reference (the
problem generators are `test_three_point`'s).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import assume, example, given
from hypothesis import strategies as st
from test_three_point import (
    _collinearity,
    _image_area,
    _scene,
    instances,
    pose_errors,
    symmetric_instances,
)

from jaxpose.solvers._components import Vec3, mat_to_array, vec_from_array, vec_to_array
from jaxpose.solvers._kernel_p3p import p3p_batch, p3p_components, three_point_batch
from jaxpose.solvers._p3p import _p3p, three_point
from jaxpose.solvers._status import Status

BATCH = 2048
SMALL = 64  # three_point batches


def _rows(a) -> tuple[Vec3, Vec3, Vec3]:
    """`(..., 3, 3)` to three `Vec3` (the rows)."""
    return vec_from_array(a[..., 0, :]), vec_from_array(a[..., 1, :]), vec_from_array(a[..., 2, :])


def _components(f, m):
    c = p3p_components(_rows(f), _rows(m))
    return mat_to_array(c.R), vec_to_array(c.t), c.real, c.near, c.positive


_ref = jax.jit(jax.vmap(_p3p))
_ker = jax.jit(_components)
_p3p_kernel = jax.jit(p3p_batch, static_argnames="chunk")
_tp_ker = jax.jit(
    three_point_batch, static_argnames=("approximate", "chunk", "min_area", "collinear_tol")
)


def _pad(f, m, n=BATCH):
    pad = n - len(f)
    assert pad >= 0
    eye = np.tile(np.eye(3), (pad, 1, 1))
    return np.concatenate([f, eye]), np.concatenate([m, eye])


def _both(f, m, dtype=jnp.float64, emitters=None):
    """Reference and kernel candidates `(R, t, real, near, positive)`, numpy, unpadded.
    `emitters`: XLA:CPU's `xla_cpu_use_fusion_emitters` for both programs (`None`: the
    run's flags, which the suite sets to `False` as the library does)."""
    n = len(f)
    fp, mp = (jnp.asarray(a, dtype) for a in _pad(f, m))
    if emitters is None:
        ref, ker = _ref(fp, mp), _ker(fp, mp)
    else:
        options = {"xla_cpu_use_fusion_emitters": emitters}
        ref, ker = (
            jax.jit(g).lower(fp, mp).compile(compiler_options=options)(fp, mp)
            for g in (jax.vmap(_p3p), _components)
        )
    ref = tuple(np.asarray(a)[:n] for a in ref)
    ker = tuple(np.asarray(a)[:n] for a in ker)
    return ref, ker


def _same_solutions(Ra, va, Rb, vb, tol):
    """Per instance: every valid rotation of one side is within `tol` (per instance) of
    a valid one of the other (the slots may be ordered differently)."""

    def covered(Ra, va, Rb, vb):
        d = np.abs(Ra[:, :, None] - Rb[:, None]).max(axis=(-2, -1))
        d = np.where(va[:, :, None] & vb[:, None], d, np.inf)
        return np.all(np.where(va, d.min(axis=2) < np.reshape(tol, (-1, 1)), True), axis=1)

    return covered(Ra, va, Rb, vb) & covered(Rb, vb, Ra, va)


def _pose_gap(ref, ker):
    """Per slot: max(|dR|, |dt| / max(1, |t|)) between the reference and the kernel."""
    dR = np.abs(ref[0] - ker[0]).max(axis=(-2, -1))
    scale = np.maximum(1.0, np.linalg.norm(ref[1], axis=-1))
    return np.maximum(dR, np.abs(ref[1] - ker[1]).max(axis=-1) / scale)


@pytest.fixture(scope="module")
def data():
    return instances(np.random.default_rng(20240611), BATCH)


@pytest.fixture(scope="module")
def solved(data):
    return _both(data["f"], data["m"])


def test_slots_and_flags_match_reference_float64(data, solved):
    ref, ker = solved
    assert ker[0].shape == (BATCH, 4, 3, 3) and ker[2].shape == (BATCH, 4)
    for name, k in (("real", 2), ("near", 3)):
        assert np.array_equal(ref[k], ker[k]), name
    flagged = ref[2] | ref[3]
    assert np.array_equal(ref[4][flagged], ker[4][flagged])
    gap = _pose_gap(ref, ker)
    assert gap[ref[2]].max() < 1e-9, np.sort(gap[ref[2]])[-3:]
    # the true pose is among the valid slots, as with the reference
    valid = ker[2] & ker[4]
    best = pose_errors(ker[0], ker[1], valid, data["R"], data["t"]).min(axis=1)
    assert np.all(best < 1e-9), np.sort(best)[-3:]


def test_p3p_batch_equals_vmapped_p3p(data, solved):
    """`p3p_batch` (in passes: 2048 = 2 x 768 + 512, the last padded) is the masked
    core: placeholders in invalid slots, never NaN."""
    ref, _ = solved
    R, t, valid = (np.asarray(a) for a in _p3p_kernel(data["f"], data["m"], chunk=768))
    assert R.shape == (BATCH, 4, 3, 3) and t.shape == (BATCH, 4, 3) and valid.dtype == bool
    assert np.array_equal(valid, ref[2] & ref[4])
    assert np.isfinite(R).all() and np.isfinite(t).all()
    assert np.all(R[~valid] == np.eye(3)) and np.all(t[~valid] == 0)
    gap = _pose_gap(ref, (R, t))
    assert gap[valid].max() < 1e-9


def test_batch_shape_free_core(data):
    """The core takes any batch shape: `(2, 3)` gives the flat batch's slots."""
    f, m = data["f"][:6], data["m"][:6]

    def grid(f, m):
        c = p3p_components(*(_rows(a.reshape(2, 3, 3, 3)) for a in (f, m)))
        return mat_to_array(c.R), c.real

    flat = [np.asarray(a) for a in _ker(f, m)]
    grid_R, grid_real = (np.asarray(a) for a in jax.jit(grid)(f, m))
    assert grid_real.shape == (2, 3, 4)
    assert np.array_equal(grid_real.reshape(6, 4), flat[2])
    np.testing.assert_allclose(
        grid_R.reshape(6, 4, 3, 3)[flat[2]],
        flat[0][flat[2]],
        atol=1e-12,
    )


@pytest.mark.parametrize("emitters", [False, True], ids=["elemental", "fusion"])
def test_symmetric_and_double_root_configurations(emitters):
    """Equilateral triangles seen from their axis (all three pencil members equally
    indefinite: ties), isosceles and right triangles, the danger-cylinder double roots:
    the true pose is found as by the reference (simple solutions to 1e-9, double ones to
    1e-4), every valid slot is an exact solution, and the solution sets agree (the tie
    between equally indefinite members may be broken the other way, reordering slots).

    Under both of XLA:CPU's emitters: a double root's discriminant is `0` or `-ulp`
    depending on whether a fused multiply-add computed it, and XLA may compute it both
    ways in one program (on AVX2-only machines with the elemental emitters it did, and
    the kernel lost 9 of these double roots while the reference kept them)."""
    data = symmetric_instances(np.random.default_rng(7), 30)
    ref, ker = _both(data["f"], data["m"], emitters=emitters)
    simple = data["family"] == "simple"
    for R, t, real, _, positive in (ref, ker):
        assert np.isfinite(R[real]).all()
        best = pose_errors(R, t, real & positive, data["R"], data["t"]).min(axis=1)
        assert np.all(best[simple] < 1e-9) and np.all(best[~simple] < 1e-4)
    valid = ker[2] & ker[4]
    idx, slot = np.nonzero(valid)
    pc = np.einsum("sij,snj->sni", ker[0][idx, slot], data["m"][idx]) + ker[1][idx, slot][:, None]
    bearing = pc / np.linalg.norm(pc, axis=-1, keepdims=True)
    assert np.linalg.norm(bearing - data["f"][idx], axis=-1).max() < 1e-10

    tol = np.where(simple, 1e-9, 1e-4)
    agree = _same_solutions(ref[0], ref[2] & ref[4], ker[0], ker[2] & ker[4], tol)
    assert agree[simple].all()
    assert agree.mean() >= 0.97, agree.mean()


def test_degenerate_and_non_finite_inputs():
    rng = np.random.default_rng(1)
    f = np.tile(np.eye(3), (8, 1, 1))
    m = rng.normal(size=(8, 3, 3))
    f[0] = 0.0  # zero bearings
    f[1] = [1.0, 0.0, 0.0]  # identical bearings
    m[2] = 0.0  # coincident model points
    m[3] = [[0, 0, 0], [1, 1, 1], [2, 2, 2]]  # collinear model points
    f[4, 0] = np.nan
    m[5, 2] = np.inf
    f[6, 1] = -np.inf
    ref, ker = _both(f, m)
    for k in (2, 3):
        assert np.array_equal(ref[k], ker[k])
    R, t, valid = (np.asarray(a) for a in _p3p_kernel(*_pad(f, m), chunk=4096))
    assert np.isfinite(R).all() and np.isfinite(t).all()
    assert not valid[[0, 1, 2, 4, 5, 6]].any()


@example(
    quat=[0.0, 0.0, 0.0, 1.0],
    trans=[0.0, 0.0, 1.0],
    rays=[0.0, 0.5, 0.0, 0.0, 0.25, 0.0],
    depths=[0.5, 0.5, 0.5],
)
@example(  # found on an AVX2-only machine: the reference gave 4 solutions, the kernel 2
    quat=[0.0, 1.0, 0.0, 0.875],
    trans=[0.0, 0.0, 0.0],
    rays=[9.41e-10, 0.0, 0.3671875, 0.0, 0.0, 0.25],
    depths=[1.0, 1.0, 1.0],
)
@given(
    quat=st.lists(st.floats(-1, 1), min_size=4, max_size=4),
    trans=st.lists(st.floats(-5, 5), min_size=3, max_size=3),
    rays=st.lists(st.floats(-0.6, 0.6), min_size=6, max_size=6),
    depths=st.lists(st.floats(0.5, 20), min_size=3, max_size=3),
)
def test_property_matches_reference(quat, trans, rays, depths):
    """Hypothesis instances (the reference's property test, the reported double root
    as the example): as many exact and approximate solutions as the reference, the same
    poses (to 1e-4: multiple solutions are determined to ~sqrt(eps) only; the slots may
    be ordered differently when pencil members tie, e.g. at equal depths), and every
    valid slot an exact solution."""
    q = np.asarray(quat)
    assume(np.linalg.norm(q) > 0.1)
    w, x, y, z = q / np.linalg.norm(q)
    R = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )
    t = np.asarray(trans)
    uv = np.asarray(rays).reshape(3, 2)
    pc = np.concatenate([uv, np.ones((3, 1))], 1) * np.asarray(depths)[:, None]
    m = (pc - t) @ R
    assume(_collinearity(m[None])[0] > 0.05)
    assume(_image_area(uv[None])[0] > 1e-3)
    f = pc / np.linalg.norm(pc, axis=1, keepdims=True)
    ref, ker = _both(f[None], m[None])
    assert np.isfinite(ker[0][ker[2]]).all()
    assert ref[2].sum() == ker[2].sum() and ref[3].sum() == ker[3].sum()
    assert _same_solutions(ref[0], ref[2] & ref[4], ker[0], ker[2] & ker[4], 1e-4).all()
    for s in np.nonzero(ker[2][0] & ker[4][0])[0]:
        p = m @ ker[0][0, s].T + ker[1][0, s]
        err = np.linalg.norm(p / np.linalg.norm(p, axis=1, keepdims=True) - f, axis=1)
        assert err.max() < 1e-8


def test_float32_agrees_on_the_large_majority(data, solved):
    ref64, _ = solved
    ref, ker = _both(data["f"], data["m"], jnp.float32)
    assert ker[0].dtype == np.float32
    agree = np.mean(ref[2] == ker[2])
    assert agree >= 0.995, agree
    both = ref[2] & ker[2]
    gap = _pose_gap(ref, ker)[both]
    assert np.mean(gap < 1e-3) >= 0.99, np.quantile(gap, 0.99)
    # and the true pose: as often as the reference finds it
    rates = []
    for c in (ref, ker):
        best = pose_errors(c[0], c[1], c[2] & c[4], data["R"], data["t"]).min(axis=1)
        rates.append(np.mean(best < 1e-3))
    assert rates[1] >= rates[0] - 0.005, rates


# --------------------------------------------------------------------------------------
# three_point: cameras, pixels, statuses


def _run_three_point(cams, models, images, **kw):
    """Reference and kernel on a padded batch of `SMALL` (per-triplet cameras)."""
    n = len(models)
    pad = SMALL - n
    cams, models, images = (
        np.concatenate([a, np.repeat(a[:1], pad, 0)]) for a in (cams, models, images)
    )
    ref = jax.jit(jax.vmap(lambda c, m, i: three_point(c, m, i, **kw)))(cams, models, images)
    ker = _tp_ker(cams, models, images, **kw)
    return tuple(jax.tree.map(lambda a: np.asarray(a)[:n], r) for r in (ref, ker))


def _assert_same(ref, ker, tol=1e-9):
    assert np.array_equal(ref.status, ker.status), (ref.status, ker.status)
    assert np.array_equal(ref.valid, ker.valid)
    assert np.isfinite(ker.R).all() and np.isfinite(ker.t).all()
    scale = np.maximum(1.0, np.linalg.norm(ref.t, axis=-1))
    assert np.abs(ref.R - ker.R).max() < tol
    assert (np.abs(ref.t - ker.t).max(axis=-1) / scale).max() < tol


def _status_cases(rng):
    """`test_three_point`'s status cases: one regular scene, a collinear model, aligned
    and coincident pixels, coincident model points, non-finite pixels and camera, a
    singular camera, points behind the camera."""
    C, m, uv, R, t = _scene(rng, 1.0)
    cases = [(C, m, uv)]
    m_col = m[0] + np.outer([0.0, 1.0, 2.0], m[1] - m[0]) + rng.normal(size=(3, 3)) * 1e-5
    proj = np.concatenate([m_col @ R.T + t, np.ones((3, 1))], 1) @ C.T
    cases.append((C, m_col, proj[:, :2] / proj[:, 2:] + rng.normal(size=(3, 2)) * 30.0))
    cases.append((C, m, np.array([[100.0, 100.0], [200.0, 200.0], [300.0, 300.5]])))
    cases.append((C, m, np.full((3, 2), 100.0)))
    cases.append((C, np.zeros((3, 3)), uv))
    cases.append((C, m, np.where(np.eye(3, 2) > 0, np.nan, uv)))
    cases.append((np.full((3, 4), np.inf), m, uv))
    C_sing = C.copy()
    C_sing[:, 2] = C_sing[:, 0] + C_sing[:, 1]
    cases.append((C_sing, m, uv))
    for k in range(6):
        Ck, mk, uvk, Rk, tk = _scene(rng, 1.0)
        pw = mk @ Rk.T + tk
        centre = -np.linalg.solve(Ck[:, :3], Ck[:, 3])
        pw[k % 3] = centre - 0.5 * (pw[k % 3] - centre)
        cases.append((Ck, (pw - tk) @ Rk, uvk))
    return [np.stack(x) for x in zip(*cases, strict=True)]


def test_three_point_batch_equals_vmapped_three_point():
    rng = np.random.default_rng(11)
    scenes = [_scene(rng, s) for s in [1.0, -1.0, 3.7, -0.02, 1e-3, -250.0] * 6]
    C, m, uv, _, _ = (np.stack(x) for x in zip(*scenes, strict=True))
    cases = _status_cases(rng)
    C, m, uv = (np.concatenate([a, b]) for a, b in zip((C, m, uv), cases, strict=True))
    ref, ker = _run_three_point(C, m, uv)
    _assert_same(ref, ker)
    assert set(np.unique(ker.status)) >= {
        Status.OK,
        Status.DEGENERATE_IMAGE,
        Status.DEGENERATE_MODEL,
        Status.NOT_FINITE,
        Status.NO_SOLUTION,
    }
    # one camera for all triplets: the (3, 4) form
    C0 = C[0]
    ref1 = jax.jit(jax.vmap(three_point, in_axes=(None, 0, 0)))(C0, m, uv)
    ker1 = _tp_ker(C0, m, uv)
    _assert_same(*(jax.tree.map(np.asarray, r) for r in (ref1, ker1)))


def test_three_point_batch_in_passes():
    """Passes of a few triplets (the last one padded) give the one-pass results, for one
    camera and for one camera per triplet (its centre travels with the passes): the same
    flags and statuses, the same values to rounding (the machine code for a pass of
    another length may vectorise, and so round, differently)."""
    rng = np.random.default_rng(12)
    scenes = [_scene(rng, s) for s in [1.0, -2.0, 0.5] * 10]
    C, m, uv, _, _ = (np.stack(x) for x in zip(*scenes, strict=True))
    for cams in (C, C[0]):
        one = jax.tree.map(np.asarray, _tp_ker(cams, m, uv, chunk=0))
        passes = jax.tree.map(np.asarray, _tp_ker(cams, m, uv, chunk=7))
        for a, b in zip(one, passes, strict=True):
            if np.issubdtype(a.dtype, np.floating):
                np.testing.assert_allclose(b, a, rtol=1e-12, atol=1e-12)
            else:
                assert np.array_equal(a, b)
        assert (one.status == Status.OK).mean() > 0.5


def test_non_finite_poses_are_flagged():
    """Models far too large or small for the squared edges: every slot flagged `real`
    holds a finite pose, as the reference's flags say."""
    data = instances(np.random.default_rng(13), 24)
    f, m = data["f"], data["m"].copy()
    m[:8] *= 1e160  # squared edges overflow
    m[8:16] *= 1e-170  # and underflow
    ref, ker = _both(f, m)
    assert np.array_equal(ref[2], ker[2]) and np.array_equal(ref[3], ker[3])
    flagged = ker[2] | ker[3]
    assert np.isfinite(ker[0][flagged]).all() and np.isfinite(ker[1][flagged]).all()
    assert flagged[16:].any()


def test_three_point_batch_approximate_and_thresholds():
    """`approximate=True` keeps the near-real roots of the noisy double-root scenes, as
    the reference does; the thresholds are passed through."""
    data = symmetric_instances(np.random.default_rng(5), 4)
    rng = np.random.default_rng(6)
    n = len(data["m"])
    K = np.array([[800.0, 0.0, 320.0], [0.0, 800.0, 240.0], [0.0, 0.0, 1.0]])
    C = np.repeat((K @ np.eye(3, 4))[None], n, 0)
    pc = np.einsum("nij,nkj->nki", data["R"], data["m"]) + data["t"][:, None]
    h = pc @ K.T
    uv = h[..., :2] / h[..., 2:] + rng.normal(size=(n, 3, 2)) * 0.3
    m = data["m"]  # the camera frame is the world frame: pc are world points
    for kw in ({"approximate": True}, {"approximate": False, "min_area": 1e-6}):
        ref, ker = _run_three_point(C[:SMALL], m[:SMALL], uv[:SMALL], **kw)
        assert np.array_equal(ref.status, ker.status)
        agree = _same_solutions(ref.R, ref.valid, ker.R, ker.valid, 1e-6)
        print(kw, "same solution sets:", agree.mean())
        assert agree.mean() >= 0.95, agree.mean()


def test_together_is_exact():
    """`together` returns its arrays bit for bit (signed zeros, infinities, NaN, masks),
    whatever the grouping, a lone array included."""
    from jaxpose.solvers._components import together

    x = np.asarray([0.0, -0.0, 1.5, -np.inf, np.inf, np.nan, 5e-324, -1e308])
    with np.errstate(over="ignore", invalid="ignore"):  # -1e308 * 2, nan > 0
        tree = {"a": x, "b": (x * 2, x[::-1].copy()), "c": x > 0, "d": np.reshape(x, (2, 4))}
    for group in (0, 1, 2, 8):
        out = jax.jit(lambda t, g=group: together(t, g))(tree)
        for a, b in zip(jax.tree.leaves(tree), jax.tree.leaves(out), strict=True):
            assert a.dtype == b.dtype and a.shape == b.shape
            assert np.array_equal(np.asarray(a).view(np.uint8), np.asarray(b).view(np.uint8))
