"""Tests of jaxpose.apps._robot: forward and inverse kinematics of the paper's 4-DOF robot."""

import math

import cv2
import hypothesis.strategies as st
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings

import jaxpose as jp
from jaxpose.apps import RobotStatus
from jaxpose.apps._robot import (
    Robot,
    default_robot,
    forward_kinematics,
    inverse_kinematics,
    joint_command,
)

ROBOT = default_robot()
DEG = math.pi / 180

fk = jax.jit(jax.vmap(forward_kinematics, in_axes=(None, 0)))
ik = jax.jit(jax.vmap(inverse_kinematics, in_axes=(None, 0, 0)))


def ik_free(robot, targets):
    """IK without an approach direction (a zero approach means none)."""
    return ik(robot, targets, np.zeros_like(targets))


def reference_tip(robot, q):
    """The tip by chaining homogeneous transforms (numpy, OpenCV's Rodrigues for the
    rotations): carriage translation, pan about z, tilt about the turret's y, shank."""
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = robot.base_R, robot.base_t

    def link(R=np.eye(3), p=np.zeros(3)):
        A = np.eye(4)
        A[:3, :3], A[:3, 3] = R, p
        return A

    T = T @ link(p=np.array([q[0], q[1], float(robot.height)]))
    T = T @ link(R=cv2.Rodrigues(np.array([0.0, 0.0, q[2]]))[0])
    # Tilt turns the downward shank towards the turret's +x: a rotation by -tilt about y.
    T = T @ link(R=cv2.Rodrigues(np.array([0.0, -q[3], 0.0]))[0])
    return (T @ np.array([0.0, 0.0, -float(robot.shank), 1.0]))[:3]


def random_joints(rng, robot, n):
    return rng.uniform(np.asarray(robot.lower), np.asarray(robot.upper), size=(n, 4))


def test_forward_kinematics_against_a_transform_chain():
    rng = np.random.default_rng(0)
    q = random_joints(rng, ROBOT, 64)
    state = fk(ROBOT, q)
    ref = np.stack([reference_tip(ROBOT, qi) for qi in q])
    np.testing.assert_allclose(state.tip, ref, atol=1e-9)
    # The shank is a unit vector of the right length from the wrist.
    np.testing.assert_allclose(
        np.linalg.norm(np.asarray(state.tip - state.wrist), axis=1), float(ROBOT.shank)
    )
    np.testing.assert_allclose(np.asarray(state.wrist)[:, 2], float(ROBOT.height))
    # Frames: proper rotations; the tool frame sits at the tip with z along the shank.
    F = np.asarray(state.frames)
    Rs = F[:, :, :3, :3]
    np.testing.assert_allclose(
        Rs @ Rs.transpose(0, 1, 3, 2), np.broadcast_to(np.eye(3), Rs.shape), atol=1e-12
    )
    np.testing.assert_allclose(np.linalg.det(Rs), 1.0, atol=1e-12)
    np.testing.assert_allclose(F[:, 3, :3, 3], state.tip, atol=1e-12)
    np.testing.assert_allclose(F[:, 3, :3, 2], state.shank, atol=1e-12)
    np.testing.assert_allclose(F[:, 1, :3, 3], state.wrist, atol=1e-12)
    np.testing.assert_allclose(F[:, :, 3, :], np.broadcast_to([0, 0, 0, 1.0], F[:, :, 3, :].shape))


def test_straight_down_and_dimensions():
    state = fk(ROBOT, np.array([[10.0, -20.0, 0.7, 0.0]]))
    np.testing.assert_allclose(state.tip[0], [10.0, -20.0, 300.0 - 320.0], atol=1e-12)
    np.testing.assert_allclose(state.shank[0], [0.0, 0.0, -1.0], atol=1e-12)


@settings(max_examples=40)
@given(seed=st.integers(0, 2**31 - 1))
def test_fk_of_ik_is_the_target(seed):
    """Reachable targets (the tips of random joints within limits), with random approach
    directions or none: FK(IK(x)) == x, within the limits."""
    rng = np.random.default_rng(seed)
    q = random_joints(rng, ROBOT, 16)
    # Keep the carriage well inside its travel so that every azimuth stays reachable.
    q[:, :2] *= 0.2
    targets = np.asarray(fk(ROBOT, q).tip)
    approach = rng.normal(size=(16, 3))
    for out in (ik(ROBOT, targets, approach), ik_free(ROBOT, targets)):
        assert np.all(np.asarray(out.status) == RobotStatus.OK)
        np.testing.assert_allclose(fk(ROBOT, out.joints).tip, targets, atol=1e-9)
        assert np.all(np.asarray(out.error) < 1e-9)
        j = np.asarray(out.joints)
        assert np.all(j >= np.asarray(ROBOT.lower) - 1e-12)
        assert np.all(j <= np.asarray(ROBOT.upper) + 1e-12)


def test_ik_with_the_shank_as_approach_returns_the_joints():
    """Asking for the shank direction that FK produced gives back the same joints."""
    rng = np.random.default_rng(1)
    q = random_joints(rng, ROBOT, 32)
    q[:, :2] *= 0.5
    q[:, 3] = np.abs(q[:, 3]) + 1 * DEG  # tilt > 0, so the pan is determined
    state = fk(ROBOT, q)
    out = ik(ROBOT, state.tip, state.shank)
    assert np.all(np.asarray(out.status) == RobotStatus.OK)
    np.testing.assert_allclose(out.joints, q, atol=1e-9)
    np.testing.assert_allclose(out.approach_angle, 0.0, atol=1e-6)


def test_approach_sets_the_azimuth():
    target = np.array([[40.0, 25.0, 20.0]] * 3)
    approach = np.array([[1.0, 0.0, -1.0], [0.0, -1.0, -0.2], [0.0, 0.0, -1.0]])
    out = ik(ROBOT, target, approach)
    state = fk(ROBOT, out.joints)
    s = np.asarray(state.shank)
    np.testing.assert_allclose(np.arctan2(s[:2, 1], s[:2, 0]), [0.0, -math.pi / 2], atol=1e-12)
    # Height fixes the tilt: cos(tilt) = (h - z) / L for every approach.
    np.testing.assert_allclose(
        np.abs(np.asarray(out.joints)[:, 3]), math.acos(280 / 320), atol=1e-12
    )
    # Vertical approach: the shank leans outwards, away from the base's axis.
    np.testing.assert_allclose(math.atan2(s[2, 1], s[2, 0]), math.atan2(25.0, 40.0), atol=1e-12)


def test_unreachable_and_joint_limits_are_flagged():
    targets = np.array(
        [
            [0.0, 0.0, -40.0],  # below the shank's reach (h - L = -20)
            [0.0, 0.0, 700.0],  # above the wrist by more than L
            [0.0, 0.0, 280.0],  # within L of the wrist, but needs tilt > 80 deg
            [900.0, 0.0, 20.0],  # carriage beyond its travel
            [np.nan, 0.0, 20.0],
        ]
    )
    out = ik_free(ROBOT, targets)
    assert np.asarray(out.status).tolist() == [
        RobotStatus.UNREACHABLE,
        RobotStatus.UNREACHABLE,
        RobotStatus.JOINT_LIMITS,
        RobotStatus.JOINT_LIMITS,
        RobotStatus.NOT_FINITE,
    ]
    for x in out:
        assert np.all(np.isfinite(x))
    # Placeholders are within the limits.
    j = np.asarray(out.joints)
    assert np.all((j >= np.asarray(ROBOT.lower)) & (j <= np.asarray(ROBOT.upper)))
    with pytest.raises(ValueError, match="out of the robot's reach"):
        joint_command(ROBOT, targets[0])
    with pytest.raises(ValueError, match="tilt"):
        joint_command(ROBOT, targets[2])
    with pytest.raises(ValueError, match="carriage"):
        joint_command(ROBOT, targets[3])
    with pytest.raises(ValueError, match="target"):
        joint_command(ROBOT, targets[4])
    with pytest.raises(ValueError, match="approach"):
        joint_command(ROBOT, targets[3], approach=[1.0, 0.0])


def test_joint_limits_choose_another_solution():
    """Pan limited to [-90, 90] deg: a shank leaning towards -x needs the other tilt sign
    (pan + pi, -tilt), the same shank."""
    lower = np.asarray(ROBOT.lower).copy()
    upper = np.asarray(ROBOT.upper).copy()
    lower[2], upper[2] = -90 * DEG, 90 * DEG
    robot = ROBOT._replace(lower=lower, upper=upper)
    out = ik(robot, np.array([[0.0, 0.0, 100.0]]), np.array([[-1.0, 0.0, 0.0]]))
    assert int(out.status[0]) == RobotStatus.OK
    x, y, pan, tilt = np.asarray(out.joints[0])
    assert abs(pan) < 1e-12 and tilt < 0
    state = fk(robot, out.joints)
    np.testing.assert_allclose(state.tip[0], [0.0, 0.0, 100.0], atol=1e-9)
    assert state.shank[0, 0] < 0  # still leaning towards -x
    # Carriage limited to a small box: the azimuth moves to one that fits.
    lower[:2], upper[:2] = [-50.0, -50.0], [50.0, 50.0]
    robot = ROBOT._replace(lower=lower, upper=upper)
    out = ik(robot, np.array([[200.0, 0.0, 100.0]]), np.array([[-1.0, 0.0, 0.0]]))
    assert int(out.status[0]) == RobotStatus.OK
    np.testing.assert_allclose(fk(robot, out.joints).tip[0], [200.0, 0.0, 100.0], atol=1e-9)
    j = np.asarray(out.joints[0])
    assert np.all((j >= lower - 1e-12) & (j <= upper + 1e-12))


def test_moved_base():
    """A base turned and shifted in the world: FK(IK(x)) == x in world coordinates."""
    R = cv2.Rodrigues(np.array([0.0, 0.0, 0.6]))[0]
    robot = ROBOT._replace(base_R=R, base_t=np.array([100.0, -50.0, 5.0]))
    rng = np.random.default_rng(3)
    q = random_joints(rng, robot, 16)
    q[:, :2] *= 0.2
    state = fk(robot, q)
    np.testing.assert_allclose(
        state.tip, np.stack([reference_tip(robot, qi) for qi in q]), atol=1e-9
    )
    out = ik_free(robot, state.tip)
    assert np.all(np.asarray(out.status) == RobotStatus.OK)
    np.testing.assert_allclose(fk(robot, out.joints).tip, state.tip, atol=1e-9)


def test_the_robot_reaches_points_on_the_bench_object():
    """Points on every face of the bench object that the camera sees: reachable, the tip
    gets there, the shank pointing into the face from outside."""
    bench = jp.default_bench()
    model = bench.model
    world = model.vertices @ bench.R.T + bench.t
    centre = np.asarray(jp.geometry.camera_centre(bench.camera))
    outline = model.vertices[:12, :2].astype(np.float32).reshape(-1, 1, 2)
    rng = np.random.default_rng(4)
    points, normals = [], []
    for face in model.faces:
        P = world[list(face)]
        n = np.cross(P[1] - P[0], P[2] - P[0])
        n /= np.linalg.norm(n)
        if n @ (centre - P[0]) <= 0:
            continue  # not seen by the camera
        if len(face) == 4:  # a side: a rectangle, convex
            samples = rng.dirichlet(np.ones(4), size=4) @ P
        else:  # the top: points of the plate's outline (not convex), on its plane
            xy = rng.uniform(-80.0, 75.0, size=(64, 2))
            inside = [cv2.pointPolygonTest(outline, tuple(map(float, p)), False) > 0 for p in xy]
            m = np.column_stack([xy[inside][:8], np.full(min(8, sum(inside)), 10.0)])
            samples = m @ bench.R.T + bench.t
        points += list(samples)
        normals += [n] * len(samples)
    points, normals = np.asarray(points), np.asarray(normals)
    assert len(points) >= 24
    out = ik(ROBOT, points, -normals)
    assert np.all(np.asarray(out.status) == RobotStatus.OK)
    state = fk(ROBOT, out.joints)
    np.testing.assert_allclose(state.tip, points, atol=1e-9)
    assert np.all(np.sum(np.asarray(state.shank) * normals, axis=1) < 0)
    # joint_command (the numpy boundary) agrees with the batched solver.
    np.testing.assert_allclose(joint_command(ROBOT, points[0], -normals[0]), out.joints[0])


def test_float32_and_gradient():
    q = np.array([10.0, -20.0, 0.3, 0.5])
    r32 = Robot(*(np.asarray(x, np.float32) for x in ROBOT))
    tip32 = jax.jit(forward_kinematics)(r32, q.astype(np.float32)).tip
    assert tip32.dtype == jnp.float32
    tip64 = fk(ROBOT, q[None]).tip[0]
    np.testing.assert_allclose(tip32, tip64, atol=1e-3)
    J = jax.jit(jax.jacfwd(lambda q: forward_kinematics(ROBOT, q).tip))(q)
    h = 1e-6
    fd = np.stack(
        [
            (reference_tip(ROBOT, q + h * e) - reference_tip(ROBOT, q - h * e)) / (2 * h)
            for e in np.eye(4)
        ],
        axis=1,
    )
    np.testing.assert_allclose(J, fd, atol=1e-6)


def test_shape_errors():
    with pytest.raises(ValueError, match="joints"):
        forward_kinematics(ROBOT, np.zeros(3))
    with pytest.raises(ValueError, match="target"):
        inverse_kinematics(ROBOT, np.zeros(2))
    with pytest.raises(ValueError, match="robot.lower"):
        forward_kinematics(ROBOT._replace(lower=np.zeros(3)), np.zeros(4))
