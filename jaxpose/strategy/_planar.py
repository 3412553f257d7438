"""The planar ambiguity: a coplanar model seen from afar has two poses that image it
nearly alike; `planar_partner` gives the other one (the mixed algorithm and the answer
from the best roots refine it and keep the better)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float

from ..geometry._numerics import masked_centroid
from ..geometry._pose import Observations, Pose
from ..geometry._rotation import rotvec_to_matrix
from ..solvers._components import (
    Mat3,
    Vec3,
    add,
    cross,
    dot,
    matmul,
    matvec,
    norm_sq,
    scale,
    sub,
    vec_from_array,
)

__all__ = [
    "FLAT_TOL",
    "camera_centre",
    "model_planes",
    "plane_fit",
    "planar_partner",
    "planar_partner_batch",
]

# Flatness below which a model counts as coplanar (planar partner start): RMS distance to
# its best-fit plane over its RMS extent along the plane's narrower direction.
FLAT_TOL = 1e-2


def planar_partner(obs: Observations, pose: Pose) -> tuple[Pose, Array]:
    """The planar-ambiguity partner of `pose` (one problem), and whether the model is
    coplanar (within `FLAT_TOL`).

    A plane seen from afar is imaged nearly alike in two attitudes: its normal `n` and the
    normal reflected about the line of sight `v` to its centroid `p_c`,
    `n' = 2 (n . v) v - n` (IPPE's two solutions). The partner is `pose` rotated about
    `p_c` by the rotation `Q` taking `n` to `n'` (about `n x v`, twice their angle):
    `R' = Q R`, `t' = Q (t - p_c) + p_c`. On the plane `Q` acts as the mirror through
    the plane normal to `v` at `p_c`, which an orthographic view along `v` cannot tell
    apart from the identity."""
    dtype = pose.R.dtype
    w = obs.mask.astype(dtype)
    count = jnp.maximum(jnp.sum(w), 1)
    centre = masked_centroid(obs.model, w)
    X = (obs.model - centre[None, :]) * w[:, None]
    smallest, middle, normal = plane_fit(X.T @ X / count)
    flat = (smallest <= FLAT_TOL**2 * middle) & (middle > 0) & (jnp.sum(w) >= 4)
    n = pose.R @ normal
    p_c = pose.R @ centre + pose.t
    eye = jnp.finfo(dtype).eps ** 0.5
    o = camera_centre(obs.camera)
    sight = p_c - o
    v = sight / jnp.maximum(jnp.linalg.norm(sight), jnp.finfo(dtype).tiny)
    n = jnp.where(jnp.dot(n, v) < 0, -n, n)  # angle to v in [0, pi/2]
    axis = jnp.cross(n, v)
    s = jnp.linalg.norm(axis)
    angle = jnp.arctan2(s, jnp.dot(n, v))
    big = s > eye
    rotvec = jnp.where(big, 2 * angle * axis / jnp.where(big, s, 1), 2 * axis)
    Q = rotvec_to_matrix(rotvec)
    partner = Pose(Q @ pose.R, Q @ (pose.t - p_c) + p_c)
    ok = flat & jnp.all(jnp.isfinite(partner.R)) & jnp.all(jnp.isfinite(partner.t))
    return jax.tree.map(lambda a, b: jnp.where(ok, a, b), partner, pose), ok


def model_planes(
    model: Float[ArrayLike, "B n 3"], mask: ArrayLike
) -> tuple[Vec3, Vec3, Bool[Array, " B"]]:
    """Each model's best-fit plane, batch-first: `(centre, normal, flat)`, the centroid
    of the used points, the unit normal and whether the model is coplanar within
    `FLAT_TOL` (`planar_partner`'s test). The scatter matrix is six sums over the points
    (component form, no 3x3 product per problem), its eigen-decomposition `plane_fit`'s:
    cheap beside a partner, so that a batch can ask first and build partners only where
    one exists."""
    model = jnp.asarray(model)
    w = jnp.asarray(mask).astype(model.dtype)
    count = jnp.maximum(jnp.sum(w, axis=-1), 1)
    x, y, z = (model[..., i] for i in range(3))
    centre = Vec3(*(jnp.sum(a * w, axis=-1) / count for a in (x, y, z)))
    dx, dy, dz = ((a - c[:, None]) * w for a, c in zip((x, y, z), centre, strict=True))
    pairs = ((dx, dx), (dx, dy), (dx, dz), (dy, dy), (dy, dz), (dz, dz))
    sxx, sxy, sxz, syy, syz, szz = (jnp.sum(a * b, axis=-1) / count for a, b in pairs)
    S = jnp.stack(
        [jnp.stack(r, axis=-1) for r in ((sxx, sxy, sxz), (sxy, syy, syz), (sxz, syz, szz))],
        axis=-2,
    )
    smallest, middle, normal = jax.vmap(plane_fit)(S)
    flat = (smallest <= FLAT_TOL**2 * middle) & (middle > 0) & (jnp.sum(w, axis=-1) >= 4)
    return centre, vec_from_array(normal), flat


def planar_partner_batch(
    camera: Float[ArrayLike, "B 3 4"], R: Mat3, t: Vec3, centre: Vec3, normal: Vec3
) -> tuple[Mat3, Vec3, Bool[Array, " B"]]:
    """`planar_partner` for a batch in component form (`R`, `t` of shape `(B,)` each;
    `centre`, `normal` from `model_planes`): `(R', t', finite)`. The rotation taking `n`
    to its mirror about the line of sight `v` turns by twice their angle `theta` about
    `a = n x v` (`|a| = sin theta`, `n . v = cos theta`), so
    `Q = (1 - 2 |a|^2) I + 2 cos(theta) [a]x + 2 a a^T`: no trigonometric function and no
    division by `|a|` (it is the identity when `n` lies along `v`)."""
    n = matvec(R, normal)
    p_c = add(matvec(R, centre), t)
    o = vec_from_array(jax.vmap(camera_centre)(camera))
    sight = sub(p_c, o)
    dtype = sight.x.dtype
    length = jnp.sqrt(norm_sq(sight))
    v = scale(sight, 1 / jnp.maximum(length, jnp.finfo(dtype).tiny))
    c = dot(n, v)
    n = scale(n, jnp.where(c < 0, -1.0, 1.0).astype(dtype))  # angle to v in [0, pi/2]
    c = jnp.abs(c)
    a = cross(n, v)
    s2 = norm_sq(a)
    diag = 1 - 2 * s2
    Q = Mat3(
        diag + 2 * a.x * a.x,
        2 * a.x * a.y - 2 * c * a.z,
        2 * a.x * a.z + 2 * c * a.y,
        2 * a.y * a.x + 2 * c * a.z,
        diag + 2 * a.y * a.y,
        2 * a.y * a.z - 2 * c * a.x,
        2 * a.z * a.x - 2 * c * a.y,
        2 * a.z * a.y + 2 * c * a.x,
        diag + 2 * a.z * a.z,
    )
    Rp = matmul(Q, R)
    tp = add(matvec(Q, sub(t, p_c)), p_c)
    finite = jnp.ones_like(c, dtype=bool)
    for part in (*Rp, *tp):
        finite = finite & jnp.isfinite(part)
    return Rp, tp, finite


def camera_centre(camera: Float[ArrayLike, "3 4"]) -> Float[Array, " 3"]:
    """The centre `o` of a camera, `C [o 1]^T = 0`: `-M^-1 c4` for `C = [M | c4]`, by
    cross products of the rows of `M` (no LAPACK call)."""
    camera = jnp.asarray(camera)
    r1, r2, r3 = camera[0, :3], camera[1, :3], camera[2, :3]
    c1, c2, c3 = jnp.cross(r2, r3), jnp.cross(r3, r1), jnp.cross(r1, r2)
    det = jnp.dot(r1, c1)
    safe = jnp.where(det != 0, det, 1)
    return -(camera[0, 3] * c1 + camera[1, 3] * c2 + camera[2, 3] * c3) / safe


def plane_fit(S: Float[ArrayLike, "3 3"]) -> tuple[Array, Array, Float[Array, " 3"]]:
    """The two smallest eigenvalues of a symmetric positive semi-definite 3x3 matrix
    (a scatter matrix) and a unit eigenvector of the smallest (the normal of the best-fit
    plane), in closed form: the eigenvalues by the trigonometric solution of the
    characteristic cubic, the vector as the longest cross product of two rows of
    `S - lambda I` (no LAPACK call; `jnp.linalg.eigh`'s values up to rounding)."""
    S = jnp.asarray(S)
    dtype = S.dtype
    q = jnp.trace(S) / 3
    off = S[0, 1] ** 2 + S[0, 2] ** 2 + S[1, 2] ** 2
    p2 = (S[0, 0] - q) ** 2 + (S[1, 1] - q) ** 2 + (S[2, 2] - q) ** 2 + 2 * off
    p = jnp.sqrt(p2 / 6)
    round_ = p > jnp.finfo(dtype).tiny ** 0.5  # else: a multiple of the identity
    B = (S - q * jnp.eye(3, dtype=dtype)) / jnp.where(round_, p, 1)
    r = jnp.clip(jnp.dot(B[0], jnp.cross(B[1], B[2])) / 2, -1, 1)  # det(B) / 2
    phi = jnp.arccos(r) / 3  # in [0, pi/3]: cos(phi) >= cos(phi - 2pi/3) >= cos(phi + 2pi/3)
    largest = q + 2 * p * jnp.cos(phi)
    smallest = q + 2 * p * jnp.cos(phi + 2 * jnp.pi / 3)
    middle = 3 * q - largest - smallest
    smallest, middle = jnp.where(round_, smallest, q), jnp.where(round_, middle, q)
    A = S - smallest * jnp.eye(3, dtype=dtype)
    crosses = jnp.stack([jnp.cross(A[0], A[1]), jnp.cross(A[0], A[2]), jnp.cross(A[1], A[2])])
    lengths = jnp.sum(crosses**2, axis=1)
    best = crosses[jnp.argmax(lengths)]
    length = jnp.sqrt(jnp.max(lengths))
    fallback = jnp.array([0, 0, 1], dtype)
    normal = jnp.where(length > 0, best / jnp.where(length > 0, length, 1), fallback)
    return smallest, middle, normal
