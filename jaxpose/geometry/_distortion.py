"""OpenCV's lens distortion model inside JAX: projection, and the pose refined in image
pixels.

OpenCV maps a camera-frame point `(X, Y, Z)` to the normalised coordinates
`x = X / Z, y = Y / Z`, distorts them, and applies `K`:

    r2 = x^2 + y^2
    radial = (1 + k1 r2 + k2 r2^2 + k3 r2^3) / (1 + k4 r2 + k5 r2^2 + k6 r2^3)
    x' = x radial + 2 p1 x y + p2 (r2 + 2 x^2) + s1 r2 + s2 r2^2
    y' = y radial + p1 (r2 + 2 y^2) + 2 p2 x y + s3 r2 + s4 r2^2
    (x'', y'') = the tilted sensor's projection of (x', y') (tau_x, tau_y)
    u = K00 x'' + K01 y'' + K02,  v = K11 y'' + K12

with the coefficients in OpenCV's order `k1, k2, p1, p2[, k3[, k4, k5, k6[, s1, s2, s3,
s4[, tau_x, tau_y]]]]` (4, 5, 8, 12 or 14 of them; the missing ones are zero). Everything
here is plain `jax.numpy` in component form (`x`, `y` separate arrays), for any batch
shape, and differentiable with respect to the points, the pose, `K` and the coefficients.

`cv2.solvePnP` with distortion minimises the pixel error in the *image* (distorted
pixels). `refine_in_image` does the same from a start pose (`jaxpose.solve_pnp` gives it
the answer found on undistorted pixels): Levenberg-Marquardt on the image residuals.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float

from ._rotation import matrix_to_rotvec, rotvec_to_matrix

__all__ = ["COEFFICIENTS", "distort", "project_points", "refine_in_image"]

#: The number of coefficients of OpenCV's full model (`k1 ... tau_y`).
COEFFICIENTS = 14


def _full(dist: ArrayLike) -> Array:
    """The coefficients padded with zeros to `COEFFICIENTS`."""
    d = jnp.asarray(dist).reshape(-1)
    return jnp.concatenate([d, jnp.zeros(COEFFICIENTS - d.shape[0], d.dtype)])


def _tilt(tau_x: Array, tau_y: Array) -> list[list]:
    """The 3x3 projection of a sensor tilted by `tau_x`, `tau_y` (OpenCV's
    `computeTiltProjectionMatrix`): `[[c22, 0, -c02], [0, c22, -c12], [0, 0, 1]] R`, with
    `R = R_y(tau_y) R_x(tau_x)`."""
    cx, sx, cy, sy = jnp.cos(tau_x), jnp.sin(tau_x), jnp.cos(tau_y), jnp.sin(tau_y)
    zero, one = jnp.zeros_like(cx), jnp.ones_like(cx)
    rx = [[one, zero, zero], [zero, cx, sx], [zero, -sx, cx]]
    ry = [[cy, zero, -sy], [zero, one, zero], [sy, zero, cy]]
    r = [[sum(ry[i][k] * rx[k][j] for k in range(3)) for j in range(3)] for i in range(3)]
    proj = [[r[2][2], zero, -r[0][2]], [zero, r[2][2], -r[1][2]], [zero, zero, one]]
    return [[sum(proj[i][k] * r[k][j] for k in range(3)) for j in range(3)] for i in range(3)]


def distort(x: Array, y: Array, dist: ArrayLike) -> tuple[Array, Array]:
    """Distorted normalised coordinates `(x'', y'')` of `(x, y)` (module docstring), any
    batch shape; `dist` 4, 5, 8, 12 or 14 coefficients in OpenCV's order."""
    k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4, tau_x, tau_y = _full(dist)
    r2 = x * x + y * y
    r4 = r2 * r2
    r6 = r4 * r2
    radial = (1 + k1 * r2 + k2 * r4 + k3 * r6) / (1 + k4 * r2 + k5 * r4 + k6 * r6)
    xy2 = 2 * x * y
    xd = x * radial + p1 * xy2 + p2 * (r2 + 2 * x * x) + s1 * r2 + s2 * r4
    yd = y * radial + p1 * (r2 + 2 * y * y) + p2 * xy2 + s3 * r2 + s4 * r4
    T = _tilt(tau_x, tau_y)
    w = T[2][0] * xd + T[2][1] * yd + T[2][2]
    inv = jnp.where(w != 0, 1 / jnp.where(w != 0, w, 1), 1)
    return (T[0][0] * xd + T[0][1] * yd + T[0][2]) * inv, (
        T[1][0] * xd + T[1][1] * yd + T[1][2]
    ) * inv


def _pixels(points_cam: Array, K: Array, dist: ArrayLike) -> Array:
    """`(..., 2)` image pixels of camera-frame points `(..., 3)`."""
    z = points_cam[..., 2]
    safe = jnp.where(z != 0, z, 1)
    xd, yd = distort(points_cam[..., 0] / safe, points_cam[..., 1] / safe, dist)
    u = K[0, 0] * xd + K[0, 1] * yd + K[0, 2]
    v = K[1, 1] * yd + K[1, 2]
    return jnp.stack([u, v], axis=-1)


def project_points(
    object_points: Float[ArrayLike, "n 3"],
    rvec: Float[ArrayLike, "3"],
    tvec: Float[ArrayLike, "3"],
    K: Float[ArrayLike, "3 3"],
    dist: Float[ArrayLike, " k"] | None = None,
) -> Float[Array, "n 2"]:
    """`cv2.projectPoints` in JAX: the image pixels of `object_points` seen by the camera
    `K`, `dist` at the pose `rvec`, `tvec` (OpenCV's convention, `x_cam = R X + t`).
    `dist` None: no distortion. Differentiable in every argument."""
    X = jnp.asarray(object_points)
    R = rotvec_to_matrix(jnp.asarray(rvec).reshape(3))
    cam = X @ R.T + jnp.asarray(tvec).reshape(1, 3)
    d = jnp.zeros(4, X.dtype) if dist is None else jnp.asarray(dist, X.dtype)
    return _pixels(cam, jnp.asarray(K, X.dtype), d)


def refine_in_image(
    K: Float[ArrayLike, "3 3"],
    dist: Float[ArrayLike, " k"],
    object_points: Float[ArrayLike, "n 3"],
    image_points: Float[ArrayLike, "n 2"],
    mask: Bool[ArrayLike, " n"],
    rvec: Float[ArrayLike, "3"],
    tvec: Float[ArrayLike, "3"],
    iterations: int = 30,
) -> tuple[Array, Array, Array]:
    """The pose minimising the pixel error in the distorted image (what
    `cv2.solvePnPRefineLM` minimises with distortion), by Levenberg-Marquardt from
    `rvec`, `tvec`: `iterations` steps (`jax.lax.fori_loop`; a step is kept only when it
    lowers the error, the damping divided by 10 then, else multiplied by 10), the
    rotation updated as `R <- Rot(w) R`. `mask` selects the matches. Pure, for `jit`.

    **Returns:** `(rvec, tvec, rms)`: the refined pose and its RMS image error (px); the
    start when no step lowered the error.
    """
    X = jnp.asarray(object_points)
    dtype = X.dtype
    K = jnp.asarray(K, dtype)
    d = jnp.asarray(dist, dtype)
    img = jnp.asarray(image_points, dtype)
    w = jnp.asarray(mask).astype(dtype)
    R0 = rotvec_to_matrix(jnp.asarray(rvec, dtype).reshape(3))
    t0 = jnp.asarray(tvec, dtype).reshape(3)

    def pose(xi, R, t):
        return rotvec_to_matrix(xi[:3]) @ R, t + xi[3:]

    def residuals(xi, R, t):
        Rn, tn = pose(xi, R, t)
        r = (_pixels(X @ Rn.T + tn[None, :], K, d) - img) * w[:, None]
        return r.reshape(-1)

    def cost(R, t):
        r = residuals(jnp.zeros(6, dtype), R, t)
        return r @ r

    def step(_, carry):
        R, t, c, lam = carry
        zero = jnp.zeros(6, dtype)
        r = residuals(zero, R, t)
        J = jax.jacfwd(residuals)(zero, R, t)
        H = J.T @ J
        g = J.T @ r
        D = jnp.diag(jnp.diag(H)) + 1e-12 * jnp.eye(6, dtype=dtype)
        delta = jnp.linalg.solve(H + lam * D, -g)
        delta = jnp.where(jnp.all(jnp.isfinite(delta)), delta, 0)
        Rn, tn = pose(delta, R, t)
        cn = cost(Rn, tn)
        better = jnp.isfinite(cn) & (cn < c)
        R = jnp.where(better, Rn, R)
        t = jnp.where(better, tn, t)
        c = jnp.where(better, cn, c)
        lam = jnp.clip(jnp.where(better, lam / 10, lam * 10), 1e-12, 1e12)
        return R, t, c, lam

    c0 = cost(R0, t0)
    R, t, c, _ = jax.lax.fori_loop(0, iterations, step, (R0, t0, c0, jnp.asarray(1e-3, dtype)))
    count = jnp.maximum(jnp.sum(w), 1)
    return matrix_to_rotvec(R), t, jnp.sqrt(c / count)
