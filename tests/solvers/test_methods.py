"""The linear and non-linear methods (and the residuals they minimise) against OpenCV."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import central_difference_jacobian, opencv_optimum, rms_px

import jaxpose as jp

# The helpers the tests call outside the solvers, jitted: one program per shape rather
# than one per eager operation.
_rotvec_to_matrix = jax.jit(jp.rotvec_to_matrix)
_matrix_to_rotvec = jax.jit(jp.matrix_to_rotvec)
_matrix_to_quaternion = jax.jit(jp.geometry.matrix_to_quaternion)
_camera_centre = jax.jit(jp.geometry.camera_centre)
_observations = jax.jit(jp.observations)


def _perturbed(R, t, rng, angle_deg, rel_shift, depth):
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    dR = np.asarray(_rotvec_to_matrix(np.radians(angle_deg) * axis))
    return dR @ R, t + rel_shift * depth * rng.normal(size=3) / np.sqrt(3)


def _scenes(count=6, n=10, noise=1.0):
    rng = np.random.default_rng(11)
    scenes = [jp.default_bench()]
    scenes += [jp.apps.random_scene(rng, n, noise=noise) for _ in range(count)]
    return scenes


def _pad(scenes):
    """Stack scenes of different n into fixed shapes with a mask."""
    n = max(len(s.model_points) for s in scenes)
    C = np.stack([s.camera for s in scenes])
    M = np.zeros((len(scenes), n, 3))
    I = np.zeros((len(scenes), n, 2))
    mask = np.zeros((len(scenes), n), dtype=bool)
    for b, s in enumerate(scenes):
        k = len(s.model_points)
        M[b, :k], I[b, :k], mask[b, :k] = s.model_points, s.image_points, True
        M[b, k:], I[b, k:] = s.model_points[0], s.image_points[0]  # finite padding
    return C, M, I, mask


@jax.jit
def _run_both(C, M, I, mask, R0, t0):
    def one(C, M, I, mask, R0, t0):
        obs = jp.observations(C, M, I, mask)
        start = jp.Pose(R0, t0)
        lin3 = jp.solvers.linear(obs, start, iterations=3)
        lin = jp.solvers.linear(obs, start)
        raw = jp.solvers.linear(obs, start, iterations=8, weighting="raw")
        nl = jp.solvers.nonlinear(obs, start)
        return lin3, lin, raw, nl

    return jax.vmap(one)(C, M, I, mask, R0, t0)


def test_linear_and_nonlinear_reach_the_opencv_optimum():
    scenes = _scenes()
    rng = np.random.default_rng(5)
    C, M, I, mask = _pad(scenes)
    starts = []
    refs = []
    for s in scenes:
        R, t = opencv_optimum(s)
        refs.append((R, t))
        world = s.model_points @ s.R.T + s.t
        depth = np.linalg.norm(world.mean(0) - np.asarray(_camera_centre(s.camera)))
        starts.append(_perturbed(s.R, s.t, rng, 4.0, 0.03, depth))
    R0 = np.stack([r for r, _ in starts])
    t0 = np.stack([t for _, t in starts])
    lin3, lin, raw, nl = jax.tree.map(np.asarray, _run_both(C, M, I, mask, R0, t0))
    for b, s in enumerate(scenes):
        R_ref, t_ref = refs[b]
        e_ref = rms_px(s.camera, R_ref, t_ref, s.model_points, s.image_points)
        # the paper: 2-3 iterations of the linear method suffice from a good start
        assert int(lin3.status[b]) == jp.Status.OK
        assert abs(float(lin3.error[b]) - e_ref) < 1e-4
        assert int(lin.status[b]) == jp.Status.OK
        assert int(nl.status[b]) == jp.Status.OK
        assert abs(float(lin.error[b]) - e_ref) < 1e-6
        assert abs(float(nl.error[b]) - e_ref) < 1e-6
        np.testing.assert_allclose(lin.pose.R[b], R_ref, atol=1e-7)
        np.testing.assert_allclose(nl.pose.R[b], R_ref, atol=1e-7)
        scale = np.linalg.norm(t_ref) + 1
        np.testing.assert_allclose(lin.pose.t[b], t_ref, atol=1e-7 * scale)
        np.testing.assert_allclose(nl.pose.t[b], t_ref, atol=1e-7 * scale)
        # the raw (depth-weighted) rows converge to a nearby but different fixed point
        assert float(raw.error[b]) >= e_ref - 1e-9
        assert float(raw.error[b]) < e_ref * 1.05


def test_linear_reports_non_convergence_from_a_bad_start():
    b = jp.default_bench()
    obs = _observations(b.camera, b.model_points, b.image_points)
    rng = np.random.default_rng(0)
    R_ref, t_ref = opencv_optimum(b)
    e_ref = rms_px(b.camera, R_ref, t_ref, b.model_points, b.image_points)
    run = jax.jit(jax.vmap(lambda R, t: jp.solvers.linear(obs, jp.Pose(R, t), iterations=3)))
    starts = [_perturbed(b.R, b.t, rng, 150.0, 0.3, 2000.0) for _ in range(32)]
    res = run(np.stack([r for r, _ in starts]), np.stack([t for _, t in starts]))
    status = np.asarray(res.status)
    assert np.all(np.isfinite(res.pose.R)) and np.all(np.isfinite(res.error))
    # Far starts do not reach the optimum in three steps, and say so.
    reached = np.abs(np.asarray(res.error) - e_ref) < 1e-6
    assert np.all(reached | (status != jp.Status.OK))
    assert np.sum(status != jp.Status.OK) >= 16
    assert np.sum(status == jp.Status.LINEAR_NOT_CONVERGED) >= 4


def test_methods_on_too_few_points_and_degenerate_data():
    b = jp.default_bench()
    mask = np.zeros(16, dtype=bool)
    mask[:2] = True
    obs = _observations(b.camera, b.model_points, b.image_points, mask)
    # compiled (op by op, each of the solvers' operations would be compiled on its own)
    linear, nonlinear = jax.jit(jp.solvers.linear), jax.jit(jp.solvers.nonlinear)
    lin = linear(obs, jp.Pose(b.R, b.t))
    nl = nonlinear(obs, jp.Pose(b.R, b.t))
    assert int(lin.status) == jp.Status.TOO_FEW_POINTS
    assert int(nl.status) == jp.Status.TOO_FEW_POINTS
    for leaf in jax.tree.leaves((lin, nl)):
        assert np.all(np.isfinite(leaf))
    # all points behind the camera
    obs = _observations(b.camera, b.model_points, b.image_points)
    centre = np.asarray(_camera_centre(b.camera))
    behind = jp.Pose(b.R, 2 * centre - b.t)
    lin = jax.jit(functools.partial(jp.solvers.linear, iterations=1))(obs, behind)
    assert int(lin.status) != jp.Status.OK
    assert np.all(np.isfinite(lin.pose.t)) and np.isfinite(float(lin.error))


def test_float32_methods():
    b = jp.default_bench()
    obs = _observations(
        *(np.asarray(x, np.float32) for x in (b.camera, b.model_points, b.image_points))
    )
    rng = np.random.default_rng(2)
    R0, t0 = _perturbed(b.R, b.t, rng, 3.0, 0.02, 2000.0)
    start = jp.Pose(np.asarray(R0, np.float32), np.asarray(t0, np.float32))
    lin = jax.jit(jp.solvers.linear)(obs, start)
    nl = jax.jit(jp.solvers.nonlinear)(obs, start)
    R_ref, t_ref = opencv_optimum(b)
    e_ref = rms_px(b.camera, R_ref, t_ref, b.model_points, b.image_points)
    assert lin.pose.R.dtype == jnp.float32 and nl.pose.t.dtype == jnp.float32
    assert int(lin.status) == jp.Status.OK
    # float32: the optimum's error to ~1e-3 px, the translation to ~0.1 mm at 2 m
    assert abs(float(lin.error) - e_ref) < 2e-3
    assert abs(float(nl.error) - e_ref) < 2e-3
    np.testing.assert_allclose(np.asarray(lin.pose.t), t_ref, atol=0.5)


@pytest.mark.parametrize("residual", ["rotvec", "quaternion", "ray"])
def test_residual_jacobians_match_central_differences(residual):
    rng = np.random.default_rng(4)
    s = jp.apps.random_scene(rng, 8, noise=0.5)
    obs = _observations(s.camera, s.model_points, s.image_points)
    if residual == "rotvec":
        f, x = (
            jp.solvers.rotvec_residual,
            np.concatenate([np.asarray(_matrix_to_rotvec(s.R)), s.t]),
        )
    elif residual == "quaternion":
        q = np.asarray(_matrix_to_quaternion(s.R))
        f, x = jp.solvers.quaternion_residual, np.concatenate([q[1:] * np.sign(q[0]), s.t])
    else:
        f, x = jp.solvers.ray_residual, np.concatenate([np.asarray(_matrix_to_rotvec(s.R)), s.t])
    x = x + 1e-3 * rng.normal(size=6)
    fwd = np.asarray(jax.jit(jax.jacfwd(f))(x, obs))
    rev = np.asarray(jax.jit(jax.jacrev(f))(x, obs))
    f = jax.jit(f)
    fd = central_difference_jacobian(lambda y: f(y, obs), x, h=1e-6)
    np.testing.assert_allclose(fwd, rev, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(fwd, fd, rtol=1e-6, atol=1e-6 * np.abs(fd).max())


def test_compact_residual_has_the_residuals_derivatives():
    """Levenberg-Marquardt's residual with its Jacobian formed once (`_compact_residual`):
    same values, and the same derivatives in the chart coordinates and in the problem,
    forward and reverse, as the plain residual."""
    from jaxpose.solvers._chart import chart_at
    from jaxpose.solvers._nonlinear import _compact_residual, _residual

    rng = np.random.default_rng(9)
    s = jp.apps.random_scene(rng, 8, noise=0.5)
    obs = _observations(s.camera, s.model_points, s.image_points)
    init = jp.geometry.Pose(s.R, s.t)

    @jax.jit
    def chart_and_base(obs, init):
        base = jp.geometry.transform(init, obs.model)
        return chart_at(init, obs, base), base

    chart, base = chart_and_base(obs, init)
    args = (obs, chart, base)

    @jax.jit
    def derivatives(y, image, y_dot, image_dot):
        out = []
        for f in (_compact_residual, _residual):
            g = lambda y, image, f=f: f(y, (args[0]._replace(image=image), *args[1:]))
            out.append(
                (
                    jax.jvp(g, (y, image), (y_dot, image_dot)),
                    jax.jacfwd(g)(y, image),
                    jax.jacrev(g, argnums=(0, 1))(y, image),
                )
            )
        return out

    y, y_dot = (x * rng.normal(size=6) for x in (1e-2, 1.0))
    image_dot = rng.normal(size=obs.image.shape)
    got, want = derivatives(y, obs.image, y_dot, image_dot)
    for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(want), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)


def test_residuals_vanish_at_the_true_pose():
    b = jp.default_bench(noise=0.0)
    obs = _observations(b.camera, b.model_points, b.image_points)
    r = np.asarray(_matrix_to_rotvec(b.R))
    q = np.asarray(_matrix_to_quaternion(b.R))
    rotvec, quaternion, ray = (
        jax.jit(f)
        for f in (
            jp.solvers.rotvec_residual,
            jp.solvers.quaternion_residual,
            jp.solvers.ray_residual,
        )
    )
    assert np.abs(rotvec(np.concatenate([r, b.t]), obs)).max() < 1e-8
    assert np.abs(quaternion(np.concatenate([q[1:], b.t]), obs)).max() < 1e-8
    assert np.abs(ray(np.concatenate([r, b.t]), obs)).max() < 1e-5
