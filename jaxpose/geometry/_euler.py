"""Roll-pitch-yaw angles (paper A.2), as pure JAX functions.

`rpy = (roll, pitch, yaw)` ("nautical angles") are the angles of the rotations about `x`,
`y` and `z`, and `R = Rz(yaw) @ Ry(pitch) @ Rx(roll)`: rotations about `z`, then the new
`y`, then the newer `x` of the current frame (equivalently
`scipy.spatial.transform.Rotation.from_euler("ZYX", [yaw, pitch, roll])`). A rotation
matrix maps the rotated (object) frame to the reference (world) frame, `p = R m`, as in
`jaxpose.geometry._rotation`.

Every function takes **one** rotation (no batch axis; `jax.vmap` for many), follows the
floating dtype of its input (integer input is promoted to the default float dtype), runs
under `jit`/`vmap`/`grad`, and gives finite values *and* finite derivatives at gimbal
lock (pitch `+-90 deg`).
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Bool

from ._numerics import as_float, safe_atan2
from ._rotation import Matrix3, Matrix3Like, Vector3, Vector3Like

__all__ = ["matrix_to_rpy", "rpy_to_matrix"]

BoolScalar = Bool[Array, ""]


def _wrap_angle(a: Array) -> Array:
    """Map an angle in `[-pi, pi]` to `(-pi, pi]`."""
    return jnp.where(a <= -jnp.pi, a + 2.0 * jnp.pi, a)


def _shift_by_pi(a: Array) -> Array:
    """`a + pi` wrapped to `(-pi, pi]`, for `a` in `(-pi, pi]`."""
    return _wrap_angle(jnp.where(a > 0, a - jnp.pi, a + jnp.pi))


def rpy_to_matrix(rpy: Vector3Like) -> Matrix3:
    r"""Rotation matrix of roll-pitch-yaw ("nautical") angles (paper A.2).

    `rpy = (roll, pitch, yaw)` are the angles about `x`, `y` and `z`, and

    $$R = R_z(\mathrm{yaw})\, R_y(\mathrm{pitch})\, R_x(\mathrm{roll}) =
    \begin{bmatrix}
    c_y c_p & c_y s_p s_r - s_y c_r & c_y s_p c_r + s_y s_r\\
    s_y c_p & s_y s_p s_r + c_y c_r & s_y s_p c_r - c_y s_r\\
    -s_p & c_p s_r & c_p c_r
    \end{bmatrix}:$$

    a rotation about `z`, then about the new `y`, then about the newer `x` (each
    expressed in the current frame, hence multiplied on the right, A.1.1).

    **Arguments:**

    - `rpy`: `(roll, pitch, yaw)`, shape `(3,)`, radians.

    **Returns:**

    The rotation matrix `R`, shape `(3, 3)`.
    """
    rpy = as_float(rpy)
    cr, sr = jnp.cos(rpy[0]), jnp.sin(rpy[0])
    cp, sp = jnp.cos(rpy[1]), jnp.sin(rpy[1])
    cy, sy = jnp.cos(rpy[2]), jnp.sin(rpy[2])
    return jnp.stack(
        [
            jnp.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr]),
            jnp.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr]),
            jnp.stack([-sp, cp * sr, cp * cr]),
        ]
    )


def _rpy_singular_tolerance(dtype) -> float:
    """Gimbal-lock tolerance on `|cos(pitch)|`: `16 eps` (3.6e-15 f64, 1.9e-6 f32).

    Small enough that choosing `roll = 0` inside it moves `R` by `O(tol)` only, large
    enough that rounding in a matrix built at pitch = +-90 deg still counts as singular.
    """
    return 16.0 * float(jnp.finfo(dtype).eps)


def matrix_to_rpy(
    R: Matrix3Like,
) -> tuple[Vector3, Vector3, BoolScalar]:
    r"""Both roll-pitch-yaw solutions of a rotation matrix, and the gimbal-lock flag.

    Inverse of `rpy_to_matrix` (`R = Rz(yaw) Ry(pitch) Rx(roll)`). Away from gimbal lock
    there are exactly two solutions:

    - `rpy_a`: `pitch` in `[-pi/2, pi/2]` (`cos(pitch) >= 0`),
      `yaw = atan2(R10, R00)`;
    - `rpy_b`: `pitch' = pi - pitch`, `roll' = roll + pi`, `yaw' = yaw + pi`.

    All angles are wrapped to `(-pi, pi]`. Given the yaw, the other two angles are read
    from `Rz(yaw)^T R = Ry(pitch) Rx(roll)`, which keeps the reconstruction accurate to
    rounding even close to gimbal lock:
    `roll = atan2(sy R02 - cy R12, cy R11 - sy R01)`,
    `pitch = atan2(-R20, |cy R00 + sy R10|)`.

    `singular` is `True` when `|cos(pitch)| = sqrt(R00^2 + R10^2)` is below a
    dtype-dependent tolerance (`16 eps`). Then only `yaw - roll` (pitch = +90 deg) or
    `yaw + roll` (pitch = -90 deg) is determined; both solutions take `roll = 0` and put
    the whole in-plane rotation in `yaw = atan2(-R01, R11)` (so the two solutions then
    differ only by pitch, `pitch' = pi - pitch`, equal at exactly +-90 deg). Values and
    derivatives are finite there. Forcing `roll = 0` inside the tolerance band moves the
    reconstruction by at most about `2 tol` (`7e-15` in float64, `4e-6` in float32);
    outside it both solutions reproduce `R` to rounding, however close to gimbal lock
    (where the individual angles, not the matrix, become ill-conditioned: `~eps/cos(pitch)`).

    **Arguments:**

    - `R`: rotation matrix, shape `(3, 3)`.

    **Returns:**

    A tuple `(rpy_a, rpy_b, singular)`: two arrays `(roll, pitch, yaw)` of shape `(3,)`,
    each reproducing `R`, and a boolean scalar.
    """
    R = as_float(R)
    tol = _rpy_singular_tolerance(R.dtype)
    cos_pitch_sq = R[0, 0] ** 2 + R[1, 0] ** 2
    singular = cos_pitch_sq < tol * tol

    # Regular: yaw = atan2(R10, R00) (|(R10, R00)| = cos(pitch) >= tol, never degenerate).
    # Gimbal lock: roll = 0 and yaw = atan2(-R01, R11).
    yaw = safe_atan2(jnp.where(singular, -R[0, 1], R[1, 0]), jnp.where(singular, R[1, 1], R[0, 0]))
    yaw = _wrap_angle(yaw)
    cy, sy = jnp.cos(yaw), jnp.sin(yaw)

    roll = safe_atan2(sy * R[0, 2] - cy * R[1, 2], cy * R[1, 1] - sy * R[0, 1])
    roll = jnp.where(singular, jnp.zeros_like(roll), _wrap_angle(roll))
    pitch = safe_atan2(-R[2, 0], jnp.abs(cy * R[0, 0] + sy * R[1, 0]))

    rpy_a = jnp.stack([roll, pitch, yaw])
    pitch_b = _wrap_angle(jnp.where(pitch >= 0, jnp.pi - pitch, -jnp.pi - pitch))
    roll_b = jnp.where(singular, roll, _shift_by_pi(roll))
    yaw_b = jnp.where(singular, yaw, _shift_by_pi(yaw))
    rpy_b = jnp.stack([roll_b, pitch_b, yaw_b])
    return rpy_a, rpy_b, singular
