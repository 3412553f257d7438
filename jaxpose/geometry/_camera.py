"""The pinhole camera as a 3x4 projection matrix calibrated in the world frame.

A camera is a matrix `C` (3, 4) with rows `c1, c2, c3`; a world point `p` is seen at
pixel `(u, v)` when (the paper's Eq. 4)

$$ s \\, [u\\ v\\ 1]^T = C \\, [p\\ 1]^T, \\qquad s \\neq 0 $$

for some scale `s` of either sign: `C` and `-C` are the same camera. Write
`C = [M | c4]` with `M` (3, 3). The OpenCV convention is the special case
`C = K [R_wc | t_wc]`, `(R_wc, t_wc)` mapping world to camera coordinates.

Every function here is a pure `jax.numpy` function of ONE camera and `(n, ...)` points
(no batch axis; batch with `jax.vmap`), follows the floating dtype of its inputs
(integers are promoted to JAX's default float), composes with `jit`, `vmap` and `grad`,
and never produces NaN: degenerate inputs (a singular `M`, a point on the focal plane
of the camera) yield the finite placeholders documented per function. The one
exception is `undistort_pixels`, a numpy helper for the public boundary.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import numpy.typing as npt
from jaxtyping import Array, ArrayLike, Float, Real

from ._numerics import adjugate3, as_float, det3, safe_norm, safe_normalize
from ._validate import as_dist_coeffs

__all__ = [
    "backproject",
    "camera_centre",
    "camera_matrix",
    "decompose_camera",
    "normalize_camera",
    "project",
    "project_with_depth",
    "ray_planes",
    "undistort_pixels",
]


# --------------------------------------------------------------------------- helpers


def _sign(x: Array) -> Array:
    """Sign that is never zero: +1 for `x >= 0`, -1 otherwise (no gradient)."""
    return jnp.where(x < 0, -1, 1).astype(x.dtype)


# --------------------------------------------------------------------------- building


def camera_matrix(
    K: Real[ArrayLike, "3 3"],
    R: Real[ArrayLike, "3 3"] | None = None,
    t: Real[ArrayLike, " 3"] | None = None,
) -> Float[Array, "3 4"]:
    """Projection matrix `C = K [R | t]` from intrinsics and a world-to-camera motion.

    $$ C = K \\, [R \\mid t], \\qquad x_{cam} = R \\, p + t $$

    **Arguments:**

    - `K`: intrinsic matrix, shape (3, 3).
    - `R`: world-to-camera rotation, shape (3, 3); default the identity.
    - `t`: world-to-camera translation, shape (3,); default zero.

    **Returns:**

    `C`, shape (3, 4), in the common floating dtype of the inputs.
    """
    K = as_float(K)
    R = jnp.eye(3, dtype=K.dtype) if R is None else R
    t = jnp.zeros(3, dtype=K.dtype) if t is None else t
    K, R, t = as_float(K, R, t)
    return K @ jnp.concatenate([R, t.reshape(3, 1)], axis=1)


def camera_centre(C: Real[ArrayLike, "3 4"]) -> Float[Array, " 3"]:
    """Optical centre of the camera in the world frame: the null vector of `C`.

    $$ C \\, [o\\ 1]^T = 0 \\iff o = -M^{-1} c_4 $$

    **Arguments:**

    - `C`: camera, shape (3, 4).

    **Returns:**

    `o`, shape (3,). Placeholder: the zero vector when `M` is numerically singular,
    `|det M| <= eps ||m1|| ||m2|| ||m3||` (a camera with its centre at infinity).
    """
    C = as_float(C)
    M = C[:, :3]
    adj, det = adjugate3(M), det3(M)
    # Hadamard: |det M| <= ||m1|| ||m2|| ||m3||; a ratio below eps is numerically singular.
    bound = safe_norm(M[0]) * safe_norm(M[1]) * safe_norm(M[2])
    ok = jnp.abs(det) > jnp.finfo(C.dtype).eps * bound
    centre = -(adj @ C[:, 3]) / jnp.where(ok, det, 1)
    return jnp.where(ok, centre, 0)


def normalize_camera(C: Real[ArrayLike, "3 4"]) -> Float[Array, "3 4"]:
    """Rescale `C` so that its third row has `||m3|| = 1` and `det(M) > 0`.

    $$ C' = \\frac{\\operatorname{sign}(\\det M)}{\\|m_3\\|} \\, C $$

    Then `c3' . [p 1]` is the (signed, metric) depth of `p`, positive in front of the
    camera, and `C'` is the same camera as `C`.

    **Arguments:**

    - `C`: camera, shape (3, 4).

    **Returns:**

    `C'`, shape (3, 4). Placeholder: `C` itself (sign-corrected) when `m3 = 0`;
    a zero determinant counts as positive.
    """
    C = as_float(C)
    M = C[:, :3]
    det = det3(M)
    n3 = safe_norm(M[2])
    return C * (_sign(det) / jnp.where(n3 > 0, n3, 1))


def decompose_camera(
    C: Real[ArrayLike, "3 4"],
) -> tuple[Float[Array, "3 3"], Float[Array, "3 3"], Float[Array, " 3"], Float[Array, " 3"]]:
    """Split a camera into intrinsics, world-to-camera rotation and translation, centre.

    With `s = sign(det M)`, an RQ decomposition `s M = K~ R` (`K~` upper triangular with
    positive diagonal, `R` orthonormal) gives

    $$ C = \\lambda \\, K \\, [R \\mid t], \\quad K = K~ / K~_{33}, \\quad
       \\lambda = s \\, K~_{33}, \\quad t = -R \\, o, \\quad o = -M^{-1} c_4 $$

    `R` is a proper rotation (`det R = +1`) whatever the sign of `C`'s scale, because
    the decomposition is taken of `s M`, whose determinant is positive. The RQ step is a
    Gram-Schmidt pass over the rows of `M` from the last one up:
    `r3 = m3 / ||m3||`, `r2` the normalised part of `m2` orthogonal to `r3`,
    `r1 = r2 x r3`, and `K~ = M R^T`, whose lower triangle is zero by construction.

    Compared with `cv2.decomposeProjectionMatrix`: OpenCV does not normalise `K`
    (`K[2,2]` carries the scale), returns the centre homogeneous (4, 1), and for a
    negative scale returns `K` with a negative diagonal entry; here `K[2,2] = 1` always.

    **Arguments:**

    - `C`: camera, shape (3, 4).

    **Returns:**

    `(K, R, t, centre)`, shapes (3, 3), (3, 3), (3,), (3,), with `K[2,2] = 1`,
    `K[0,0], K[1,1] > 0`. Placeholders for a degenerate `M` (zero rows, rank < 3):
    zero rows of the Gram-Schmidt pass stay zero, `K[2,2]` is forced to 1 when
    `||m3|| = 0`, and `centre` and `t` are the zero vector when `M` is singular.
    """
    C = as_float(C)
    M = C[:, :3]
    det = det3(M)
    sM = M * _sign(det)
    r3 = safe_normalize(sM[2])
    r2 = safe_normalize(sM[1] - jnp.dot(sM[1], r3) * r3)
    r1 = jnp.cross(r2, r3)
    R = jnp.stack([r1, r2, r3])
    Kt = jnp.triu(sM @ R.T)
    k33 = Kt[2, 2]
    K = Kt / jnp.where(k33 > 0, k33, 1)
    K = K.at[2, 2].set(1)
    centre = camera_centre(C)
    t = -(R @ centre)
    return K, R, t, centre


# --------------------------------------------------------------------------- projecting


def _homogeneous(C: Float[Array, "3 4"], points: Float[Array, "n 3"]) -> Float[Array, "n 3"]:
    """`C [p 1]^T` for every point, shape (n, 3)."""
    return points @ C[:, :3].T + C[:, 3][None, :]


def _divide_w(h: Float[Array, "n 3"]) -> Float[Array, "n 2"]:
    """`(x / w, y / w)` for homogeneous rows `h = (x, y, w)` (n, 3), finite everywhere.

    A row whose `|w|` is below `floor = eps * max(|x|, |y|) + sqrt(tiny)` (on the
    camera's focal plane, or within about `1e-154` (float64) / `1e-19` (float32) of
    the camera centre) is divided by `sign(w) * floor` instead (zero counts as
    positive): pixels of magnitude at most about `1 / eps`, with zero gradient. Every
    other row is divided by `w` itself, so its value and gradient are the exact ones,
    and bounded.
    """
    info = jnp.finfo(h.dtype)
    xy = h[:, :2]
    w = h[:, 2:3]
    floor = info.eps * jnp.max(jnp.abs(xy), axis=1, keepdims=True) + jnp.sqrt(info.tiny)
    bad = jnp.abs(w) < floor
    exact = xy / jnp.where(bad, 1, w)
    placeholder = jax.lax.stop_gradient(xy / (_sign(w) * floor))
    return jnp.where(bad, placeholder, exact)


def project(C: Real[ArrayLike, "3 4"], points: Real[ArrayLike, "n 3"]) -> Float[Array, "n 2"]:
    """Pixels of world points (the paper's Eq. 4).

    $$ [x\\ y\\ w]^T = C \\, [p\\ 1]^T, \\qquad (u, v) = (x / w,\\ y / w) $$

    Points behind the camera are projected as well (the division is sign-free);
    use `project_with_depth` to tell them apart.

    **Arguments:**

    - `C`: camera, shape (3, 4), any nonzero scale.
    - `points`: world points, shape (n, 3).

    **Returns:**

    Pixels, shape (n, 2). Placeholder: a point (numerically) on the camera's focal
    plane, `|w| < eps * max(|x|, |y|) + sqrt(tiny)`, is divided by that floor instead
    (same sign, zero counts as positive): finite pixels of magnitude up to about
    `1 / eps`, far off the image, so its residual is huge but finite; the placeholder
    carries no gradient. The camera centre itself maps to (0, 0).
    """
    C, points = as_float(C, points)
    return _divide_w(_homogeneous(C, points))


def project_with_depth(
    C: Real[ArrayLike, "3 4"], points: Real[ArrayLike, "n 3"]
) -> tuple[Float[Array, "n 2"], Float[Array, " n"]]:
    """Pixels and signed depths of world points.

    $$ \\operatorname{depth}(p) = \\operatorname{sign}(\\det M) \\,
       \\frac{c_3 \\cdot [p\\ 1]}{\\|m_3\\|} $$

    the metric distance of `p` from the camera's focal plane, positive in front of the
    camera whatever the sign of `C`'s scale.

    **Arguments:**

    - `C`: camera, shape (3, 4).
    - `points`: world points, shape (n, 3).

    **Returns:**

    `(uv, depth)`, shapes (n, 2) and (n,). `uv` as `project` (same placeholder on the
    focal plane, where `depth` is 0). If `m3 = 0` the depth is the unnormalised
    `c3 . [p 1]` (i.e. 0 when also `c34 = 0`).
    """
    C, points = as_float(C, points)
    h = _homogeneous(C, points)
    uv = _divide_w(h)
    det = det3(C[:, :3])
    n3 = safe_norm(C[2, :3])
    depth = h[:, 2] * (_sign(det) / jnp.where(n3 > 0, n3, 1))
    return uv, depth


# --------------------------------------------------------------------------- visual rays


def ray_planes(
    C: Real[ArrayLike, "3 4"], uv: Real[ArrayLike, "n 2"]
) -> tuple[Float[Array, "n 3"], Float[Array, " n"], Float[Array, "n 3"], Float[Array, " n"]]:
    """The two planes whose intersection is the visual ray of each pixel (the paper's Eq. 5).

    $$ n_1 = c_1[{:}3] - u \\, c_3[{:}3], \\quad a_1 = c_1[3] - u \\, c_3[3], $$
    $$ n_2 = c_2[{:}3] - v \\, c_3[{:}3], \\quad a_2 = c_2[3] - v \\, c_3[3]. $$

    A world point `p` lies on the ray of `(u, v)` exactly when
    `n1 . p + a1 = 0` and `n2 . p + a2 = 0`. The planes are not normalised.

    **Arguments:**

    - `C`: camera, shape (3, 4).
    - `uv`: pixels, shape (n, 2).

    **Returns:**

    `(n1, a1, n2, a2)`, shapes (n, 3), (n,), (n, 3), (n,).
    """
    C, uv = as_float(C, uv)
    u = uv[:, 0:1]
    v = uv[:, 1:2]
    p1 = C[0][None, :] - u * C[2][None, :]
    p2 = C[1][None, :] - v * C[2][None, :]
    return p1[:, :3], p1[:, 3], p2[:, :3], p2[:, 3]


def backproject(
    C: Real[ArrayLike, "3 4"], uv: Real[ArrayLike, "n 2"]
) -> tuple[Float[Array, " 3"], Float[Array, "n 3"]]:
    """Camera centre and unit world-frame directions of the visual rays of pixels.

    $$ d \\propto \\operatorname{sign}(\\det M) \\, M^{-1} [u\\ v\\ 1]^T
         = \\operatorname{adj}(M) [u\\ v\\ 1]^T / |\\det M| $$

    normalised; the world point `centre + lam * d`, `lam > 0`, projects to `(u, v)` and
    lies in front of the camera (positive depth), whatever the sign of `C`'s scale.

    **Arguments:**

    - `C`: camera, shape (3, 4).
    - `uv`: pixels, shape (n, 2).

    **Returns:**

    `(centre, directions)`, shapes (3,) and (n, 3). Placeholders for a singular `M`:
    `centre` as `camera_centre` (zero), and a direction whose `adj(M) [u v 1]` vanishes
    is the zero vector.
    """
    C, uv = as_float(C, uv)
    adj = adjugate3(C[:, :3])
    x = jnp.concatenate([uv, jnp.ones_like(uv[:, :1])], axis=1)
    directions = safe_normalize(x @ adj.T)
    return camera_centre(C), directions


# --------------------------------------------------------------------------- distortion


def undistort_pixels(
    uv: npt.ArrayLike,
    K: npt.ArrayLike,
    dist_coeffs: npt.ArrayLike | None,
    *,
    criteria: tuple[int, int, float] | None = None,
) -> np.ndarray | npt.ArrayLike:
    """Remove lens distortion from pixels, staying in pixel units (numpy, not traced).

    Uses `cv2.undistortPoints(uv, K, dist_coeffs, P=K)`: the ideal pinhole pixels that
    `K` alone would have produced. After this, the camera is `K [R | t]` without
    distortion.

    **Arguments:**

    - `uv`: pixels, shape (n, 2) (or OpenCV's (n, 1, 2)).
    - `K`: intrinsic matrix, shape (3, 3).
    - `dist_coeffs`: OpenCV distortion coefficients (4, 5, 8, 12 or 14 of them), or None.
    - `criteria`: optional OpenCV termination criteria `(type, max_iter, eps)` of the
      iterative undistortion; default OpenCV's.

    **Returns:**

    Undistorted pixels, numpy, shape (n, 2), in the floating dtype of `uv` (float64 for
    integer input). When `dist_coeffs` is None or all zero, `uv` is returned unchanged.

    **Raises:**

    `ValueError` naming `dist_coeffs` for a size OpenCV does not accept, or NaN.
    """
    import cv2

    d = as_dist_coeffs(dist_coeffs)
    if d is None:
        return uv
    pts = np.asarray(uv)
    dtype = pts.dtype if np.issubdtype(pts.dtype, np.floating) else np.dtype(np.float64)
    src = pts.reshape(-1, 1, 2).astype(np.float64)
    K64 = np.asarray(K, dtype=np.float64)
    if criteria is None:
        out = cv2.undistortPoints(src, K64, d, P=K64)
    else:
        out = cv2.undistortPoints(src, K64, d, P=K64, criteria=criteria)
    return out.reshape(-1, 2).astype(dtype)


# --------------------------------------------------------------------------- numpy


def project_numpy(C: npt.ArrayLike, points: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Pixels and depths of world points in numpy float64, for drawing and data generation
    (no JAX, no gradient).

    The camera is scaled so that `C[2, :3]` is a unit vector with `det(C[:, :3]) > 0`:
    the returned depth is then the signed distance in front of the camera centre (model
    units), positive in front. A point on the focal plane (`|depth| <= 1e-300`) is divided
    by that floor: finite pixels far off the image.

    **Arguments:** `C` `(3, 4)`; `points` `(n, 3)`.

    **Returns:** `(pixels (n, 2), depth (n,))`.
    """
    C0 = np.asarray(C, dtype=np.float64)
    M = C0[:, :3]
    Cn: np.ndarray = C0 * ((np.sign(np.linalg.det(M)) or 1.0) / np.linalg.norm(M[2]))
    h = np.asarray(points, dtype=np.float64) @ Cn[:, :3].T + Cn[:, 3]
    depth = h[:, 2]
    safe = np.where(np.abs(depth) > 1e-300, depth, np.copysign(1e-300, depth))
    return h[:, :2] / safe[:, None], depth
