"""The batch-first linear-step and Eq. 8 kernels against the single-problem references
(`linear_step`, `linear`, `pose_errors`), on fresh random problems.

Few shapes are compiled: one padded width (`N = 30`, each problem using 4 to 30 matches
through its mask) and one small exact width (`n = 4`), with several starts per problem.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxpose.geometry._pose import Pose, observations
from jaxpose.geometry._rotation import rotvec_to_matrix
from jaxpose.solvers._components import mat_from_array, mat_to_array, vec_from_array, vec_to_array
from jaxpose.solvers._kernel_linear import (
    in_chunks,
    linear_kernel,
    linear_step_kernel,
    matches_from_observations,
    pixel_error_kernel,
)
from jaxpose.solvers._linear import linear, linear_step
from jaxpose.solvers._status import Status
from jaxpose.strategy._triplets import pose_errors

N = 30  # padded width
K = 3  # starts per problem

# Helpers and references as the tests call them, jitted (one program per shape rather
# than one per eager operation); the checks run in numpy.
_rotvecs_to_matrices = jax.jit(jax.vmap(rotvec_to_matrix))
_mat_to_array = jax.jit(mat_to_array)


@jax.jit
def _pixel_errors(R, t, m):
    """`pixel_error_kernel` of poses given as arrays `(..., 3, 3)`, `(..., 3)`."""
    return pixel_error_kernel(mat_from_array(R), vec_from_array(t), m)


@jax.jit
def _pose_errors(obs, R, t):
    return jax.vmap(lambda o, R, t: pose_errors(Pose(R, t), o))(obs, R, t)


def _as_dtype(tree, dtype):
    """The floating leaves of `tree` as numpy arrays of `dtype`."""
    return jax.tree.map(
        lambda a: np.asarray(a).astype(dtype) if a.dtype.kind == "f" else np.asarray(a), tree
    )


def _rotations(rng, count, max_angle):
    axis = rng.normal(size=(count, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    angle = rng.uniform(0, max_angle, size=(count, 1))
    return np.asarray(_rotvecs_to_matrices(axis * angle))


def _problems(seed, P, n, *, min_used=4):
    """`P` random problems of width `n`: general world-frame cameras (some with skew and
    unequal focal lengths), 1 px noise, masks using `min_used..n` matches (the padding
    holds finite junk), the true poses."""
    rng = np.random.default_rng(seed)
    K_ = np.zeros((P, 3, 3))
    K_[:, 0, 0] = rng.uniform(500, 1200, P)
    K_[:, 1, 1] = K_[:, 0, 0] * np.where(rng.uniform(size=P) < 0.5, 1, rng.uniform(0.7, 1.3, P))
    K_[:, 0, 1] = np.where(rng.uniform(size=P) < 0.5, 0, rng.uniform(-40, 40, P))
    K_[:, 0, 2], K_[:, 1, 2], K_[:, 2, 2] = 320, 240, 1
    R_wc = _rotations(rng, P, np.pi)
    t_wc = rng.normal(size=(P, 3)) * 500
    camera = K_ @ np.concatenate([R_wc, t_wc[..., None]], axis=-1)
    camera *= rng.uniform(0.1, 10, size=(P, 1, 1))  # any scale: the library normalises
    in_cam = rng.uniform([-200, -200, 800], [200, 200, 1600], size=(P, n, 3))
    world = np.einsum("pji,pnj->pni", R_wc, in_cam - t_wc[:, None])
    R = _rotations(rng, P, np.pi)
    t = rng.normal(size=(P, 3)) * 300
    model = np.einsum("pji,pnj->pni", R, world - t[:, None])
    h = in_cam @ np.swapaxes(K_, 1, 2)
    image = h[..., :2] / h[..., 2:] + rng.normal(size=(P, n, 2))
    used = rng.integers(min_used, n + 1, size=P)
    mask = np.arange(n)[None, :] < used[:, None]
    order = rng.permuted(np.tile(np.arange(n), (P, 1)), axis=1)
    mask = np.take_along_axis(mask, order, axis=1)
    model = np.where(mask[..., None], model, rng.normal(size=model.shape))
    return camera, model, image, mask, R, t


def _starts(seed, R, t, angles):
    """`len(angles)` starts per problem, each rotated by up to `angle` about the object's
    centre and shifted by a tenth of that in relative translation."""
    rng = np.random.default_rng(seed)
    P = len(R)
    Rs, ts = [], []
    for angle in angles:
        dR = _rotations(rng, P, angle)
        Rs.append(dR @ R)
        ts.append(t + angle * 100 * rng.normal(size=(P, 3)))
    return np.stack(Rs, axis=1), np.stack(ts, axis=1)


@jax.jit
def _observations(C, M, I, mask):
    return jax.vmap(observations)(C, M, I, mask)


@jax.jit
def _matches(obs):
    return jax.tree.map(lambda a: a[:, None], matches_from_observations(obs))


@jax.jit
def _reference(obs, R, t):
    """`linear_step`, `linear` and `pose_errors` of poses `(P, K)`."""

    def per_problem(o, R, t):
        step = jax.vmap(lambda R, t: linear_step(Pose(R, t), o))(R, t)
        lin = jax.vmap(lambda R, t: linear(o, Pose(R, t)))(R, t)
        return step, lin, pose_errors(Pose(R, t), o)

    return jax.vmap(per_problem)(obs, R, t)


@jax.jit
def _kernels(m, R, t):
    R, t = mat_from_array(R), vec_from_array(t)
    step = linear_step_kernel(R, t, m)
    lin = linear_kernel(R, t, m)
    return step, lin, pixel_error_kernel(R, t, m)


def _check(obs, R, t, *, rtol, atol_t, statuses=True, determined=slice(None)):
    """Kernels against references; the single steps compared on the `determined`
    problems, the methods' results where the reference succeeds."""
    dtype = R.dtype
    reference = jax.tree.map(np.asarray, _reference(obs, R, t))
    (ref_pose, ref_step), ref_lin, ref_err = reference
    m = _matches(_as_dtype(obs, dtype))
    kernels = _kernels(m, R, t)
    (kR, kt, kstep), (lR, lt, lerr, lstep, lstatus), kerr = jax.tree.map(np.asarray, kernels)
    for a in jax.tree.leaves(((kR, kt, kstep), (lR, lt, lerr, lstep, lstatus), kerr)):
        assert bool(np.all(np.isfinite(a)))
    kR, lR = np.asarray(_mat_to_array(kR)), np.asarray(_mat_to_array(lR))
    kt = np.stack([kt.x, kt.y, kt.z], axis=-1)  # vec_to_array
    d = determined
    scale = np.max(np.abs(ref_pose.t))
    np.testing.assert_allclose(kR[d], ref_pose.R[d], rtol=0, atol=rtol)
    np.testing.assert_allclose(kt[d], ref_pose.t[d], atol=atol_t * scale)
    np.testing.assert_allclose(kstep[d], ref_step[d], rtol=rtol, atol=rtol)
    np.testing.assert_allclose(kerr, ref_err, rtol=rtol, atol=0)
    ok = ref_lin.status == Status.OK
    np.testing.assert_allclose(lerr[ok], ref_lin.error[ok], rtol=rtol)
    np.testing.assert_allclose(lR[ok], ref_lin.pose.R[ok], atol=rtol)
    if statuses:
        np.testing.assert_array_equal(lstatus, ref_lin.status)
    return ref_lin.status, lstatus, ref_pose.R, kR


@pytest.fixture(scope="module")
def padded():
    C, M, I, mask, R, t = _problems(1, 40, N)
    obs = _observations(C, M, I, mask)
    Rs, ts = _starts(2, R, t, [0.02, 0.1, 0.5])
    return obs, Rs, ts


def test_float64_padded_problems_several_starts(padded):
    obs, R, t = padded
    ref_status, *_ = _check(obs, R, t, rtol=1e-9, atol_t=1e-9)
    # the starts near the optimum converge, the far ones do not all
    assert np.all(np.asarray(ref_status)[:, 0] == Status.OK)


def test_float64_exactly_four_matches():
    C, M, I, mask, R, t = _problems(3, 12, 4, min_used=4)
    obs = _observations(C, M, I, mask)
    Rs, ts = _starts(4, R, t, [0.01, 0.05, 0.3])
    _check(obs, Rs, ts, rtol=1e-8, atol_t=1e-8)


def test_float32_agrees_loosely(padded):
    obs, R, t = padded
    obs32 = _as_dtype(obs, np.float32)
    R32, t32 = R.astype(np.float32), t.astype(np.float32)
    (ref_pose, _), ref_lin, ref_err = jax.tree.map(np.asarray, _reference(obs, R, t))
    m = _matches(obs32)
    (kR, kt, _), (lR, lt, lerr, _, lstatus), kerr = _kernels(m, R32, t32)
    assert kR.xx.dtype == jnp.float32 and lerr.dtype == jnp.float32
    np.testing.assert_allclose(kerr, ref_err, rtol=1e-3)
    np.testing.assert_allclose(_mat_to_array(kR), ref_pose.R, atol=2e-4)
    ok = ref_lin.status == Status.OK
    assert np.mean(np.asarray(lstatus)[ok] == Status.OK) > 0.9
    np.testing.assert_allclose(np.asarray(_mat_to_array(lR))[ok], ref_lin.pose.R[ok], atol=1e-4)
    # Eq. 8 error at the fixed point within float32 rounding of the float64 optimum
    np.testing.assert_allclose(np.asarray(lerr)[ok], ref_lin.error[ok], rtol=1e-3)


def _degenerate(zero_depth=False):
    """The padded fixture's shapes (40 problems of width N, K starts): 0, 1 collinear
    model points; 2 two matches; 3 exactly three; 4 one match behind the camera at the
    first start (at depth ~0 with `zero_depth`); 5 the whole object behind the camera;
    the others ordinary."""
    C, M, I, mask, R, t = _problems(5, 40, N, min_used=12)
    rng = np.random.default_rng(6)
    for b in (0, 1):
        d = rng.normal(size=3)
        M[b] = M[b, :1] + np.linspace(-100, 100, N)[:, None] * d
    mask[2] = False
    mask[2, :2] = True
    mask[3] = False
    mask[3, :3] = True
    Rs, ts = _starts(7, R, t, [0.01, 0.02, 0.05])
    m3 = C[5, 2, :3] / np.linalg.norm(C[5, 2, :3])
    ts[5] = ts[5] - 4000 * m3  # the whole object behind the camera
    i = int(np.flatnonzero(mask[4])[0])
    c3 = C[4, 2, :3]
    depth = c3 @ (Rs[4, 0] @ M[4, i] + ts[4, 0]) + C[4, 2, 3]
    target = 0 if zero_depth else -300 * np.linalg.norm(c3)
    M[4, i] -= Rs[4, 0].T @ (c3 * (depth - target) / (c3 @ c3))
    obs = _observations(C, M, I, mask)
    return obs, Rs, ts


def test_degenerate_problems_are_finite_with_the_reference_status():
    obs, R, t = _degenerate()
    # problems 0-2 leave some motion undetermined (collinear points, two matches)
    ref_status, status, ref_R, kR = _check(
        obs, R, t, rtol=1e-9, atol_t=1e-9, statuses=False, determined=slice(4, None)
    )
    ref_status, status = np.asarray(ref_status), np.asarray(status)
    np.testing.assert_array_equal(status[4:], ref_status[4:])
    assert np.all(ref_status[2] == Status.TOO_FEW_POINTS)
    assert np.all(status[2] == Status.TOO_FEW_POINTS)
    assert Status.BEHIND_CAMERA in ref_status[4:6]  # the branch is exercised
    # Three matches determine the pose, but ill-conditioned: one step agrees to 1e-4,
    # five steps may part (as two runs of the reference with other rounding would).
    np.testing.assert_allclose(kR[3], ref_R[3], atol=1e-4)
    # Collinear model points leave the rotation about their line undetermined: both
    # solvers damp it by the same pivot floor, but what the step does in that direction
    # is rounding noise over the floor, so only the failure is common.
    assert np.all(status[:2] != Status.OK) and np.all(ref_status[:2] != Status.OK)


def test_pixel_error_with_a_match_at_zero_depth():
    """At a depth of rounding size the residual is huge (or `0` where the depth rounds to
    exactly `0`) but finite, in both; its value is the rounding of the depth's
    cancellation, not comparable."""
    obs, R, t = _degenerate(zero_depth=True)
    err = np.asarray(_pixel_errors(R, t, _matches(obs)))
    ref = np.asarray(_pose_errors(obs, R, t))
    assert bool(np.all(np.isfinite(err)))
    keep = np.ones(err.shape, dtype=bool)
    keep[4, 0] = False
    np.testing.assert_allclose(err[keep], ref[keep], rtol=1e-9)


def test_pixel_errors_of_many_candidates(padded):
    """Poses (P, C) against problems (P, 1): the triplet-scoring shape."""
    obs, R, t = padded
    R2 = np.concatenate([R, np.swapaxes(R, -1, -2)], axis=1)  # some far from anything
    t2 = np.concatenate([t, -t], axis=1)
    m = _matches(obs)
    err = _pixel_errors(R2, t2, m)
    ref = _pose_errors(obs, R2, t2)
    assert err.shape == R2.shape[:2]
    np.testing.assert_allclose(err, ref, rtol=1e-9)


def test_in_chunks_matches_one_pass(padded):
    obs, R, t = padded
    m = _matches(obs)

    def whole(R, t, m):
        return linear_kernel(mat_from_array(R), vec_from_array(t), m)

    def chunked(R, t, m):
        return in_chunks(linear_kernel, mat_from_array(R), vec_from_array(t), m, size=16)

    whole, chunked = jax.jit(whole)(R, t, m), jax.jit(chunked)(R, t, m)
    for a, b in zip(jax.tree.leaves(whole), jax.tree.leaves(chunked)):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)


def test_derivative_of_the_step_matches_the_reference():
    C, M, I, mask, R, t = _problems(8, 2, 6, min_used=6)
    obs = _observations(C, M, I, mask)
    Rs, ts = _starts(9, R, t, [0.05])
    R0, t0 = jax.device_put(Rs[:, 0]), ts[:, 0]
    m = jax.jit(matches_from_observations)(obs)

    def kernel(t):
        R1, t1, _ = linear_step_kernel(mat_from_array(R0), vec_from_array(t), m)
        return jnp.concatenate([mat_to_array(R1).reshape(2, -1), vec_to_array(t1)], axis=1)

    def reference(t):
        pose, _ = jax.vmap(lambda R, t, o: linear_step(Pose(R, t), o))(R0, t, obs)
        return jnp.concatenate([pose.R.reshape(2, -1), pose.t], axis=1)

    def loss(f):
        # reverse mode: the kernel's derivative rules, transposed
        return jax.jit(jax.grad(lambda t: jnp.sum(f(t) ** 2)))

    np.testing.assert_allclose(loss(kernel)(t0), loss(reference)(t0), rtol=1e-6)
