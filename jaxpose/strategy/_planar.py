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
    mat_to_array,
    matmul,
    matvec,
    norm_sq,
    scale,
    sub,
    vec_from_array,
    vec_to_array,
)
from ..solvers._kernel_linear import matches_from_observations

__all__ = [
    "FLAT_TOL",
    "camera_centre",
    "model_planes",
    "plane_fit",
    "planar_partner",
    "planar_partner_batch",
    "planar_poses",
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


def _rotation_to(d: Float[Array, " 3"]) -> Float[Array, "3 3"]:
    """The rotation about `e_z x d` taking `e_z` to the unit vector `d` (`d_z > 0`):
    `I + [k]x + [k]x^2 / (1 + d_z)`, `k = e_z x d`."""
    k = jnp.stack([-d[1], d[0], jnp.zeros_like(d[0])])
    kx = jnp.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]], d.dtype)
    return jnp.eye(3, dtype=d.dtype) + kx + kx @ kx / (1 + d[2])


def _plane_basis(normal: Float[Array, " 3"]) -> Float[Array, "3 3"]:
    """A rotation whose third column is the unit `normal` (its columns: two directions in
    the plane, then the normal)."""
    axis = jnp.eye(3, dtype=normal.dtype)[jnp.argmin(jnp.abs(normal))]
    e1 = jnp.cross(normal, axis)
    e1 = e1 / jnp.linalg.norm(e1)
    return jnp.stack([e1, jnp.cross(normal, e1), normal], axis=1)


def _homography(u: Array, x: Array, w: Array) -> Array:
    """The homography `H` with `[x 1] ~ H [u 1]` of the weighted matches (`u`, `x` of
    `(n, 2)`, `w` `(n,)` 0 or 1) by the normalised direct linear transform: both point
    sets centred and scaled to an RMS distance of `sqrt 2`, `h` the eigenvector of the
    smallest eigenvalue of `A^T A` (`A` the two rows of each match)."""
    dtype = u.dtype
    count = jnp.maximum(jnp.sum(w), 1)

    def normaliser(p):
        c = jnp.sum(p * w[:, None], axis=0) / count
        d = p - c[None, :]
        rms = jnp.sqrt(jnp.sum(jnp.sum(d**2, axis=1) * w) / count)
        s = jnp.sqrt(2.0) / jnp.where(rms > 0, rms, 1)
        T = jnp.array([[s, 0, -s * c[0]], [0, s, -s * c[1]], [0, 0, 1]], dtype)
        return d * s, T

    un, Tu = normaliser(u)
    xn, Tx = normaliser(x)
    one, zero = jnp.ones_like(w), jnp.zeros_like(w)
    a, b = un[:, 0], un[:, 1]
    X, Y = xn[:, 0], xn[:, 1]
    rows_x = jnp.stack([a, b, one, zero, zero, zero, -X * a, -X * b, -X], axis=1)
    rows_y = jnp.stack([zero, zero, zero, a, b, one, -Y * a, -Y * b, -Y], axis=1)
    A = jnp.concatenate([rows_x, rows_y]) * jnp.concatenate([w, w])[:, None]
    _, vectors = jnp.linalg.eigh(A.T @ A)
    Hn = vectors[:, 0].reshape(3, 3)
    # H = Tx^-1 Hn Tu (Tx^-1 in closed form: a scale and a shift)
    s, cx, cy = Tx[0, 0], -Tx[0, 2] / Tx[0, 0], -Tx[1, 2] / Tx[0, 0]
    Tx_inv = jnp.array([[1 / s, 0, cx], [0, 1 / s, cy], [0, 0, 1]], dtype)
    return Tx_inv @ Hn @ Tu


def planar_poses(obs: Observations) -> tuple[Pose, Bool[Array, " 2"]]:
    """The two poses of a coplanar model from the homography of its plane to the image
    (one problem; infinitesimal plane-based pose estimation, Collins & Bartoli 2014):
    `(Pose` with a leading axis of 2, `ok (2,))`, `ok` False for a model that is not
    coplanar (`FLAT_TOL`, as `planar_partner`) or a degenerate homography.

    In the camera's whitened frame (`jaxpose.solvers._kernel_linear.Matches`: there the
    image is the pinhole's normalised coordinates `x`) and the plane's own coordinates
    `u` (about the model's centroid, along its best-fit plane), the homography `H`
    (`_homography`) maps the centroid to `v = H(0)` with Jacobian `J`. A pose `x =
    proj(R_p [u 0] + t)` has, at `u = 0`, `J = B R'_{2x2} / t_z` with `R_p = R_v R'`,
    `R_v` the rotation taking `e_z` to the ray of `v`, and `B = [I_2 | -v] R_v[:, :2]`.
    So `A = B^-1 J` is the top-left block of a rotation scaled by `1 / t_z`: its largest
    singular value `gamma` is `1 / t_z`, `R'_{2x2} = A / gamma`, and the third row `b`
    of the first two columns satisfies `b b^T = I - R'_{2x2}^T R'_{2x2}` (rank one),
    which fixes `b` up to its sign: the two poses of the planar ambiguity, `b` and `-b`.
    Each rotation's translation is the linear least-squares one (the cross-multiplied
    projection equations of every match)."""
    m = matches_from_observations(obs)
    dtype = m.x.dtype
    w = m.mask.astype(dtype)
    count = jnp.sum(w)
    centred = jnp.stack(list(m.model), axis=1)  # (n, 3): about the centroid, 0 if unused
    smallest, middle, normal = plane_fit(centred.T @ centred / jnp.maximum(count, 1))
    flat = (smallest <= FLAT_TOL**2 * middle) & (middle > 0) & (count >= 4)
    basis = _plane_basis(normal)
    u = (centred @ basis)[:, :2]
    x = jnp.stack([m.x, m.y], axis=1)
    H = _homography(u, x, w)
    h33 = jnp.where(H[2, 2] != 0, H[2, 2], 1)
    v = H[:2, 2] / h33
    J = (H[:2, :2] - v[:, None] * H[2, :2][None, :]) / h33
    d = jnp.concatenate([v, jnp.ones((1,), dtype)])
    Rv = _rotation_to(d / jnp.linalg.norm(d))
    B = (jnp.concatenate([jnp.eye(2, dtype=dtype), -v[:, None]], axis=1) @ Rv)[:, :2]
    det_B = B[0, 0] * B[1, 1] - B[0, 1] * B[1, 0]
    B_inv = jnp.array([[B[1, 1], -B[0, 1]], [-B[1, 0], B[0, 0]]]) / jnp.where(det_B != 0, det_B, 1)
    A = B_inv @ J
    frob = jnp.sum(A**2)
    det_A = A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]
    gamma = jnp.sqrt((frob + jnp.sqrt(jnp.maximum(frob**2 - 4 * det_A**2, 0))) / 2)
    R22 = A / jnp.where(gamma > 0, gamma, 1)
    M = jnp.eye(2, dtype=dtype) - R22.T @ R22
    first = M[0, 0] >= M[1, 1]
    lead = jnp.sqrt(jnp.maximum(jnp.where(first, M[0, 0], M[1, 1]), 0))
    other = jnp.where(lead > 0, M[0, 1] / jnp.where(lead > 0, lead, 1), 0)
    b = jnp.where(first, jnp.stack([lead, other]), jnp.stack([other, lead]))
    tiny = jnp.finfo(dtype).tiny
    frame, offset, centroid = (
        mat_to_array(m.frame),
        vec_to_array(m.offset),
        vec_to_array(m.centroid),
    )

    def pose(sign):
        c1 = jnp.stack([R22[0, 0], R22[1, 0], sign * b[0]])
        c2 = jnp.stack([R22[0, 1], R22[1, 1], sign * b[1]])
        Rp = Rv @ jnp.stack([c1, c2, jnp.cross(c1, c2)], axis=1)
        Rf = Rp @ basis.T  # model (about its centroid) to the whitened frame
        q = centred @ Rf.T  # (n, 3)
        # x (q_z + t_z) = q_x + t_x, y (q_z + t_z) = q_y + t_y, least squares in t
        rows = jnp.stack(
            [
                jnp.stack([-w, jnp.zeros_like(w), w * m.x], axis=1),
                jnp.stack([jnp.zeros_like(w), -w, w * m.y], axis=1),
            ]
        )  # (2, n, 3)
        rhs = jnp.stack([w * (q[:, 0] - m.x * q[:, 2]), w * (q[:, 1] - m.y * q[:, 2])])
        N = jnp.einsum("kni,knj->ij", rows, rows)
        r = jnp.einsum("kni,kn->i", rows, rhs)
        adj = jnp.stack([jnp.cross(N[1], N[2]), jnp.cross(N[2], N[0]), jnp.cross(N[0], N[1])])
        det_N = jnp.dot(N[0], adj[0])
        t_f = adj.T @ r / jnp.where(jnp.abs(det_N) > tiny, det_N, 1)
        R = frame.T @ Rf
        t = frame.T @ (t_f - offset) - R @ centroid
        return R, t, jnp.abs(det_N) > tiny

    R1, t1, ok1 = pose(1.0)
    R2, t2, ok2 = pose(-1.0)
    poses = Pose(jnp.stack([R1, R2]), jnp.stack([t1, t2]))
    ok = flat & (det_B != 0) & (gamma > 0) & jnp.stack([ok1, ok2])
    ok = ok & jax.vmap(lambda R, t: jnp.all(jnp.isfinite(R)) & jnp.all(jnp.isfinite(t)))(
        poses.R, poses.t
    )
    return poses, ok
