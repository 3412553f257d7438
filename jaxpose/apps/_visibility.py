"""What a camera sees of a polyhedral model at a pose, for tracking (issue #32): the
faces turned towards it, sample points along the visible edges (hidden parts removed),
the image area the model covers, and the model points under given pixels.

Camera frame throughout, as OpenCV's: a model point `m` is at `x = R m + t` in front of
the camera (`z > 0`) and projects through `K` and OpenCV's distortion `dist`. The
paper's pointing (Section 6) casts one visual ray through a clicked pixel onto the
model; `cast_rays` does it for many pixels at once (the 3D points of tracked image
points), in numpy.

Hidden parts. A face is turned towards the camera when its outward normal points to the
camera centre (back-face culling). A model edge is a candidate when a face along it is
turned towards the camera and the edge is a crease (its two faces meet at more than
`crease_angle`), a silhouette (its other face turned away) or a border (one face); an
edge of no face (a `.cao` line) is a candidate too. A sample point of a candidate edge
is visible when the segment from the camera centre to it crosses no face of the model
on the way (the depth test non-convex models need; a convex one passes it always).

All functions take the model as a `Polyhedron` or, to save the preparation per frame,
as the `MeshGeometry` that `mesh_geometry` makes of it once. Plain numpy and OpenCV,
vectorised over faces, edges and points; not traced.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..geometry._validate import no_type_check
from ._polyhedron import Polyhedron

__all__ = [
    "EdgeSamples",
    "MeshGeometry",
    "RayHits",
    "cast_rays",
    "edge_samples",
    "face_mask",
    "front_faces",
    "mesh_geometry",
    "project",
]

#: Relative tolerance of the depth test (fraction of the distance to a sample point).
_DEPTH_TOL = 1e-6
#: Largest number of ray x face x corner entries handled at once (memory bound).
_CHUNK = 1 << 21


class MeshGeometry(NamedTuple):
    """A `Polyhedron` prepared for visibility and ray casting (model frame, numpy).

    **Fields:**
    - `model`: the `Polyhedron`.
    - `corners`: `(F, K, 3)` each face's corners, padded to `K` by repeating its last.
    - `normals`: `(F, 3)` unit outward normals (Newell's method).
    - `offsets`: `(F,)` each face plane's `n . p`.
    - `origins`, `axes`: `(F, 3)` and `(F, 2, 3)`: a point and two orthonormal in-plane
      axes per face; `polygons` `(F, K, 2)` the corners in those axes.
    - `edge_faces`: `(E, 2)` int: the faces along each edge (`-1` where fewer than two).
    """

    model: Polyhedron
    corners: np.ndarray
    normals: np.ndarray
    offsets: np.ndarray
    origins: np.ndarray
    axes: np.ndarray
    polygons: np.ndarray
    edge_faces: np.ndarray


class EdgeSamples(NamedTuple):
    """Sample points along a model's candidate edges at a pose (see the module docstring).

    **Fields:**
    - `points`: `(S, 3)` the samples on the model, model frame.
    - `pixels`: `(S, 2)` where they project (OpenCV's pixel convention).
    - `tangents`: `(S, 2)` unit direction of the projected edge at each sample (from the
      edge's first vertex to its second).
    - `normals`: `(S, 2)` unit normal of the projected edge, `(-tangent_y, tangent_x)`.
    - `edge`: `(S,)` int32 index into `model.edges`.
    - `visible`: `(S,)` bool: in front of the camera, inside the image (when its size
      is given) and hidden by no face. Where False the other fields are still finite.
    - `outline`: `(S,)` bool: the sample's edge is on the model's outline (its other
      face turned away, or none), where the object meets what lies behind it; the others
      are creases between two faces seen.
    """

    points: np.ndarray
    pixels: np.ndarray
    tangents: np.ndarray
    normals: np.ndarray
    edge: np.ndarray
    visible: np.ndarray
    outline: np.ndarray


class RayHits(NamedTuple):
    """Where the visual rays of pixels meet a model (the nearest face in front).

    **Fields:**
    - `points`: `(N, 3)` the hits, model frame (the zero vector where `hit` is False).
    - `face`: `(N,)` int32 index of the face hit (`-1` for none).
    - `depth`: `(N,)` the hit's camera-frame `z` (0 for none).
    - `hit`: `(N,)` bool.
    """

    points: np.ndarray
    face: np.ndarray
    depth: np.ndarray
    hit: np.ndarray


# --------------------------------------------------------------------------- preparation


@no_type_check
def mesh_geometry(model: Polyhedron | MeshGeometry) -> MeshGeometry:
    """Prepare a `Polyhedron` once for the functions of this module (see `MeshGeometry`).

    **Raises:** `ValueError` naming `model` for a model without faces, a face of under
    three corners or of zero area, a bad index or non-finite vertices.
    """
    if isinstance(model, MeshGeometry):
        return model
    if not isinstance(model, Polyhedron):
        raise ValueError(f"model must be a Polyhedron, got {type(model).__name__}")
    vertices = np.asarray(model.vertices, dtype=np.float64)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or not np.all(np.isfinite(vertices)):
        raise ValueError("model.vertices must be finite with shape (V, 3)")
    faces = [tuple(int(i) for i in f) for f in model.faces]
    if not faces:
        raise ValueError("model has no faces")
    if any(len(f) < 3 or min(f) < 0 or max(f) >= len(vertices) for f in faces):
        raise ValueError("model.faces has a face of under 3 corners or a bad index")
    width = max(len(f) for f in faces)
    index = np.array([list(f) + [f[-1]] * (width - len(f)) for f in faces])
    corners = vertices[index]
    area = np.cross(corners, np.roll(corners, -1, axis=1)).sum(axis=1)
    norm = np.linalg.norm(area, axis=1)
    if np.any(norm <= 1e-300):
        raise ValueError("model.faces has a face of zero area")
    normals = area / norm[:, None]
    origins = corners[:, 0]
    first = corners[:, 1] - corners[:, 0]
    first -= (first * normals).sum(axis=1, keepdims=True) * normals
    bad = np.linalg.norm(first, axis=1) < 1e-12
    first[bad] = np.cross(normals[bad], np.eye(3)[np.argmin(np.abs(normals[bad]), axis=1)])
    u = first / np.linalg.norm(first, axis=1, keepdims=True)
    axes = np.stack([u, np.cross(normals, u)], axis=1)
    polygons = np.einsum("fkd,fad->fka", corners - origins[:, None], axes)
    edges = np.asarray(model.edges, dtype=np.int64).reshape(-1, 2)
    sides: dict[tuple[int, int], list[int]] = {}
    for i, f in enumerate(faces):
        for a, b in zip(f, f[1:] + f[:1], strict=True):
            sides.setdefault((min(a, b), max(a, b)), []).append(i)
    edge_faces = np.full((len(edges), 2), -1, dtype=np.int64)
    for e, (a, b) in enumerate(edges):
        along = sides.get((min(a, b), max(a, b)), [])[:2]
        edge_faces[e, : len(along)] = along
    return MeshGeometry(
        model, corners, normals, (normals * origins).sum(axis=1), origins, axes, polygons,
        edge_faces,
    )  # fmt: skip


# --------------------------------------------------------------------------- checks


def _check_pose(K, dist, R, t):
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"K must be a finite (3, 3) camera matrix, got shape {K.shape}")
    if dist is not None:
        dist = np.asarray(dist, dtype=np.float64).ravel()
        if dist.size not in (0, 4, 5, 8, 12, 14) or not np.all(np.isfinite(dist)):
            raise ValueError(f"dist must have 4, 5, 8, 12 or 14 finite values, got {dist.size}")
        if not np.any(dist):
            dist = None
    R = np.asarray(R, dtype=np.float64)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        raise ValueError(f"R must be a finite (3, 3) rotation, got shape {R.shape}")
    if np.abs(R @ R.T - np.eye(3)).max() > 1e-6:
        raise ValueError("R must be a rotation matrix (R R^T = I)")
    t = np.asarray(t, dtype=np.float64).reshape(-1)
    if t.shape != (3,) or not np.all(np.isfinite(t)):
        raise ValueError(f"t must be 3 finite values, got shape {t.shape}")
    return K, dist, R, t


def project(points_cam: np.ndarray, K: np.ndarray, dist: np.ndarray | None) -> np.ndarray:
    """Pixels `(n, 2)` of camera-frame points `(n, 3)` through `K` and OpenCV's
    distortion `dist` (None: none). Points at or behind the camera plane get the pixel
    of a point just in front of it (finite, never used: callers mask them)."""
    z = np.maximum(points_cam[:, 2], 1e-12)
    if dist is None:
        x, y = points_cam[:, 0] / z, points_cam[:, 1] / z
        return np.column_stack([K[0, 0] * x + K[0, 1] * y + K[0, 2], K[1, 1] * y + K[1, 2]])
    import cv2

    safe = np.column_stack([points_cam[:, :2], z])
    uv, _ = cv2.projectPoints(safe.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, dist)
    return np.nan_to_num(uv.reshape(-1, 2), nan=0.0, posinf=0.0, neginf=0.0)


def _camera_in_model(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    return -R.T @ t


# --------------------------------------------------------------------------- faces


@no_type_check
def front_faces(model: Polyhedron | MeshGeometry, R, t) -> np.ndarray:
    """Which faces are turned towards the camera at pose `(R, t)` (back-face culling).

    **Returns:** `(F,)` bool, True where the face's outward normal points to the
    camera centre.
    """
    geo = mesh_geometry(model)
    _, _, R, t = _check_pose(np.eye(3), None, R, t)
    return geo.normals @ _camera_in_model(R, t) > geo.offsets


def facing(geo: MeshGeometry, R: np.ndarray, t: np.ndarray, grazing: float = 90.0):
    """`(F,)` bool: the faces whose outward normal is within `grazing` degrees of the
    line of sight to the camera centre (seen from the face's centroid); with 90, the
    faces turned towards the camera."""
    centre = _camera_in_model(R, t)
    if grazing >= 90:
        return geo.normals @ centre > geo.offsets
    sight = centre - geo.corners.mean(axis=1)
    cos = (geo.normals * sight).sum(axis=1) / np.maximum(np.linalg.norm(sight, axis=1), 1e-300)
    return cos > np.cos(np.radians(grazing))


def _crossings(geo: MeshGeometry, origin: np.ndarray, directions: np.ndarray, faces=None):
    """Ray parameters `(N, F)` where rays `origin + s d` (model frame) cross each face
    inside its polygon, `inf` where they do not (or run parallel to it)."""
    corners = geo.polygons if faces is None else geo.polygons[faces]
    normals = geo.normals if faces is None else geo.normals[faces]
    offsets = geo.offsets if faces is None else geo.offsets[faces]
    origins = geo.origins if faces is None else geo.origins[faces]
    axes = geo.axes if faces is None else geo.axes[faces]
    den = directions @ normals.T  # (N, F)
    ok = np.abs(den) > 1e-15
    s = (offsets - normals @ origin)[None, :] / np.where(ok, den, 1.0)
    # In-plane coordinates of the crossing: (o + s d - origin_f) . axes_f
    base = np.einsum("fad,fd->fa", axes, origin[None, :] - origins)  # (F, 2)
    step = np.einsum("fad,nd->nfa", axes, directions)  # (N, F, 2)
    q = base[None] + s[..., None] * step
    x, y = q[..., 0:1], q[..., 1:2]  # (N, F, 1)
    px, py = corners[None, :, :, 0], corners[None, :, :, 1]  # (1, F, K)
    qx, qy = np.roll(px, -1, axis=2), np.roll(py, -1, axis=2)
    crosses = (py > y) != (qy > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        at = px + (y - py) * (qx - px) / np.where(crosses, qy - py, 1.0)
    inside = np.sum(crosses & (x < at), axis=2) % 2 == 1
    return np.where(ok & inside, s, np.inf)


def _nearest_crossing(geo, origin, directions, faces=None):
    """`_crossings` over chunks of rays: the nearest positive parameter and its face."""
    count = len(geo.normals) if faces is None else len(faces)
    width = geo.polygons.shape[1]
    chunk = max(1, _CHUNK // max(count * width, 1))
    best = np.full(len(directions), np.inf)
    which = np.full(len(directions), -1, dtype=np.int64)
    for lo in range(0, len(directions), chunk):
        s = _crossings(geo, origin, directions[lo : lo + chunk], faces)
        s = np.where(s > 0, s, np.inf)
        k = np.argmin(s, axis=1)
        best[lo : lo + chunk] = s[np.arange(len(k)), k]
        which[lo : lo + chunk] = k
    return best, which


# --------------------------------------------------------------------------- edges


def _candidate_edges(geo: MeshGeometry, front: np.ndarray, crease_angle: float):
    """Which edges are drawn, and which of them are outlines (a face turned away or
    none on their other side, or no face at all: the object against what is behind)."""
    ef = geo.edge_faces
    has = ef >= 0
    face_front = np.where(has, front[np.maximum(ef, 0)], False)
    n0, n1 = geo.normals[np.maximum(ef[:, 0], 0)], geo.normals[np.maximum(ef[:, 1], 0)]
    crease = (n0 * n1).sum(axis=1) < np.cos(np.radians(crease_angle))
    two = has.all(axis=1)
    silhouette = two & (face_front[:, 0] != face_front[:, 1])
    border = has[:, 0] & ~has[:, 1]
    seen = face_front.any(axis=1) & (~two | crease | silhouette | border)
    return seen | ~has[:, 0], silhouette | border | ~has[:, 0]


@no_type_check
def edge_samples(
    model: Polyhedron | MeshGeometry,
    K,
    dist,
    R,
    t,
    *,
    spacing: float = 10.0,
    image_size: tuple[int, int] | None = None,
    margin: float = 0.0,
    crease_angle: float = 10.0,
    grazing: float = 90.0,
    occlusion: bool = True,
) -> EdgeSamples:
    """Sample points along the edges a camera sees of a model at pose `(R, t)`, for
    moving-edge measurement (`jaxpose.features.moving_edges`).

    Each candidate edge (see the module docstring) gets `max(1, L // spacing)` samples at
    the middles of equal parts of its length, `L` its projected length in pixels (edge
    ends, where two edges meet in the image, are left out); with `image_size`, at most
    as many as twice the image's perimeter allows (an edge passing near the camera
    plane projects enormously long).

    **Arguments:**
    - `model`: a `Polyhedron` or its `MeshGeometry`.
    - `K`: `(3, 3)` intrinsics; `dist`: OpenCV's distortion coefficients or None.
    - `R`, `t`: the pose, model to camera (`x = R m + t`).
    - `spacing`: pixels between samples (> 0).
    - `image_size`: `(width, height)`: samples outside the image (less `margin` pixels
      on each side) are marked not visible; None: no such test.
    - `crease_angle`: degrees between the normals of two faces below which their common
      edge is not drawn (a smooth surface's triangulation).
    - `grazing`: degrees between a face's normal and its line of sight beyond which
      the face counts as turned away (90: plain back-face culling; less, e.g. 80: a
      face seen edge-on, whose edges crowd into a pixel or two, is left out and its
      neighbour's edge along it becomes an outline).
    - `occlusion`: run the depth test (False: back-face culling only, enough for a
      convex model).

    **Returns:** `EdgeSamples` (`visible` marks the samples seen).

    **Raises:** `ValueError` naming the argument.
    """
    geo = mesh_geometry(model)
    K, dist, R, t = _check_pose(K, dist, R, t)
    for label, value in (("spacing", spacing), ("crease_angle", crease_angle)):
        if isinstance(value, bool) or not isinstance(value, int | float) or not value > 0:
            raise ValueError(f"{label} must be a number > 0, got {value!r}")
    if isinstance(margin, bool) or not isinstance(margin, int | float) or not margin >= 0:
        raise ValueError(f"margin must be a number >= 0, got {margin!r}")
    if image_size is not None and (
        len(image_size) != 2 or min(int(image_size[0]), int(image_size[1])) < 1
    ):
        raise ValueError(f"image_size must be (width, height) >= 1, got {image_size!r}")
    vertices = np.asarray(geo.model.vertices, dtype=np.float64)
    edges = np.asarray(geo.model.edges, dtype=np.int64).reshape(-1, 2)
    if isinstance(grazing, bool) or not isinstance(grazing, int | float) or not 0 < grazing <= 90:
        raise ValueError(f"grazing must be a number in (0, 90], got {grazing!r}")
    front = facing(geo, R, t, grazing)
    drawn, outline = _candidate_edges(geo, front, crease_angle)
    chosen = np.flatnonzero(drawn)
    a, b = vertices[edges[chosen, 0]], vertices[edges[chosen, 1]]
    ca, cb = a @ R.T + t, b @ R.T + t
    ends = project(np.vstack([ca, cb]), K, dist)
    length = np.linalg.norm(ends[len(chosen) :] - ends[: len(chosen)], axis=1)
    most = 100_000 if image_size is None else 2 * (int(image_size[0]) + int(image_size[1]))
    count = np.clip(length // spacing, 1, max(most // spacing, 1)).astype(np.int64)
    which = np.repeat(np.arange(len(chosen)), count)
    first = np.cumsum(count) - count
    frac = (np.arange(len(which)) - first[which] + 0.5) / count[which]
    points = a[which] + frac[:, None] * (b - a)[which]
    delta = 1e-3 / count[which]
    cam = points @ R.T + t
    span = (cb - ca)[which]
    uv = project(np.vstack([cam, cam + delta[:, None] * span]), K, dist)
    pixels, ahead = uv[: len(cam)], uv[len(cam) :]
    tangent = ahead - pixels
    norm = np.linalg.norm(tangent, axis=1)
    good = norm > 1e-12
    tangent = np.where(good[:, None], tangent / np.where(good, norm, 1.0)[:, None], [1.0, 0.0])
    normal = np.column_stack([-tangent[:, 1], tangent[:, 0]])
    visible = good & (cam[:, 2] > 1e-9 * max(1.0, float(np.abs(t).max())))
    if image_size is not None:
        w, h = float(image_size[0]), float(image_size[1])
        x, y = pixels[:, 0], pixels[:, 1]
        visible &= (x >= margin - 0.5) & (x <= w - 0.5 - margin)
        visible &= (y >= margin - 0.5) & (y <= h - 0.5 - margin)
    if occlusion and visible.any():
        idx = np.flatnonzero(visible)
        centre = _camera_in_model(R, t)
        s, _ = _nearest_crossing(geo, centre, points[idx] - centre)
        visible[idx] = ~(s < 1.0 - _DEPTH_TOL)
    pixels = np.where(np.isfinite(pixels), pixels, 0.0)
    edge = chosen[which].astype(np.int32)
    return EdgeSamples(points, pixels, tangent, normal, edge, visible, outline[edge])


# --------------------------------------------------------------------------- area, rays


def _outline(corners_cam: np.ndarray, K, dist, steps: int) -> np.ndarray:
    """A face's projected outline `(k * steps, 2)`: each side split in `steps` (a
    straight side bends under distortion)."""
    nxt = np.roll(corners_cam, -1, axis=0)
    frac = np.arange(steps) / steps
    pts = corners_cam[:, None] + frac[None, :, None] * (nxt - corners_cam)[:, None]
    return project(pts.reshape(-1, 3), K, dist)


@no_type_check
def face_mask(
    model: Polyhedron | MeshGeometry,
    K,
    dist,
    R,
    t,
    image_size: tuple[int, int],
    *,
    erode: int = 0,
) -> np.ndarray:
    """The image area the model covers at pose `(R, t)`: its faces turned towards the
    camera, filled (the region to look for keypoints in).

    **Arguments:** `model`, `K`, `dist`, `R`, `t` as for `edge_samples`;
    `image_size` `(width, height)`; `erode`: pixels taken off the area's border.

    **Returns:** `(height, width)` uint8, 255 inside, 0 outside.

    **Raises:** `ValueError` naming the argument.
    """
    import cv2

    if isinstance(erode, bool) or not isinstance(erode, int) or erode < 0:
        raise ValueError(f"erode must be an int >= 0, got {erode!r}")
    w, h = _image_size(image_size)
    mask = np.zeros((h, w), np.uint8)
    for _, poly in _face_outlines(model, K, dist, R, t):
        cv2.fillPoly(mask, [poly], 255, cv2.LINE_8, _SHIFT)
    if erode:
        mask = cv2.erode(mask, np.ones((2 * erode + 1, 2 * erode + 1), np.uint8))
    return mask


def face_labels(
    model: Polyhedron | MeshGeometry, K, dist, R, t, image_size: tuple[int, int]
) -> np.ndarray:
    """Which face each pixel shows at pose `(R, t)`: the faces turned towards the camera
    filled far to near (the nearest face drawn last), `(height, width)` int32 face
    indices, -1 outside. Arguments as `face_mask`."""
    import cv2

    w, h = _image_size(image_size)
    labels = np.full((h, w), -1, np.int32)
    for f, poly in _face_outlines(model, K, dist, R, t):
        cv2.fillPoly(labels, [poly], int(f), cv2.LINE_8, _SHIFT)
    return labels


#: Fractional bits of the pixel coordinates `cv2.fillPoly` is given.
_SHIFT = 4


def _image_size(image_size) -> tuple[int, int]:
    if len(image_size) != 2 or min(int(image_size[0]), int(image_size[1])) < 1:
        raise ValueError(f"image_size must be (width, height) >= 1, got {image_size!r}")
    return int(image_size[0]), int(image_size[1])


def _face_outlines(model, K, dist, R, t):
    """`(face, outline)` of each face turned towards the camera, far to near: its
    projected outline in `cv2.fillPoly`'s fixed point (`_SHIFT`); a face crossing the
    camera plane, or projected out of range, left out."""
    geo = mesh_geometry(model)
    K, dist, R, t = _check_pose(K, dist, R, t)
    front = np.flatnonzero(geo.normals @ _camera_in_model(R, t) > geo.offsets)
    cams = [geo.corners[f] @ R.T + t for f in front]
    steps = 1 if dist is None else 8
    for k in np.argsort([-cam[:, 2].mean() for cam in cams], kind="stable"):
        cam = cams[k]
        if np.any(cam[:, 2] <= 0):
            continue
        outline = _outline(cam, K, dist, steps)
        if np.all(np.abs(outline) < 1e6):
            yield front[k], np.round(outline * (1 << _SHIFT)).astype(np.int32)


@no_type_check
def cast_rays(model: Polyhedron | MeshGeometry, K, dist, R, t, pixels) -> RayHits:
    """The model points under pixels at pose `(R, t)`: each pixel's visual ray (through
    `K`, undistorted with `dist`) meets the model's faces; the nearest crossing in front
    of the camera is kept (the paper's pointing, Section 6, for many pixels at once).

    **Arguments:** `model`, `K`, `dist`, `R`, `t` as for `edge_samples`; `pixels`
    `(N, 2)` finite.

    **Returns:** `RayHits` (model-frame points, the face, the camera depth, the mask).

    **Raises:** `ValueError` naming the argument.
    """
    geo = mesh_geometry(model)
    K, dist, R, t = _check_pose(K, dist, R, t)
    pixels = np.asarray(pixels, dtype=np.float64)
    if pixels.ndim != 2 or pixels.shape[1] != 2 or not np.all(np.isfinite(pixels)):
        raise ValueError(f"pixels must be finite with shape (N, 2), got {pixels.shape}")
    if len(pixels) == 0:
        z = np.zeros(0)
        return RayHits(np.zeros((0, 3)), np.zeros(0, np.int32), z, np.zeros(0, bool))
    if dist is None:
        y = (pixels[:, 1] - K[1, 2]) / K[1, 1]
        x = (pixels[:, 0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
    else:
        import cv2

        xy = cv2.undistortPoints(pixels.reshape(-1, 1, 2), K, dist).reshape(-1, 2)
        x, y = xy[:, 0], xy[:, 1]
    rays_cam = np.column_stack([x, y, np.ones_like(x)])
    centre = _camera_in_model(R, t)
    s, face = _nearest_crossing(geo, centre, rays_cam @ R)
    hit = np.isfinite(s)
    s = np.where(hit, s, 0.0)
    points = np.where(hit[:, None], centre + s[:, None] * (rays_cam @ R), 0.0)
    return RayHits(points, np.where(hit, face, -1).astype(np.int32), s, hit)
