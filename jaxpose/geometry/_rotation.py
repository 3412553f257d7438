"""Rotation parameterisations of the paper (Section 2.2, Appendix A), as pure JAX functions.

Every function takes **one** rotation (no batch axis; `jax.vmap` for many), follows the
floating dtype of its input (float32 or float64; integer input is promoted to the default
float dtype), runs under `jit`/`vmap`/`grad`, and gives finite values *and* finite
derivatives (`jax.grad`, `jax.jacfwd`, `jax.jacrev`) at the singular points of each
parameterisation: a rotation of angle exactly `0` and exactly `pi`. Roll-pitch-yaw
angles live in `jaxpose.geometry._euler`.

Conventions used throughout:

- A rotation matrix `R` (3x3, `det R = +1`) maps coordinates in the rotated (object)
  frame to the reference (world) frame: `p = R m` (the paper's "direction cosines", A.1).
- `hat(v)` is the cross-product matrix `X(v)`, `X(v) w = v x w`.
- A rotation vector is `r = theta u`, `u` the unit axis, `theta` the right-handed angle
  (Rodrigues, A.6): `R = I + sin(theta) X(u) + (1 - cos(theta)) X(u)^2`.
- A quaternion is **scalar first**, `q = (q0, q1, q2, q3)`, `q0 = cos(theta/2)`,
  `(q1, q2, q3) = sin(theta/2) u` (A.12); `q` and `-q` are the same rotation; the
  functions returning a quaternion return it with `q0 >= 0`. Products are Hamilton
  products, `quaternion_to_matrix(quaternion_multiply(p, q)) == P @ Q`.

Numerical technique (after jaxlie): every formula with a removable singularity is split
into a Taylor branch, used below a dtype-dependent threshold, and the closed form, and the
two are combined with `jnp.where`. The closed form is fed a *safe* argument (for instance
`1` instead of `theta^2 = 0`) where it is not selected, so that the untaken branch cannot
produce an `inf`/`NaN` that reverse-mode differentiation would multiply by zero (`0 * inf`
is `NaN`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float, Real

from ._numerics import as_float, safe_norm, safe_normalize, safe_sqrt

# Shape-annotated aliases (one rotation, no batch axis). Inputs may be integer (they are
# promoted to the default float dtype); outputs are floating.
Vector3 = Float[Array, "3"]
Vector3Like = Real[ArrayLike, "3"]
QuaternionArray = Float[Array, "4"]
QuaternionLike = Real[ArrayLike, "4"]
Matrix3 = Float[Array, "3 3"]
Matrix3Like = Real[ArrayLike, "3 3"]
Scalar = Float[Array, ""]

__all__ = [
    "compose",
    "hat",
    "matrix_to_quaternion",
    "matrix_to_rotvec",
    "project_to_rotation",
    "quaternion_conjugate",
    "quaternion_multiply",
    "quaternion_to_matrix",
    "quaternion_to_rotvec",
    "quaternion_vector_to_matrix",
    "rotation_angle",
    "rotation_distance",
    "rotvec_to_matrix",
    "rotvec_to_quaternion",
]


# --------------------------------------------------------------------------------------
# Private helpers
# --------------------------------------------------------------------------------------


def _taylor_threshold(dtype) -> float:
    """Threshold on `x^2` below which the Taylor branches are used.

    The closed forms (`sin(x)/x`, `atan(x)/x`) are accurate to rounding in value for
    every `x > 0`, but their derivatives lose `~eps/x^2` (relative) to cancellation; the
    Taylor branches, kept to `x^6`, are exact to rounding in value there and lose at
    most `~x^6` in derivative. At `x^2 = eps^(1/4)` (`1.2e-4` in float64, `1.9e-2` in
    float32) both derivative errors are `<~ eps^(3/4)`: `2e-12` and `6e-6` relative.
    """
    return float(jnp.finfo(dtype).eps) ** 0.25


def _sinc_of_sq(x2: Array) -> Array:
    """`sin(x) / x` as a function of `x2 = x^2` (smooth, even at `x = 0`)."""
    small = x2 < _taylor_threshold(x2.dtype)
    x = jnp.sqrt(jnp.where(small, 1.0, x2))  # safe: never sqrt(0)
    taylor = 1.0 - x2 / 6.0 * (1.0 - x2 / 20.0 * (1.0 - x2 / 42.0))
    return jnp.where(small, taylor, jnp.sin(x) / x)


def _cos_of_sq(x2: Array) -> Array:
    """`cos(x)` as a function of `x2 = x^2` (smooth, even at `x = 0`)."""
    small = x2 < _taylor_threshold(x2.dtype)
    x = jnp.sqrt(jnp.where(small, 1.0, x2))
    taylor = 1.0 - x2 / 2.0 * (1.0 - x2 / 12.0 * (1.0 - x2 / 30.0))
    return jnp.where(small, taylor, jnp.cos(x))


# --------------------------------------------------------------------------------------
# Cross-product matrix and composition
# --------------------------------------------------------------------------------------


def hat(v: Vector3Like) -> Matrix3:
    r"""Cross-product ("vectorial pre-product") matrix of a 3-vector (paper A.1.2).

    $$X(v) = \begin{bmatrix} 0 & -v_z & v_y \\ v_z & 0 & -v_x \\ -v_y & v_x & 0
    \end{bmatrix}, \qquad X(v)\,w = v \times w.$$

    **Arguments:**

    - `v`: vector, shape `(3,)`.

    **Returns:**

    The skew-symmetric matrix `X(v)`, shape `(3, 3)`, same dtype as `v`.
    """
    v = as_float(v)
    zero = jnp.zeros_like(v[0])
    return jnp.stack(
        [
            jnp.stack([zero, -v[2], v[1]]),
            jnp.stack([v[2], zero, -v[0]]),
            jnp.stack([-v[1], v[0], zero]),
        ]
    )


def compose(R1: Matrix3Like, R2: Matrix3Like) -> Matrix3:
    """Composition of two rotations: `compose(R1, R2) = R1 @ R2`.

    The result applies `R2` first, then `R1`: `(R1 @ R2) p = R1 (R2 p)`. In the paper's
    words (A.1.1), `R2` is expressed in the current frame reached by `R1`
    (multiplication on the right).

    **Arguments:**

    - `R1`, `R2`: rotation matrices, shape `(3, 3)`.

    **Returns:**

    `R1 @ R2`, shape `(3, 3)`.
    """
    return as_float(R1) @ as_float(R2)


# --------------------------------------------------------------------------------------
# Rotation vector
# --------------------------------------------------------------------------------------


def rotvec_to_matrix(r: Vector3Like) -> Matrix3:
    r"""Rotation matrix of a rotation vector (Rodrigues, paper Eq. 1 / A.6).

    With `r = theta u`, `theta = |r|`:

    $$R = I + \frac{\sin\theta}{\theta} X(r) + \frac{1-\cos\theta}{\theta^2} X(r)^2
        = I + \sin\theta\, X(u) + (1-\cos\theta)\, X(u)^2 .$$

    The coefficients are computed as `sinc(theta)` and `(1 - cos theta)/theta^2 =
    sinc(theta/2)^2 / 2` (no cancellation), each with a Taylor branch near `theta = 0`, so
    values and derivatives are accurate and finite at and near `r = 0`. Any `theta` is accepted
    (`theta > pi` is the same rotation as `theta - 2 pi`).

    **Arguments:**

    - `r`: rotation vector, shape `(3,)`, radians.

    **Returns:**

    The rotation matrix `R`, shape `(3, 3)`.
    """
    r = as_float(r)
    theta2 = jnp.dot(r, r)
    a = _sinc_of_sq(theta2)
    b = 0.5 * _sinc_of_sq(0.25 * theta2) ** 2
    # X(r)^2 = r r^T - theta^2 I, so R = (1 - b theta^2) I + a X(r) + b r r^T.
    return (1.0 - b * theta2) * jnp.eye(3, dtype=r.dtype) + a * hat(r) + b * jnp.outer(r, r)


def matrix_to_rotvec(R: Matrix3Like) -> Vector3:
    r"""Rotation vector of a rotation matrix, `theta` in `[0, pi]` (paper A.7-A.11).

    The paper reads `cos(theta) = (tr R - 1)/2` (A.7) and `2 sin(theta) u` from the skew
    part of `R` (A.8-A.10), and the axis near `theta = pi` from the symmetric part with
    signs from the skew part (A.11). The same information is used here through the unit
    quaternion (`matrix_to_quaternion`, whose Shepperd cases are exactly the skew and
    symmetric parts of `R`, divided by the best-conditioned diagonal combination):
    `theta = 2 atan2(|q_v|, q0)` and `r = theta q_v / |q_v|`. This is accurate to
    rounding for every angle: near `0` (Taylor branch of `theta / |q_v|`) and near `pi`
    (the axis comes from the symmetric part, not from `sin(theta) ~ 0`).

    At `theta = pi` exactly, `r` and `-r` are both correct; either is returned. Values
    and derivatives are finite everywhere, including `R = I` and `theta = pi`.

    **Arguments:**

    - `R`: rotation matrix, shape `(3, 3)`.

    **Returns:**

    The rotation vector `r = theta u`, shape `(3,)`, with `0 <= theta <= pi`.
    """
    return _unit_quaternion_to_rotvec(matrix_to_quaternion(R))


# --------------------------------------------------------------------------------------
# Quaternions
# --------------------------------------------------------------------------------------


def quaternion_to_matrix(q: QuaternionLike) -> Matrix3:
    r"""Rotation matrix of a (not necessarily unit) quaternion, scalar first (A.12-A.14).

    With `q = (q0, v)` normalised to unit norm, (A.14) reads
    `R = I + 2 q0 X(v) + 2 X(v)^2`. The normalisation is folded in as
    `R = I + (2 / |q|^2) (q0 X(v) + X(v)^2)`, which is exact for any `q != 0`;
    `q = 0` gives `I` (with finite derivatives).

    **Arguments:**

    - `q`: quaternion `(q0, q1, q2, q3)`, `q0 = cos(theta/2)`, shape `(4,)`.

    **Returns:**

    The rotation matrix `R`, shape `(3, 3)`; `q` and `-q` give the same `R`.
    """
    q = as_float(q)
    n2 = jnp.dot(q, q)
    positive = n2 > 0
    s = jnp.where(positive, 2.0 / jnp.where(positive, n2, 1.0), 0.0)
    v = q[1:]
    # X(v)^2 = v v^T - |v|^2 I.
    diagonal = 1.0 - s * jnp.dot(v, v)
    return diagonal * jnp.eye(3, dtype=q.dtype) + s * (q[0] * hat(v) + jnp.outer(v, v))


def matrix_to_quaternion(R: Matrix3Like) -> QuaternionArray:
    r"""Unit quaternion of a rotation matrix (paper A.15), robust (Shepperd's method).

    The four products `4 q_i q` can be read linearly from `R`:

    $$\begin{aligned}
    4 q_0 q &= (t_0,\; R_{21}-R_{12},\; R_{02}-R_{20},\; R_{10}-R_{01}),
        & t_0 &= 1 + R_{00} + R_{11} + R_{22},\\
    4 q_1 q &= (R_{21}-R_{12},\; t_1,\; R_{10}+R_{01},\; R_{02}+R_{20}),
        & t_1 &= 1 + R_{00} - R_{11} - R_{22},\\
    4 q_2 q &= (R_{02}-R_{20},\; R_{10}+R_{01},\; t_2,\; R_{21}+R_{12}),
        & t_2 &= 1 - R_{00} + R_{11} - R_{22},\\
    4 q_3 q &= (R_{10}-R_{01},\; R_{02}+R_{20},\; R_{21}+R_{12},\; t_3),
        & t_3 &= 1 - R_{00} - R_{11} + R_{22},
    \end{aligned}$$

    with `t_i = 4 q_i^2`. All four are computed and the one with the largest `t_i` is
    selected with `jnp.where` (no `lax.cond`), then normalised; since
    `sum t_i = 4`, the selected vector has norm `>= 2` for a rotation, so nothing is
    ever divided by a small number. For a matrix that is not exactly orthonormal the
    result is this normalised estimate (use `project_to_rotation` first for the best fit).

    **Arguments:**

    - `R`: rotation matrix, shape `(3, 3)`.

    **Returns:**

    The unit quaternion `(q0, q1, q2, q3)`, shape `(4,)`, with `q0 >= 0`.
    """
    R = as_float(R)
    r00, r01, r02 = R[0, 0], R[0, 1], R[0, 2]
    r10, r11, r12 = R[1, 0], R[1, 1], R[1, 2]
    r20, r21, r22 = R[2, 0], R[2, 1], R[2, 2]
    t = jnp.stack(
        [
            1.0 + r00 + r11 + r22,
            1.0 + r00 - r11 - r22,
            1.0 - r00 + r11 - r22,
            1.0 - r00 - r11 + r22,
        ]
    )
    cases = jnp.stack(
        [
            jnp.stack([t[0], r21 - r12, r02 - r20, r10 - r01]),
            jnp.stack([r21 - r12, t[1], r10 + r01, r02 + r20]),
            jnp.stack([r02 - r20, r10 + r01, t[2], r21 + r12]),
            jnp.stack([r10 - r01, r02 + r20, r21 + r12, t[3]]),
        ]
    )
    selected = (jnp.arange(4) == jnp.argmax(t))[:, None]
    q = jnp.sum(jnp.where(selected, cases, 0.0), axis=0)
    # Component `best` of the selected vector is t[best] >= 1: the norm is never small.
    q = q / jnp.sqrt(jnp.dot(q, q))
    return jnp.where(q[0] < 0, -q, q)


def quaternion_vector_to_matrix(qv: Vector3Like) -> Matrix3:
    r"""Rotation matrix from the quaternion's vector part only (the paper's LM unknowns).

    The paper's non-linear method optimises `qv = (q1, q2, q3)` and recovers the scalar
    part from the unit norm (A.13): `q0 = sqrt(1 - |qv|^2) >= 0`, then applies (A.14).
    This covers every rotation with `theta` in `[0, pi]` once.

    Outside the unit ball, `|qv| >= 1`, `q0` is clamped to `0` and `qv` is normalised:
    the result is the half-turn (`theta = pi`) about `qv / |qv|`. The map is continuous
    across `|qv| = 1`. Values and derivatives are finite everywhere (exactly at
    `qv = 0` and at `|qv| = 1`); just inside the unit sphere the derivative grows like
    `1 / sqrt(1 - |qv|^2)`, the parameterisation's own singularity. For the same reason,
    near `theta = pi` the rounding of `|qv|^2` limits `q0`, hence `R`, to an absolute
    accuracy of about `sqrt(eps)` (`1.5e-8` in float64); elsewhere `R` is accurate to
    rounding.

    **Arguments:**

    - `qv`: vector part `(q1, q2, q3) = sin(theta/2) u`, shape `(3,)`.

    **Returns:**

    The rotation matrix `R`, shape `(3, 3)`.
    """
    qv = as_float(qv)
    one_minus = 1.0 - jnp.dot(qv, qv)
    q0 = safe_sqrt(one_minus)
    # quaternion_to_matrix normalises: |q| = 1 inside, and q = (0, qv) -> (0, qv/|qv|).
    return quaternion_to_matrix(jnp.concatenate([q0[None], qv]))


def rotvec_to_quaternion(r: Vector3Like) -> QuaternionArray:
    r"""Unit quaternion of a rotation vector (A.12).

    With `r = theta u`: `q = (cos(theta/2), sin(theta/2) u) =
    (cos(theta/2), sinc(theta/2) r / 2)`, with Taylor branches near `theta = 0`.
    The result is smooth in `r`; `q0 >= 0` for `theta <= pi` (and negative beyond,
    still the same rotation).

    **Arguments:**

    - `r`: rotation vector, shape `(3,)`, radians.

    **Returns:**

    The unit quaternion `(q0, q1, q2, q3)`, shape `(4,)`.
    """
    r = as_float(r)
    half2 = 0.25 * jnp.dot(r, r)
    q0 = _cos_of_sq(half2)
    qv = 0.5 * _sinc_of_sq(half2) * r
    return jnp.concatenate([q0[None], qv])


def quaternion_to_rotvec(q: QuaternionLike) -> Vector3:
    r"""Rotation vector of a (not necessarily unit) quaternion, `theta` in `[0, pi]`.

    `q` is normalised (`q = 0` gives `r = 0`) and flipped to `q0 >= 0`; then with
    `s = |q_v|`: `theta = 2 atan2(s, q0)` and `r = (theta / s) q_v`. The factor
    `theta / s = (2/q0) atan(z)/z`, `z = s/q0`, uses its Taylor series near `s = 0`,
    so values and derivatives are finite at the identity; at `q0 = 0` (`theta = pi`)
    it is `pi / s`, finite.

    **Arguments:**

    - `q`: quaternion `(q0, q1, q2, q3)`, shape `(4,)`.

    **Returns:**

    The rotation vector `r = theta u`, shape `(3,)`, with `0 <= theta <= pi`.
    """
    q = as_float(q)
    identity = jnp.array([1.0, 0.0, 0.0, 0.0], dtype=q.dtype)
    q = safe_normalize(q, fallback=identity)
    return _unit_quaternion_to_rotvec(jnp.where(q[0] < 0, -q, q))


def _unit_quaternion_to_rotvec(q: Array) -> Array:
    """`quaternion_to_rotvec` for a unit quaternion with `q0 >= 0` (no normalisation)."""
    w, v = q[0], q[1:]
    s2 = jnp.dot(v, v)
    small = s2 < _taylor_threshold(q.dtype)
    # Taylor branch: s^2 < threshold < 1 on the unit sphere, so w >= sqrt(1 - threshold).
    safe_w = jnp.where(small, w, 1.0)
    z2 = s2 / (safe_w * safe_w)
    taylor = (2.0 / safe_w) * (1.0 - z2 * (1.0 / 3.0 - z2 * (1.0 / 5.0 - z2 / 7.0)))
    safe_s = jnp.sqrt(jnp.where(small, 1.0, s2))
    exact = 2.0 * jnp.arctan2(safe_s, w) / safe_s
    return jnp.where(small, taylor, exact) * v


def quaternion_multiply(p: QuaternionLike, q: QuaternionLike) -> QuaternionArray:
    r"""Hamilton product `p q` of two scalar-first quaternions.

    $$p\,q = \bigl(p_0 q_0 - p_v\cdot q_v,\; p_0 q_v + q_0 p_v + p_v \times q_v\bigr),$$

    so that `quaternion_to_matrix(quaternion_multiply(p, q)) ==
    quaternion_to_matrix(p) @ quaternion_to_matrix(q)` (apply `q` first, then `p`).

    **Arguments:**

    - `p`, `q`: quaternions `(q0, q1, q2, q3)`, shape `(4,)`.

    **Returns:**

    The product, shape `(4,)` (unit if both are unit; not re-signed).
    """
    p = as_float(p)
    q = as_float(q)
    p0, pv = p[0], p[1:]
    q0, qv = q[0], q[1:]
    w = p0 * q0 - jnp.dot(pv, qv)
    v = p0 * qv + q0 * pv + jnp.cross(pv, qv)
    return jnp.concatenate([w[None], v])


def quaternion_conjugate(q: QuaternionLike) -> QuaternionArray:
    """Conjugate `(q0, -q1, -q2, -q3)`: the inverse rotation of a unit quaternion.

    **Arguments:**

    - `q`: quaternion `(q0, q1, q2, q3)`, shape `(4,)`.

    **Returns:**

    The conjugate quaternion, shape `(4,)`.
    """
    q = as_float(q)
    return jnp.concatenate([q[:1], -q[1:]])


# --------------------------------------------------------------------------------------
# Angles, distances, projection
# --------------------------------------------------------------------------------------


def rotation_angle(R: Matrix3Like) -> Scalar:
    r"""Rotation angle `theta` in `[0, pi]` of a rotation matrix.

    `theta = 2 atan2(sin(theta/2), cos(theta/2))` with both half-angle terms taken from
    the Shepperd quaternion (`matrix_to_quaternion`), i.e. from the norms of the skew and
    symmetric parts of `R`, never `arccos((tr R - 1)/2)`: accurate to rounding near `0`
    and `pi`, and the derivative is finite everywhere (`0` at `R = I`, where `theta` has a
    cone-shaped minimum).

    **Arguments:**

    - `R`: rotation matrix, shape `(3, 3)`.

    **Returns:**

    The angle `theta`, a scalar, radians.
    """
    q = matrix_to_quaternion(R)
    return 2.0 * jnp.arctan2(safe_norm(q[1:]), q[0])


def rotation_distance(R1: Matrix3Like, R2: Matrix3Like) -> Scalar:
    """Geodesic distance between two rotations: the angle of `R1^T R2`, in `[0, pi]`.

    See `rotation_angle` (atan2 of half-angle sine and cosine; finite derivatives
    when `R1 == R2`).

    **Arguments:**

    - `R1`, `R2`: rotation matrices, shape `(3, 3)`.

    **Returns:**

    The angle between them, a scalar, radians.
    """
    return rotation_angle(as_float(R1).T @ as_float(R2))


def _polar_factor(M: Array) -> tuple[Array, Array, Array]:
    """`R = U diag(1, 1, d) V^T` and the eigen-pair of `S = R^T M = V diag(s) V^T`."""
    U, sigma, Vt = jnp.linalg.svd(M)
    d = jnp.where(jnp.linalg.det(U @ Vt) < 0, -1.0, 1.0).astype(M.dtype)
    signs = jnp.stack([jnp.ones_like(d), jnp.ones_like(d), d])
    R = (U * signs[None, :]) @ Vt
    return R, Vt, sigma * signs


@jax.custom_jvp
def _project_to_rotation(M: Array) -> Array:
    return _polar_factor(M)[0]


@_project_to_rotation.defjvp
def _project_to_rotation_jvp(primals, tangents):
    # M = R S with S = V diag(s) V^T symmetric, so dM = dR S + R dS, dR = R W (W skew) and
    # R^T dM - dM^T R = W S + S W. In the eigenbasis of S: W'_ij = A'_ij / (s_i + s_j).
    # This avoids JAX's SVD derivative, which divides by s_i^2 - s_j^2 and is NaN at any
    # input with repeated singular values (e.g. M already a rotation).
    (M,) = primals
    (dM,) = tangents
    R, Vt, s = _polar_factor(M)
    A = R.T @ dM
    A = Vt @ (A - A.T) @ Vt.T
    denom = s[:, None] + s[None, :]
    ok = denom > 16.0 * jnp.finfo(M.dtype).eps * jnp.abs(s[0])
    W = jnp.where(ok, A / jnp.where(ok, denom, 1.0), 0.0)
    return R, R @ (Vt.T @ W @ Vt)


def project_to_rotation(M: Matrix3Like) -> Matrix3:
    r"""Nearest rotation matrix (Frobenius norm) to a 3x3 matrix.

    With the SVD `M = U diag(sigma) V^T`:
    `R = U diag(1, 1, det(U V^T)) V^T`, the special-orthogonal polar factor
    (`det R = +1` even when `det M < 0`).

    The derivative is a custom JVP from the polar decomposition `M = R S`:
    `dR = R W`, `W` skew with `W S + S W = R^T dM - dM^T R`, solved in the eigenbasis of
    `S`. It is finite at rotations (repeated singular values), unlike differentiating
    through `jnp.linalg.svd`; it is set to zero in directions where it does not exist
    (rank-deficient `M`, or `det M < 0` with two equal smallest singular values).

    **Arguments:**

    - `M`: any 3x3 matrix, shape `(3, 3)`.

    **Returns:**

    The rotation `R`, shape `(3, 3)`, `R^T R = I`, `det R = +1`.
    """
    return _project_to_rotation(as_float(M))
