"""Pointing (the paper's Section 6): a clicked pixel -> the 3D point of the object under it.

The operator clicks a pixel `(u, v)` on a recognised object. Its visual ray leaves the
camera centre `o` along the unit direction `d` (`jaxpose.geometry.backproject`),

$$ x(\\lambda) = o + \\lambda \\, d, \\qquad \\lambda > 0, $$

and meets the plane of face `f` (outward normal `n_f`, a point `c_f` of the face, both in
the world frame at the object's pose `p = R m + t`) at

$$ \\lambda_f = \\frac{n_f \\cdot (c_f - o)}{n_f \\cdot d}. $$

The answer is the nearest `lambda_f > 0` whose point lies inside face `f`'s polygon: the
3D position order for the robot, in the world frame, and the face it is on.

Faces are planar polygons, counter-clockwise seen from outside (`Polyhedron.faces`),
convex or not. They are held as one fixed-shape array `(F, K, 3)`, every face padded to
the largest vertex count `K` with a mask (`polyhedron_faces`). A face's normal is
Newell's area vector (exact for planar polygons, robust for non-convex ones); the
inside test is the winding number of the polygon around the point, summed from the
signed angles that each edge subtends (`2 pi` inside, `0` outside), which needs no
projection to 2D and treats padded (repeated) vertices as zero-length edges.

**Uncertainty.** With the pose perturbed as `R = exp(hat(w)) R^`, `t = t^ + dt`
(vector order `(w, dt)`, the order of `jaxpose`'s 6x6 pose covariances) and the click as
`(u, v) + du`, the intersection with the chosen face is a smooth function `x(w, dt, du)`;
its Jacobian (`jax.jacfwd`, at zero) carries a pose covariance `S_pose` (6, 6) and a
pixel covariance `S_px` (2, 2) to the point:

$$ \\Sigma_x = J_{pose} S_{pose} J_{pose}^T + J_{px} S_{px} J_{px}^T . $$

With the pixel held exact, the point can only move along the visual ray (rank one);
click noise spreads it across.

Everything here is pure JAX for ONE click (no batch axis; `jax.vmap` over pixels),
fixed shapes, no Python branching on values, NaN-free.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int, Real

from ..geometry._camera import backproject
from ..geometry._numerics import as_float, masked_centroid, safe_norm, safe_normalize
from ..geometry._pose import Pose
from ..geometry._rotation import rotvec_to_matrix
from ..geometry._validate import no_type_check
from ..solvers._status import StatusCode
from ._polyhedron import Polyhedron

__all__ = [
    "Faces",
    "Hit",
    "PointingStatus",
    "face_normals",
    "intersect_ray",
    "pick",
    "polyhedron_faces",
]


class PointingStatus(StatusCode):
    """What became of a click (`Hit.status`). `OK` and `NOT_FINITE` have the values of the
    solvers' `Status`."""

    OK = 0, "the visual ray meets a face of the object"
    NOT_FINITE = 11, "non-finite values in the input"
    NO_FACE = 13, "the visual ray of the pixel meets none of the object's faces"


class Faces(NamedTuple):
    """The faces of a polyhedral model as fixed-shape arrays, in the MODEL frame.

    **Fields:**
    - `vertices`: `(F, K, 3)` the corners of each face in order (counter-clockwise seen
      from outside), padded to `K` corners by repeating the face's first corner.
    - `mask`: `(F, K)` bool, which corners are real.

    Numpy arrays from `polyhedron_faces`; JAX arrays inside `jit`/`vmap`.
    """

    vertices: Float[Array | np.ndarray, "f k 3"]
    mask: Bool[Array | np.ndarray, "f k"]


class Hit(NamedTuple):
    """Where a visual ray meets an object.

    **Fields:**
    - `point`: `(3,)` the nearest intersection, world frame (model units, e.g. mm).
      Placeholder when nothing is hit: the zero vector.
    - `face`: `()` int32, index of the face it lies on (into `Faces` / `Polyhedron.faces`);
      `-1` when nothing is hit.
    - `distance`: `()` distance from the camera centre along the ray (0 when no hit).
    - `normal`: `(3,)` unit outward normal of that face, world frame (zero when no hit).
    - `covariance`: `(3, 3)` covariance of `point` propagated from the pose and pixel
      covariances given to `pick` (zero when none were given, or no hit).
    - `status`: `()` int32 `PointingStatus`: `OK`, `NO_FACE` (the ray misses the object) or
      `NOT_FINITE` (non-finite input).
    """

    point: Float[Array, " 3"]
    face: Int[Array, ""]
    distance: Float[Array, ""]
    normal: Float[Array, " 3"]
    covariance: Float[Array, "3 3"]
    status: Int[Array, ""]


# --------------------------------------------------------------------------- building


def polyhedron_faces(model: Polyhedron) -> Faces:
    """The faces of a `Polyhedron` as padded fixed-shape arrays (numpy, not traced).

    **Arguments:**
    - `model`: a `jaxpose.Polyhedron` (vertices `(V, 3)`; faces as index tuples,
      counter-clockwise seen from outside).

    **Returns:** `Faces` with `vertices` `(F, K, 3)` float64 and `mask` `(F, K)`, `K` the
    largest face's corner count; shorter faces repeat their first corner.

    **Raises:** `ValueError` naming `model` for a face with fewer than three corners, an
    index out of range, or non-finite vertices.
    """
    vertices = np.asarray(model.vertices, dtype=np.float64)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise ValueError(f"model.vertices must have shape (V, 3), got {vertices.shape}")
    if not np.all(np.isfinite(vertices)):
        raise ValueError("model.vertices contains NaN or infinite values")
    faces = [tuple(int(i) for i in f) for f in model.faces]
    if not faces:
        raise ValueError("model has no faces")
    for k, f in enumerate(faces):
        if len(f) < 3:
            raise ValueError(f"model.faces[{k}] has {len(f)} corners; a face needs at least 3")
        if min(f) < 0 or max(f) >= len(vertices):
            raise ValueError(
                f"model.faces[{k}] indexes a vertex outside 0..{len(vertices) - 1}: {f}"
            )
    width = max(len(f) for f in faces)
    index = np.array([list(f) + [f[0]] * (width - len(f)) for f in faces], dtype=np.int64)
    mask = np.array([[i < len(f) for i in range(width)] for f in faces], dtype=bool)
    return Faces(vertices[index], mask)


def _check_shape(x, shape, name):
    if tuple(x.shape) != shape:
        raise ValueError(f"{name} must have shape {shape}, got {tuple(x.shape)}")


def _check_faces(faces: Faces) -> None:
    v, m = jnp.shape(faces.vertices), jnp.shape(faces.mask)
    if len(v) != 3 or v[2] != 3 or v[1] < 3:
        raise ValueError(f"faces.vertices must have shape (F, K, 3) with K >= 3, got {v}")
    if tuple(m) != tuple(v[:2]):
        raise ValueError(f"faces.mask must have shape {tuple(v[:2])}, got {tuple(m)}")


# --------------------------------------------------------------------------- geometry


def _world_faces(faces: Faces, pose: Pose, dtype):
    """Face corners in the world frame `(F, K, 3)`, masked corners replaced by the first."""
    v = jnp.asarray(faces.vertices, dtype)
    mask = jnp.asarray(faces.mask, bool)
    v = jnp.where(mask[..., None], v, v[:, :1, :])
    return v @ pose.R.T + pose.t[None, None, :]


def _area_vector(corners):
    """Newell's area vector of a closed polygon `(K, 3)`: `0.5 sum_k c_k x c_{k+1}`.

    Its direction is the right-hand normal (outward for counter-clockwise corners seen
    from outside), its length the polygon's area; repeated corners add nothing.
    """
    return 0.5 * jnp.sum(jnp.cross(corners, jnp.roll(corners, -1, axis=0)), axis=0)


def _safe_unit(x):
    """`x / |x|` and whether `|x| > 0` (the zero vector gives zero, with zero gradient)."""
    return safe_normalize(x, fallback=0), safe_norm(x) > 0


def face_normals(faces: Faces, pose: Pose) -> Float[Array, "f 3"]:
    """Unit outward normals of the faces at a pose, world frame `(F, 3)` (zero for a
    face of zero area)."""
    _check_faces(faces)
    R, t = as_float(pose.R, pose.t)
    corners = _world_faces(faces, Pose(R, t), R.dtype)
    return jax.vmap(lambda c: _safe_unit(_area_vector(c))[0])(corners)


def _plane_hit(origin, direction, corners, mask):
    """Distance `lambda` to the plane of one face, and whether the ray crosses it there
    (finite, non-parallel). Differentiable in all arguments."""
    dtype = origin.dtype
    area = _area_vector(corners)
    centroid = masked_centroid(corners, mask)
    denom = jnp.dot(area, direction)
    scale = jnp.sqrt(jnp.sum(area * area)) * jnp.sqrt(jnp.sum(direction * direction))
    crossing = jnp.abs(denom) > 64 * jnp.finfo(dtype).eps * scale
    lam = jnp.dot(area, centroid - origin) / jnp.where(crossing, denom, 1)
    return jnp.where(crossing, lam, 0), crossing


def _winding(point, corners, normal):
    """Winding number (in turns) of a closed polygon `(K, 3)` around a point of its plane,
    about `normal`: about 1 inside a counter-clockwise polygon, 0 outside."""
    a = corners - point[None, :]
    b = jnp.roll(corners, -1, axis=0) - point[None, :]
    sin = jnp.cross(a, b) @ normal
    cos = jnp.sum(a * b, axis=1)
    return jnp.sum(jnp.arctan2(sin, cos)) / (2 * jnp.pi)


def _all_hits(origin, direction, corners, mask):
    """`(lambda, valid)` of every face `(F,)`: in front of the origin, inside the face."""

    def one(c, m):
        lam, crossing = _plane_hit(origin, direction, c, m)
        x = origin + lam * direction
        normal, nonzero = _safe_unit(_area_vector(c))
        inside = _winding(x, c, normal) > 0.5
        return lam, crossing & nonzero & inside & (lam > 0)

    return jax.vmap(one)(corners, mask)


def _finite(*xs):
    return jnp.all(jnp.stack([jnp.all(jnp.isfinite(x)) for x in xs]))


# `intersect_ray` and `pick` check their arguments' shapes themselves (a `ValueError`
# naming the argument): no run-time type check comes before theirs.
@no_type_check
def intersect_ray(
    origin: Real[ArrayLike, " 3"],
    direction: Real[ArrayLike, " 3"],
    faces: Faces,
    pose: Pose,
) -> Hit:
    """The nearest face of an object (at `pose`) that a ray meets.

    $$ \\lambda^* = \\min \\{ \\lambda_f > 0 : o + \\lambda_f d \\in \\text{face } f \\} $$

    **Arguments:**
    - `origin`: `(3,)` where the ray starts (world frame).
    - `direction`: `(3,)` its direction (need not be unit; `distance` is then in units of
      `|direction|`).
    - `faces`: the object's `Faces` (model frame).
    - `pose`: `Pose(R, t)` mapping model to world, `p = R m + t`.

    **Returns:** a `Hit` (its `covariance` is zero; see `pick`). Points exactly on an edge
    shared by two faces go to either face.
    """
    _check_faces(faces)
    origin, direction, R, t = as_float(origin, direction, pose.R, pose.t)
    _check_shape(origin, (3,), "origin")
    _check_shape(direction, (3,), "direction")
    _check_shape(R, (3, 3), "pose.R")
    _check_shape(t, (3,), "pose.t")
    return _intersect(origin, direction, faces, Pose(R, t))


def _intersect(origin, direction, faces, pose) -> Hit:
    dtype = origin.dtype
    corners = _world_faces(faces, pose, dtype)
    mask = jnp.asarray(faces.mask, bool)
    finite = _finite(origin, direction, corners)
    # The choice of face is discrete: no gradient flows through it.
    lam, valid = jax.lax.stop_gradient(
        _all_hits(
            jnp.where(finite, origin, 0),
            jnp.where(finite, direction, 0),
            jnp.where(finite, corners, 0),
            mask,
        )
    )
    big = jnp.finfo(dtype).max
    face = jnp.argmin(jnp.where(valid, lam, big))
    found = jnp.any(valid) & finite
    # Recompute the chosen face's distance differentiably.
    lam_f, _ = _plane_hit(origin, direction, corners[face], mask[face])
    point = origin + lam_f * direction
    normal, _ = _safe_unit(_area_vector(corners[face]))
    zero3 = jnp.zeros(3, dtype)
    status = jnp.where(
        finite,
        jnp.where(found, PointingStatus.OK, PointingStatus.NO_FACE),
        PointingStatus.NOT_FINITE,
    )
    return Hit(
        point=jnp.where(found, point, zero3),
        face=jnp.where(found, face, -1).astype(jnp.int32),
        distance=jnp.where(found, lam_f * safe_norm(direction), 0).astype(dtype),
        normal=jnp.where(found, normal, zero3),
        covariance=jnp.zeros((3, 3), dtype),
        status=status.astype(jnp.int32),
    )


# --------------------------------------------------------------------------- clicking


def _point_on_face(params, camera, corners_model, mask, pose):
    """The intersection of the visual ray of pixel `params[6:8]` with ONE face at the pose
    perturbed by `(w, dt) = params[:6]` (`R = exp(hat(w)) R^`, `t = t^ + dt`)."""
    R = rotvec_to_matrix(params[:3]) @ pose.R
    t = pose.t + params[3:6]
    origin, directions = backproject(camera, params[None, 6:8])
    corners = corners_model @ R.T + t[None, :]
    lam, _ = _plane_hit(origin, directions[0], corners, mask)
    return origin + lam * directions[0]


@no_type_check
def pick(
    camera: Real[ArrayLike, "3 4"],
    faces: Faces,
    pose: Pose,
    pixel: Real[ArrayLike, " 2"],
    pose_covariance: Real[ArrayLike, "6 6"] | None = None,
    pixel_covariance: Real[ArrayLike, "2 2"] | None = None,
) -> Hit:
    """The 3D point of the object under a clicked pixel, its face and its covariance.

    The visual ray of `pixel` (from `jaxpose.geometry.camera_centre(camera)` along
    `jaxpose.geometry.backproject`, in front of the camera) is intersected with every face of the
    object at `pose`; the nearest intersection inside a face wins (see the module
    docstring). Vmap over clicks: `jax.vmap(pick, in_axes=(None, None, None, 0))`.

    **Arguments:**
    - `camera`: the 3x4 matrix `C`, calibrated in the world frame.
    - `faces`: the object's `Faces` (`polyhedron_faces(model)`).
    - `pose`: the object's `Pose(R, t)`, model to world (e.g. `jaxpose.solve(...).pose`).
    - `pixel`: `(2,)` the clicked pixel `(u, v)`.
    - `pose_covariance`: optional `(6, 6)` covariance of the pose in the parameterisation
      `R = exp(hat(w)) R^`, `t = t^ + dt`, vector order `(w, dt)` (radians, model units).
    - `pixel_covariance`: optional `(2, 2)` covariance of the click (px^2), e.g.
      `sigma^2 I`.

    **Returns:** a `Hit`: world point, face index, distance from the camera centre, the
    face's outward normal, the point's `(3, 3)` covariance (first order, `jax.jacfwd` of
    the intersection with the chosen face; zero when no covariance is given) and the
    status (`OK`, `NO_FACE`, `NOT_FINITE`); finite placeholders when nothing is hit.

    **Raises:** `ValueError` naming the argument for a wrong shape (shapes are static, so
    this also holds under `jit`).
    """
    _check_faces(faces)
    C, R, t, pixel = as_float(camera, pose.R, pose.t, pixel)
    _check_shape(C, (3, 4), "camera")
    _check_shape(R, (3, 3), "pose.R")
    _check_shape(t, (3,), "pose.t")
    _check_shape(pixel, (2,), "pixel")
    dtype = C.dtype
    covariances = []
    for S, size, name in (
        (pose_covariance, 6, "pose_covariance"),
        (pixel_covariance, 2, "pixel_covariance"),
    ):
        if S is not None:
            S = jnp.asarray(S, dtype)
            _check_shape(S, (size, size), name)
        covariances.append(S)
    Sp, Sx = covariances
    finite = _finite(C, R, t, pixel, *(S for S in covariances if S is not None))
    # Non-finite input: run on harmless placeholders, report NOT_FINITE.
    C = jnp.where(finite, C, jnp.eye(3, 4, dtype=dtype))
    pose = Pose(jnp.where(finite, R, jnp.eye(3, dtype=dtype)), jnp.where(finite, t, 0))
    pixel = jnp.where(finite, pixel, 0)
    origin, directions = backproject(C, pixel[None, :])
    hit = _intersect(origin, directions[0], faces, pose)
    if Sp is not None or Sx is not None:
        S = jnp.zeros((8, 8), dtype)
        if Sp is not None:
            S = S.at[:6, :6].set(jnp.where(finite, Sp, 0))
        if Sx is not None:
            S = S.at[6:, 6:].set(jnp.where(finite, Sx, 0))
        face = jnp.maximum(hit.face, 0)
        corners = jnp.asarray(faces.vertices, dtype)[face]
        mask = jnp.asarray(faces.mask, bool)[face]
        corners = jnp.where(mask[:, None], corners, corners[:1])
        params = jnp.concatenate([jnp.zeros(6, dtype), pixel])
        J = jax.jacfwd(_point_on_face)(params, C, corners, mask, pose)
        cov = J @ S @ J.T
        cov = 0.5 * (cov + cov.T)
        ok = (hit.status == PointingStatus.OK) & _finite(cov)
        hit = hit._replace(covariance=jnp.where(ok, cov, 0))
    return _unless(hit, finite)


def _unless(hit: Hit, finite) -> Hit:
    """`hit`, or the no-hit placeholders with status `NOT_FINITE` when not `finite`."""
    dtype = hit.point.dtype
    return Hit(
        point=jnp.where(finite, hit.point, jnp.zeros(3, dtype)),
        face=jnp.where(finite, hit.face, -1).astype(jnp.int32),
        distance=jnp.where(finite, hit.distance, 0).astype(dtype),
        normal=jnp.where(finite, hit.normal, jnp.zeros(3, dtype)),
        covariance=jnp.where(finite, hit.covariance, jnp.zeros((3, 3), dtype)),
        status=jnp.where(finite, hit.status, PointingStatus.NOT_FINITE).astype(jnp.int32),
    )
