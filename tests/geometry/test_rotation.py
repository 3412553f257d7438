"""Tests of jaxpose.geometry._rotation: the four parameterisations, singular points, gradients.

Tolerances: float64 round trips to `1e-12` (absolute, radians or matrix entries), except
the 3-parameter quaternion near a half turn (`1e-7`, a limit of that parameterisation);
float32 results agree with float64 to `FLOAT32_ATOL = 2e-6`; Jacobians agree with central
differences (step `1e-6`, float64) to `1e-7` relative to their largest entry.

Compilation dominates the run time, so every function is jitted once (lazily) and reused.
"""

import functools

import cv2
import hypothesis.strategies as st
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given

from jaxpose.geometry._euler import matrix_to_rpy, rpy_to_matrix
from jaxpose.geometry._rotation import (
    compose,
    hat,
    matrix_to_quaternion,
    matrix_to_rotvec,
    project_to_rotation,
    quaternion_conjugate,
    quaternion_multiply,
    quaternion_to_matrix,
    quaternion_to_rotvec,
    quaternion_vector_to_matrix,
    rotation_angle,
    rotation_distance,
    rotvec_to_matrix,
    rotvec_to_quaternion,
)

ATOL = 1e-12
FLOAT32_ATOL = 2e-6
FD_STEP = 1e-6
FD_ATOL = 1e-7
PI = np.pi

# Every public function as a function of one array (two-argument ones curried with a fixed
# rotation, cast to the input dtype). Each is jitted once, lazily, and reused everywhere:
# XLA compilation, not arithmetic, is what this file spends its time on.
_R_FIXED = cv2.Rodrigues(np.array([0.5, 0.2, 0.7]))[0]
_P_FIXED = np.array([0.8, -0.2, 0.5, 0.1]) / np.linalg.norm([0.8, -0.2, 0.5, 0.1])

FUNCTIONS = {
    "hat": hat,
    "rotvec_to_matrix": rotvec_to_matrix,
    "matrix_to_rotvec": matrix_to_rotvec,
    "quaternion_to_matrix": quaternion_to_matrix,
    "matrix_to_quaternion": matrix_to_quaternion,
    "quaternion_vector_to_matrix": quaternion_vector_to_matrix,
    "rotvec_to_quaternion": rotvec_to_quaternion,
    "quaternion_to_rotvec": quaternion_to_rotvec,
    "quaternion_multiply": lambda q: quaternion_multiply(jnp.asarray(_P_FIXED, q.dtype), q),
    "quaternion_conjugate": quaternion_conjugate,
    "compose": lambda R: compose(jnp.asarray(_R_FIXED, R.dtype), R),
    "rpy_to_matrix": rpy_to_matrix,
    "matrix_to_rpy": lambda R: jnp.concatenate(matrix_to_rpy(R)[:2]),
    "rotation_angle": rotation_angle,
    "rotation_distance": lambda R: rotation_distance(jnp.asarray(_R_FIXED, R.dtype), R),
    "project_to_rotation": project_to_rotation,
}
INPUT_KIND = {
    "hat": "vec",
    "rotvec_to_matrix": "vec",
    "matrix_to_rotvec": "mat",
    "quaternion_to_matrix": "quat",
    "matrix_to_quaternion": "mat",
    "quaternion_vector_to_matrix": "qvec",
    "rotvec_to_quaternion": "vec",
    "quaternion_to_rotvec": "quat",
    "quaternion_multiply": "quat",
    "quaternion_conjugate": "quat",
    "compose": "mat",
    "rpy_to_matrix": "rpy",
    "matrix_to_rpy": "mat",
    "rotation_angle": "mat",
    "rotation_distance": "mat",
    "project_to_rotation": "anymat",
}


@functools.cache
def jitted(name):
    """`jax.jit(f)`: one rotation in, one result out."""
    return jax.jit(FUNCTIONS[name])


@functools.cache
def jitted_vmap(name):
    return jax.jit(jax.vmap(FUNCTIONS[name]))


@functools.cache
def jacobians(name):
    """`x -> (jax.jacfwd(f)(x), jax.jacrev(f)(x))`, jitted together."""
    f = FUNCTIONS[name]
    return jax.jit(lambda x: (jax.jacfwd(f)(x), jax.jacrev(f)(x)))


def call(name, x):
    return np.asarray(jitted(name)(x))


def rotvec_to_matrix_j(r):
    return call("rotvec_to_matrix", r)


def matrix_to_rotvec_j(R):
    return call("matrix_to_rotvec", R)


def quaternion_to_matrix_j(q):
    return call("quaternion_to_matrix", q)


def matrix_to_quaternion_j(R):
    return call("matrix_to_quaternion", R)


def rotvec_to_quaternion_j(r):
    return call("rotvec_to_quaternion", r)


def quaternion_to_rotvec_j(q):
    return call("quaternion_to_rotvec", q)


def quaternion_vector_to_matrix_j(qv):
    return call("quaternion_vector_to_matrix", qv)


def rpy_to_matrix_j(rpy):
    return call("rpy_to_matrix", rpy)


def rotation_angle_j(R):
    return call("rotation_angle", R)


def project_to_rotation_j(M):
    return call("project_to_rotation", M)


def matrix_to_rpy_j(R):
    """`(rpy_a, rpy_b, singular)`."""
    a, b, singular = _matrix_to_rpy_jit(R)
    return np.asarray(a), np.asarray(b), bool(singular)


_matrix_to_rpy_jit = jax.jit(matrix_to_rpy)
rotation_distance_j = jax.jit(rotation_distance)
quaternion_multiply_j = jax.jit(quaternion_multiply)


# --------------------------------------------------------------------------- helpers


def unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def random_axis(rng):
    return unit(rng.normal(size=3))


def random_quaternion(rng):
    """Uniform over rotations (normalised Gaussian), returned with q0 >= 0."""
    q = unit(rng.normal(size=4))
    return q if q[0] >= 0 else -q


def np_quaternion_to_matrix(q):
    """Reference: the paper's (A.14), in numpy, for a unit quaternion."""
    q0, q1, q2, q3 = q
    return np.array(
        [
            [2 * (q0**2 + q1**2) - 1, 2 * (q1 * q2 - q0 * q3), 2 * (q1 * q3 + q0 * q2)],
            [2 * (q1 * q2 + q0 * q3), 2 * (q0**2 + q2**2) - 1, 2 * (q2 * q3 - q0 * q1)],
            [2 * (q1 * q3 - q0 * q2), 2 * (q2 * q3 + q0 * q1), 2 * (q0**2 + q3**2) - 1],
        ]
    )


def random_rotation(rng):
    """Uniform over rotations."""
    return np_quaternion_to_matrix(random_quaternion(rng))


def random_input(kind, rng):
    if kind == "vec":
        return rng.normal(size=3)
    if kind == "qvec":
        return random_axis(rng) * rng.uniform(0.05, 0.95)
    if kind == "quat":
        return random_quaternion(rng) * rng.uniform(0.5, 2.0)
    if kind == "mat":
        return random_rotation(rng)
    if kind == "rpy":
        return np.array([rng.uniform(-3, 3), rng.uniform(-1.3, 1.3), rng.uniform(-3, 3)])
    if kind == "anymat":
        return rng.normal(size=(3, 3))
    raise ValueError(kind)


def numerical_jacobian(f, x, h=FD_STEP):
    """Central-difference Jacobian of `f` at `x`, shape `f(x).shape + x.shape`."""
    x = np.asarray(x, dtype=np.float64)
    columns = []
    for i in range(x.size):
        e = np.zeros(x.size)
        e[i] = h
        e = e.reshape(x.shape)
        columns.append((np.asarray(f(x + e)) - np.asarray(f(x - e))) / (2 * h))
    return np.stack(columns, axis=-1).reshape(np.shape(f(x)) + x.shape)


def angle_diff(a, b):
    """Elementwise difference of angles, wrapped to [-pi, pi)."""
    return (np.asarray(a) - np.asarray(b) + PI) % (2 * PI) - PI


def assert_rotation(R, atol=ATOL):
    R = np.asarray(R)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=atol)
    assert abs(np.linalg.det(R) - 1.0) < atol


def assert_same_rotvec(r_out, r_ref, atol=ATOL):
    """Equal; or, for a half turn (where both are correct), possibly opposite."""
    r_out, r_ref = np.asarray(r_out), np.asarray(r_ref)
    if np.linalg.norm(r_ref) < PI - 1e-6:
        np.testing.assert_allclose(r_out, r_ref, atol=atol, rtol=0)
    else:
        err = min(np.abs(r_out - r_ref).max(), np.abs(r_out + r_ref).max())
        assert err < atol, (r_out, r_ref)


def assert_same_quaternion(q_out, q_ref, atol=ATOL):
    """Equal up to sign (q and -q are the same rotation)."""
    q_out, q_ref = np.asarray(q_out), unit(q_ref)
    err = min(np.abs(q_out - q_ref).max(), np.abs(q_out + q_ref).max())
    assert err < atol, (q_out, q_ref)


# Angle regimes: uniform, near identity, identity, around the Taylor switch, near pi, pi.
ANGLE_REGIMES = {
    "uniform": lambda rng: rng.uniform(0, PI),
    "small_1e-7": lambda rng: 1e-7 * rng.uniform(0.1, 1),
    "small_1e-12": lambda rng: 1e-12 * rng.uniform(0.1, 1),
    "zero": lambda rng: 0.0,
    "taylor_switch": lambda rng: rng.uniform(5e-3, 3e-2),
    "near_pi_1e-6": lambda rng: PI - 1e-6 * rng.uniform(0.1, 1),
    "near_pi_1e-9": lambda rng: PI - 1e-9 * rng.uniform(0.1, 1),
    "pi": lambda rng: PI,
}


def rotvecs_for(regime, rng, n=12):
    return [random_axis(rng) * ANGLE_REGIMES[regime](rng) for _ in range(n)]


# Hypothesis strategies, with near-singular samples drawn on purpose.
axes = (
    st.tuples(*[st.floats(-1, 1) for _ in range(3)])
    .map(np.array)
    .filter(lambda v: np.linalg.norm(v) > 1e-3)
    .map(unit)
)
angles = st.one_of(
    st.floats(0, PI),
    st.floats(0, 1e-6),
    st.floats(PI - 1e-6, PI),
    st.sampled_from([0.0, 1e-300, 1e-12, 1e-7, PI - 1e-9, PI]),
)
rotvecs = st.builds(lambda u, t: u * t, axes, angles)
quaternions = st.one_of(
    st.tuples(*[st.floats(-1, 1) for _ in range(4)]).map(np.array),
    st.builds(lambda u, t: np.concatenate([[1.0], t * u]), axes, st.floats(0, 1e-6)),
    st.builds(lambda u, t: np.concatenate([[t], u]), axes, st.floats(-1e-6, 1e-6)),
).filter(lambda q: np.linalg.norm(q) > 1e-3)
pitches = st.one_of(
    st.floats(-PI / 2, PI / 2),
    st.sampled_from([PI / 2, -PI / 2, PI / 2 - 1e-9, -PI / 2 + 1e-9, PI / 2 - 1e-14, 0.0]),
)
rpys = st.builds(
    lambda r, p, y: np.array([r, p, y]), st.floats(-PI, PI), pitches, st.floats(-PI, PI)
)


# --------------------------------------------------------------------------- hat, compose


def test_hat_is_cross_product(rng):
    for _ in range(5):
        v, w = rng.normal(size=3), rng.normal(size=3)
        X = call("hat", v)
        np.testing.assert_allclose(X @ w, np.cross(v, w), atol=ATOL)
        np.testing.assert_array_equal(X, -X.T)


def test_compose_is_matmul(rng):
    R = random_rotation(rng)
    np.testing.assert_allclose(call("compose", R), _R_FIXED @ R, atol=ATOL)


# --------------------------------------------------------------------------- rotation vector


@pytest.mark.parametrize("regime", list(ANGLE_REGIMES))
def test_rotvec_matrix_round_trip(regime, rng):
    for r in rotvecs_for(regime, rng):
        R = rotvec_to_matrix_j(r)
        assert_rotation(R)
        r_back = matrix_to_rotvec_j(R)
        assert_same_rotvec(r_back, r)
        assert np.linalg.norm(r_back) <= PI + 1e-15
        np.testing.assert_allclose(rotvec_to_matrix_j(r_back), R, atol=ATOL)


def test_uniform_random_rotations_round_trip(rng):
    """Haar-uniform matrices through every parameterisation and back."""
    for _ in range(10):
        R = random_rotation(rng)
        np.testing.assert_allclose(rotvec_to_matrix_j(matrix_to_rotvec_j(R)), R, atol=ATOL)
        q = matrix_to_quaternion_j(R)
        np.testing.assert_allclose(quaternion_to_matrix_j(q), R, atol=ATOL)
        np.testing.assert_allclose(quaternion_vector_to_matrix_j(q[1:]), R, atol=1e-10)
        for rpy in matrix_to_rpy_j(R)[:2]:
            np.testing.assert_allclose(rpy_to_matrix_j(rpy), R, atol=ATOL)


def test_rotvec_special_values():
    np.testing.assert_array_equal(rotvec_to_matrix_j(np.zeros(3)), np.eye(3))
    np.testing.assert_array_equal(matrix_to_rotvec_j(np.eye(3)), np.zeros(3))
    # Exact half turns: the axis comes (up to sign) from the symmetric part.
    for k in range(3):
        D = -np.ones(3)
        D[k] = 1.0
        assert_same_rotvec(matrix_to_rotvec_j(np.diag(D)), PI * np.eye(3)[k])


def test_rotvec_agrees_with_opencv(rng):
    for regime in ANGLE_REGIMES:
        for r in rotvecs_for(regime, rng, 6):
            R = rotvec_to_matrix_j(r)
            R_cv, _ = cv2.Rodrigues(r)
            np.testing.assert_allclose(R, R_cv, atol=1e-12)
            r_cv = cv2.Rodrigues(R_cv)[0][:, 0]
            theta = np.linalg.norm(r)
            if theta < 1e-4:  # OpenCV snaps angles below 1e-5 rad to exactly zero
                np.testing.assert_allclose(matrix_to_rotvec_j(R_cv), r_cv, atol=1e-5)
            elif theta < PI - 1e-3:
                np.testing.assert_allclose(matrix_to_rotvec_j(R_cv), r_cv, atol=1e-10)
            else:  # near pi OpenCV picks its own sign, and is less accurate
                assert_same_rotvec(matrix_to_rotvec_j(R_cv), r_cv, atol=1e-6)


# --------------------------------------------------------------------------- quaternions


@pytest.mark.parametrize("regime", list(ANGLE_REGIMES))
def test_quaternion_matrix_round_trip(regime, rng):
    for r in rotvecs_for(regime, rng):
        q = rotvec_to_quaternion_j(r)
        np.testing.assert_allclose(np.linalg.norm(q), 1.0, atol=ATOL)
        R = quaternion_to_matrix_j(q)
        np.testing.assert_allclose(R, np_quaternion_to_matrix(q), atol=ATOL)
        q_back = matrix_to_quaternion_j(R)
        assert q_back[0] >= 0
        assert_same_quaternion(q_back, q)
        assert_same_rotvec(quaternion_to_rotvec_j(q), r)
        # Consistency: rotvec -> quaternion -> matrix == rotvec -> matrix.
        np.testing.assert_allclose(R, rotvec_to_matrix_j(r), atol=ATOL)


def test_quaternion_normalisation_and_zero(rng):
    q = random_quaternion(rng)
    R = quaternion_to_matrix_j(q)
    np.testing.assert_allclose(quaternion_to_matrix_j(3.7 * q), R, atol=ATOL)
    np.testing.assert_allclose(quaternion_to_matrix_j(-0.01 * q), R, atol=ATOL)
    assert_same_rotvec(quaternion_to_rotvec_j(-5.0 * q), matrix_to_rotvec_j(R))
    np.testing.assert_array_equal(quaternion_to_matrix_j(np.zeros(4)), np.eye(3))
    np.testing.assert_array_equal(quaternion_to_rotvec_j(np.zeros(4)), np.zeros(3))


def test_quaternion_multiply_and_conjugate(rng):
    for _ in range(5):
        p, q = random_quaternion(rng), random_quaternion(rng)
        pq = np.asarray(quaternion_multiply_j(p, q))
        P, Q = np_quaternion_to_matrix(p), np_quaternion_to_matrix(q)
        np.testing.assert_allclose(quaternion_to_matrix_j(pq), P @ Q, atol=ATOL)
        np.testing.assert_allclose(np.linalg.norm(pq), 1.0, atol=ATOL)
        q_inv = call("quaternion_conjugate", q)
        np.testing.assert_allclose(quaternion_to_matrix_j(q_inv), Q.T, atol=ATOL)
        np.testing.assert_allclose(quaternion_multiply_j(q, q_inv), [1, 0, 0, 0], atol=ATOL)


# The vector part alone pins q0 = sqrt(1 - |qv|^2) down to ~sqrt(eps) absolute only,
# where |qv| ~ 1 (theta ~ pi): rounding of |qv|^2 is amplified by the square root.
QV_ATOL_NEAR_PI = 1e-7


@pytest.mark.parametrize("regime", list(ANGLE_REGIMES))
def test_quaternion_vector_round_trip(regime, rng):
    atol = QV_ATOL_NEAR_PI if regime.startswith(("near_pi", "pi")) else ATOL
    for r in rotvecs_for(regime, rng):
        R = rotvec_to_matrix_j(r)
        q = matrix_to_quaternion_j(R)  # q0 >= 0
        np.testing.assert_allclose(quaternion_vector_to_matrix_j(q[1:]), R, atol=atol)


def test_quaternion_vector_outside_unit_ball(rng):
    u = random_axis(rng)
    R_half_turn = np_quaternion_to_matrix(np.concatenate([[0.0], u]))
    for scale in [1.0, 1.0 + 1e-12, 1.5, 10.0]:
        np.testing.assert_allclose(
            quaternion_vector_to_matrix_j(scale * u), R_half_turn, atol=QV_ATOL_NEAR_PI
        )
    np.testing.assert_allclose(quaternion_vector_to_matrix_j(10.0 * u), R_half_turn, atol=ATOL)
    # Continuous across |qv| = 1.
    inside = quaternion_vector_to_matrix_j((1 - 1e-12) * u)
    np.testing.assert_allclose(inside, R_half_turn, atol=1e-5)
    np.testing.assert_array_equal(quaternion_vector_to_matrix_j(np.zeros(3)), np.eye(3))


# --------------------------------------------------------------------------- roll-pitch-yaw


def elementary(axis, a):
    c, s = np.cos(a), np.sin(a)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


def test_rpy_matches_elementary_rotations(rng):
    for _ in range(5):
        roll, pitch, yaw = rng.uniform(-3, 3, size=3)
        expected = elementary(2, yaw) @ elementary(1, pitch) @ elementary(0, roll)
        np.testing.assert_allclose(
            rpy_to_matrix_j(np.array([roll, pitch, yaw])), expected, atol=ATOL
        )


def check_rpy_solutions(rpy):
    R = rpy_to_matrix_j(rpy)
    a, b, singular = matrix_to_rpy_j(R)
    for sol in (a, b):
        np.testing.assert_allclose(rpy_to_matrix_j(sol), R, atol=ATOL)
        assert np.all(sol > -PI) and np.all(sol <= PI), sol
    assert -PI / 2 <= a[1] <= PI / 2
    np.testing.assert_allclose(angle_diff(b[1], PI - a[1]), 0.0, atol=1e-15)
    cos_pitch = abs(np.cos(rpy[1]))
    if cos_pitch < 1e-16:
        assert singular
    if cos_pitch > 1e-14:
        assert not singular
    if singular:
        assert a[0] == 0 and b[0] == 0 and a[2] == b[2]
    else:
        np.testing.assert_allclose(angle_diff(b[[0, 2]], a[[0, 2]] + PI), 0.0, atol=1e-15)
    if cos_pitch > 1e-4:  # away from gimbal lock the input itself is recovered
        np.testing.assert_allclose(angle_diff(a, rpy), 0.0, atol=1e-10)
    return a, b, singular


def test_rpy_round_trip_random(rng):
    for _ in range(20):
        rpy = np.array([rng.uniform(-PI, PI), rng.uniform(-1.5, 1.5), rng.uniform(-PI, PI)])
        _, _, singular = check_rpy_solutions(rpy)
        assert not singular


@pytest.mark.parametrize("pitch", [PI / 2, -PI / 2, PI / 2 - 1e-9, -PI / 2 + 1e-13])
def test_rpy_near_gimbal_lock(pitch, rng):
    for _ in range(5):
        check_rpy_solutions(np.array([rng.uniform(-3, 3), pitch, rng.uniform(-3, 3)]))


def exact_gimbal_lock_matrix(roll, yaw, sign):
    """Rz(yaw) Ry(sign 90 deg) Rx(roll) with Ry exact, so that R00 = R10 = 0 exactly."""
    Ry = np.array([[0.0, 0, sign], [0, 1, 0], [-sign, 0, 0]])
    return elementary(2, yaw) @ Ry @ elementary(0, roll)


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_rpy_exact_gimbal_lock(sign):
    R = exact_gimbal_lock_matrix(0.4, -1.1, sign)
    assert R[0, 0] == 0 and R[1, 0] == 0
    a, b, singular = matrix_to_rpy_j(R)
    assert singular
    # Roll 0; yaw carries yaw - roll (pitch +90 deg) or yaw + roll (pitch -90 deg).
    np.testing.assert_allclose(a, [0.0, sign * PI / 2, -1.1 - sign * 0.4], atol=ATOL)
    np.testing.assert_allclose(b, a, atol=ATOL)


# --------------------------------------------------------------------------- angle, distance


@pytest.mark.parametrize("regime", list(ANGLE_REGIMES))
def test_rotation_angle_and_distance(regime, rng):
    for r in rotvecs_for(regime, rng, 6):
        theta = np.linalg.norm(r)
        R = rotvec_to_matrix_j(r)
        assert abs(rotation_angle_j(R) - theta) < ATOL
        R1 = random_rotation(rng)
        assert abs(rotation_distance_j(R1, R1 @ R) - theta) < ATOL
        assert abs(rotation_distance_j(R1 @ R, R1) - theta) < ATOL
        assert abs(call("rotation_distance", _R_FIXED @ R) - theta) < ATOL


# --------------------------------------------------------------------------- projection


def test_project_to_rotation(rng):
    for _ in range(5):
        R = random_rotation(rng)
        np.testing.assert_allclose(project_to_rotation_j(R), R, atol=ATOL)
        M = R + 0.05 * rng.normal(size=(3, 3))
        P = project_to_rotation_j(M)
        assert_rotation(P)
        # Reference: numpy's SVD, with the reflection fixed.
        U, _, Vt = np.linalg.svd(M)
        D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
        np.testing.assert_allclose(P, U @ D @ Vt, atol=ATOL)
        # A matrix with negative determinant still gives a proper rotation.
        assert_rotation(project_to_rotation_j(-M))


# --------------------------------------------------------------------------- hypothesis


@given(rotvecs)
def test_property_rotvec(r):
    R = rotvec_to_matrix_j(r)
    assert_rotation(R)
    assert_same_rotvec(matrix_to_rotvec_j(R), r)
    q = rotvec_to_quaternion_j(r)
    np.testing.assert_allclose(quaternion_to_matrix_j(q), R, atol=ATOL)
    assert_same_quaternion(matrix_to_quaternion_j(R), q)
    np.testing.assert_allclose(rotation_angle_j(R), np.linalg.norm(r), atol=ATOL)
    qc = q if q[0] >= 0 else -q
    atol = ATOL if np.linalg.norm(r) < 3.0 else QV_ATOL_NEAR_PI
    np.testing.assert_allclose(quaternion_vector_to_matrix_j(qc[1:]), R, atol=atol)


@given(quaternions)
def test_property_quaternion(q):
    R = quaternion_to_matrix_j(q)
    assert_rotation(R)
    np.testing.assert_allclose(R, np_quaternion_to_matrix(unit(q)), atol=ATOL)
    q_back = matrix_to_quaternion_j(R)
    assert q_back[0] >= 0
    assert_same_quaternion(q_back, q)
    np.testing.assert_allclose(rotvec_to_matrix_j(quaternion_to_rotvec_j(q)), R, atol=ATOL)


@given(rpys)
def test_property_rpy(rpy):
    check_rpy_solutions(rpy)


# --------------------------------------------------------------------------- vmap, jit, dtype


# The linear maps (hat, compose, quaternion_conjugate) are left out here and in the
# finite-difference test, to keep compilation time down; their values are tested above.
NONLINEAR = [n for n in FUNCTIONS if n not in ("hat", "compose", "quaternion_conjugate")]


@pytest.mark.parametrize("name", NONLINEAR)
def test_vmap_equals_loop(name, rng):
    xs = np.stack([random_input(INPUT_KIND[name], rng) for _ in range(5)])
    batched = np.asarray(jitted_vmap(name)(xs))
    looped = np.stack([call(name, x) for x in xs])
    np.testing.assert_allclose(batched, looped, atol=1e-14)


@pytest.mark.parametrize("name", list(FUNCTIONS))
def test_float32_follows_input_dtype(name, rng):
    for _ in range(4):
        x = random_input(INPUT_KIND[name], rng)
        out32 = jitted(name)(x.astype(np.float32))
        assert out32.dtype == jnp.float32
        # Against float64 on the float32-rounded input.
        expected = call(name, x.astype(np.float32).astype(np.float64))
        np.testing.assert_allclose(np.asarray(out32, np.float64), expected, atol=FLOAT32_ATOL)


def test_float32_singular_points():
    f32 = np.float32
    assert jitted("rotvec_to_matrix")(np.zeros(3, f32)).dtype == jnp.float32
    np.testing.assert_array_equal(matrix_to_rotvec_j(np.eye(3, dtype=f32)), np.zeros(3))
    r = matrix_to_rotvec_j(np.diag([1, -1, -1]).astype(f32))
    assert_same_rotvec(r, [PI, 0, 0], atol=FLOAT32_ATOL)
    R = rpy_to_matrix_j(np.array([0.3, PI / 2, -0.2], f32))
    a, b, singular = matrix_to_rpy_j(R)
    assert singular and a.dtype == np.float32
    np.testing.assert_allclose(rpy_to_matrix_j(a), R, atol=FLOAT32_ATOL)
    np.testing.assert_allclose(rpy_to_matrix_j(b), R, atol=FLOAT32_ATOL)
    fwd, rev = jacobians("matrix_to_rpy")(R)
    assert fwd.dtype == jnp.float32
    assert np.isfinite(np.asarray(fwd)).all() and np.isfinite(np.asarray(rev)).all()


def test_integer_input_is_promoted():
    R = jitted("rotvec_to_matrix")(np.array([0, 0, 1]))
    assert jnp.issubdtype(R.dtype, jnp.floating)
    np.testing.assert_allclose(R, cv2.Rodrigues(np.array([0.0, 0.0, 1.0]))[0], atol=ATOL)


# --------------------------------------------------------------------------- gradients


# rotation_distance(R_FIXED, R) is rotation_angle(R_FIXED^T R): testing the former tests
# the latter, at the cost of one compilation instead of two; quaternion_multiply is linear
# in q. Both are left out of the Jacobian tests.
DIFFERENTIATED = [n for n in NONLINEAR if n not in ("rotation_angle", "quaternion_multiply")]


@pytest.mark.parametrize("name", DIFFERENTIATED)
def test_jacobians_match_finite_differences(name, rng):
    for _ in range(3):
        x = random_input(INPUT_KIND[name], rng)
        fwd, rev = (np.asarray(j) for j in jacobians(name)(x))
        num = numerical_jacobian(jitted(name), x)
        assert np.isfinite(fwd).all() and np.isfinite(rev).all()
        np.testing.assert_allclose(rev, fwd, atol=1e-12)
        np.testing.assert_allclose(fwd, num, atol=FD_ATOL * max(1.0, np.abs(num).max()))


@pytest.mark.parametrize(
    "name", ["rotvec_to_matrix", "rotvec_to_quaternion", "quaternion_to_rotvec"]
)
@pytest.mark.parametrize("side", [1 - 1e-6, 1 + 1e-6])
def test_taylor_switch_is_seamless(name, side, rng):
    """Either side of the Taylor threshold, Jacobians match finite differences."""
    threshold = np.finfo(np.float64).eps ** 0.25  # on the squared (half) angle
    u = random_axis(rng)
    if name == "quaternion_to_rotvec":
        s = np.sqrt(threshold * side)
        x = np.concatenate([[np.sqrt(1 - s**2)], s * u])
    elif name == "rotvec_to_matrix":
        x = np.sqrt(threshold * side) * u  # switch of sinc(theta)
    else:
        x = 2 * np.sqrt(threshold * side) * u  # switch of sinc(theta/2)
    fwd, rev = (np.asarray(j) for j in jacobians(name)(x))
    np.testing.assert_allclose(fwd, numerical_jacobian(jitted(name), x), atol=FD_ATOL)
    np.testing.assert_allclose(rev, fwd, atol=1e-12)


def half_turn(rng):
    return rotvec_to_matrix_j(PI * random_axis(rng))


SINGULAR_POINTS = {
    "rotvec_to_matrix": lambda rng: [np.zeros(3), PI * random_axis(rng), 2 * PI * random_axis(rng)],
    "rotvec_to_quaternion": lambda rng: [np.zeros(3), PI * random_axis(rng)],
    "matrix_to_rotvec": lambda rng: [np.eye(3), np.diag([1.0, -1, -1]), half_turn(rng)],
    "matrix_to_quaternion": lambda rng: [np.eye(3), np.diag([-1.0, 1, -1]), half_turn(rng)],
    "quaternion_to_rotvec": lambda rng: [
        np.array([1.0, 0, 0, 0]),
        np.array([0.0, 1, 0, 0]),
        np.zeros(4),
    ],
    "quaternion_to_matrix": lambda rng: [np.zeros(4), np.array([1.0, 0, 0, 0])],
    "quaternion_vector_to_matrix": lambda rng: [np.zeros(3), random_axis(rng), 2 * np.ones(3)],
    "rotation_distance": lambda rng: [  # rotation_angle of I, of half turns
        _R_FIXED,
        _R_FIXED @ np.diag([-1.0, -1, 1]),
        _R_FIXED @ half_turn(rng),
    ],
    "matrix_to_rpy": lambda rng: [
        exact_gimbal_lock_matrix(0.4, -1.1, 1.0),
        exact_gimbal_lock_matrix(-2.0, 0.3, -1.0),
        rpy_to_matrix_j(np.array([0.3, PI / 2, 0.2])),
        rpy_to_matrix_j(np.array([0.3, -PI / 2, 0.2])),
        np.eye(3),
        np.diag([1.0, -1, -1]),
    ],
    "rpy_to_matrix": lambda rng: [np.array([0.3, PI / 2, 0.2]), np.zeros(3)],
    "project_to_rotation": lambda rng: [np.eye(3), half_turn(rng), np.diag([1.0, 1, -1])],
}


@pytest.mark.parametrize("name", list(SINGULAR_POINTS))
def test_jacobians_finite_at_singular_points(name, rng):
    for x in SINGULAR_POINTS[name](rng):
        fwd, rev = (np.asarray(j) for j in jacobians(name)(x))
        assert np.isfinite(fwd).all(), (name, x)
        assert np.isfinite(rev).all(), (name, x)
        np.testing.assert_allclose(rev, fwd, atol=1e-12)


def test_derivatives_at_singular_points_are_right(rng):
    """Where the derivative exists at a singular point, it has the right value."""
    e = np.eye(3)
    # d rotvec_to_matrix at r = 0 is hat(dr); d matrix_to_rotvec at I inverts it.
    J_exp = jacobians("rotvec_to_matrix")(np.zeros(3))[0]
    J_log = jacobians("matrix_to_rotvec")(np.eye(3))[1]
    for i in range(3):
        np.testing.assert_allclose(J_exp[:, :, i], call("hat", e[i]), atol=ATOL)
    np.testing.assert_allclose(np.tensordot(J_log, J_exp, 2), e, atol=ATOL)
    # The chain rule through the round trip is the identity, also near pi.
    for r in [0.4 * random_axis(rng), 3.0 * random_axis(rng), (PI - 1e-4) * random_axis(rng)]:
        J_exp = jacobians("rotvec_to_matrix")(r)[0]
        J_log = jacobians("matrix_to_rotvec")(rotvec_to_matrix_j(r))[1]
        np.testing.assert_allclose(np.tensordot(J_log, J_exp, 2), e, atol=1e-8)
    # Same for roll-pitch-yaw away from gimbal lock (solution a of matrix_to_rpy).
    rpy = np.array([0.3, 0.4, 0.2])
    J_rpy = jacobians("rpy_to_matrix")(rpy)[0]
    J_inv = jacobians("matrix_to_rpy")(rpy_to_matrix_j(rpy))[1][:3]
    np.testing.assert_allclose(np.tensordot(J_inv, J_rpy, 2), e, atol=1e-10)
    # rotvec -> quaternion at 0: dq = (0, dr / 2).
    J_q = jacobians("rotvec_to_quaternion")(np.zeros(3))[0]
    np.testing.assert_allclose(J_q, np.vstack([np.zeros(3), e / 2]), atol=ATOL)
    # quaternion_vector_to_matrix at 0: dR = 2 hat(dqv).
    J_qv = jacobians("quaternion_vector_to_matrix")(np.zeros(3))[1]
    for i in range(3):
        np.testing.assert_allclose(J_qv[:, :, i], 2 * call("hat", e[i]), atol=ATOL)
    # Distance at coincident rotations: a cone; the derivative chosen is the zero subgradient.
    np.testing.assert_array_equal(jacobians("rotation_distance")(_R_FIXED)[1], np.zeros((3, 3)))
