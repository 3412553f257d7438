r"""A first model-based tracker (issue #32): the pose of a known object kept from frame to
frame of a video, as the paper's AR loop does (Section 6), by its small-movement linear
method (Section 2.2) on what the front end measures.

Per frame, from the previous pose (the prediction):

1. **Moving edges** (`jaxpose.features.moving_edges`) along the visible model edges
   (`edge_samples`): each match says that the sample's model point `P` projects onto
   the image line through the matched point `q` with the edge's normal `n`;
2. **KLT points** (`jaxpose.features.track_points`) followed from the previous frame,
   each with its model point found once by casting its ray onto the mesh
   (`cast_rays`); their set is topped up inside the visible faces when it runs low.
3. **The linear method**: with the camera frame as the world (`C = K [I | 0]`), an
   image line `l = (n, -n . q)` is the plane `C^T l` through the camera centre, and a
   pixel `(u, v)` the two planes of its visual ray (the paper's Eq. 5). The small
   motion `dX = dt + r x (X - X_c)` (Eq. 3, turned about the centroid `X_c` of the
   measured points for conditioning) put into these planes gives one linear equation
   per edge match and two per point (Eq. 7). Each row is divided by the point's depth
   and its normal taken at the reprojected pixel, so that its right-hand side is the
   pixel residual and the iteration is Gauss-Newton on the pixel errors (as
   `jaxpose.solvers.linear`'s `"depth"` weighting). Rows are weighted by Tukey's
   biweight of their residual over a robust scale (1.4826 times the median absolute
   residual, edges and points apart), so that wrong matches (a hand over the edge,
   a neighbouring edge near a corner) lose their say, and each kind by the inverse
   square of its scale (the better measured kind counts more: points tracked on a
   plain face, mostly noise, hardly count). The 6 x 6 normal equations are solved,
   the motion applied exactly, and the step repeated.

Each edge sample expects the contrast (sign and size) that the match nearest to it on
the model had on the last frame, so that a printed line beside an edge is not taken
for it.

The edges are measured again from the refined pose (`rounds` times, the search range
shrinking to `refine_search`). Distortion is removed from the measurements first
(`cv2.undistortPoints`), so the solve is that of a pinhole camera.

Plain numpy and OpenCV per frame: one frame of 640 x 480 costs a few milliseconds
(see `benchmarks/frontend.py`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Iterator
from typing import NamedTuple

import numpy as np

from ..features._klt import detect_corners, track_points
from ..features._moving_edges import _grey, moving_edges
from ..geometry._validate import no_type_check
from ._polyhedron import Polyhedron
from ._visibility import (
    MeshGeometry,
    _check_pose,
    cast_rays,
    edge_samples,
    face_mask,
    facing,
    mesh_geometry,
)

__all__ = ["TrackOptions", "TrackedFrame", "track"]

#: Tukey's biweight constant (95% efficiency under Gaussian noise).
_TUKEY = 4.685


@dataclasses.dataclass(frozen=True)
class TrackOptions:
    """The tracker's settings (defaults for a 640 x 480 video).

    **Fields:**
    - `spacing`: pixels between edge samples; `search`: the first search range (+-px);
      `refine_search`: the range of the later rounds; `threshold`: the least derivative
      of an edge (grey levels per pixel); `rounds`: edge measurements per frame.
    - `max_corners`: KLT points kept at most; `min_corners`: top the set up below this;
      `erode`: pixels kept away from the faces' borders when detecting;
      `fb_threshold`: forward-backward check (px).
    - `iterations`: Gauss-Newton steps per round; `min_scale`: the least robust scale
      (px) of the residuals (below it, noise-free residuals would reject everything);
      `min_rows`: the fewest measurement rows with a nonzero weight a pose needs (an
      edge match gives one, a point two); with fewer, the frame keeps the previous
      pose, `ok` False.
    - `grazing`: faces seen at more than this angle (degrees) from their normal give
      no edges (`edge_samples`); an edge whose faces change between seen and not
      forgets its contrasts.
    - `choose`: which image edge a sample takes (`moving_edges`'s `choose`).
    - `ratio`: each sample expects the contrast (sign and size, within this factor) the
      match nearest to it on the model had on the last frame (`moving_edges`'s
      `contrast` and `ratio`); None: the sign only.
    - `edges`: `"all"` the edges seen, or `"outline"` only those where the object meets
      what lies behind it (for objects whose faces are alike, where creases hardly
      show).
    - `predict`: the first guess of a frame's pose: `"velocity"` (the last motion
      repeated) or `"still"` (the last pose).
    - `recast`: find the KLT points' model points again at every frame's pose (the
      points then measure the motion from frame to frame, and their tracking drift does
      not pile up in the model; the edges hold the pose to the model). False: once,
      when a point is detected.
    - `use_edges`, `use_points`: which measurements take part.
    """

    spacing: float = 8.0
    search: int = 12
    refine_search: int = 4
    threshold: float = 8.0
    rounds: int = 2
    max_corners: int = 200
    min_corners: int = 60
    erode: int = 6
    fb_threshold: float = 1.0
    iterations: int = 3
    min_scale: float = 0.3
    min_rows: int = 12
    grazing: float = 90.0
    choose: str = "strongest"
    ratio: float | None = 2.0
    edges: str = "all"
    predict: str = "velocity"
    recast: bool = True
    use_edges: bool = True
    use_points: bool = True

    def __post_init__(self) -> None:
        for name, kind, bound in _CHECKS:
            _check_field(name, getattr(self, name), kind, bound)


#: Each field of `TrackOptions`, how it is checked and against what: `"int"` an int
#: >= bound, `"number"` a number > bound, `"choice"` one of bound, `"bool"` a bool,
#: `"ratio"` None or a number > bound, `"angle"` a number in (0, bound].
_CHECKS: tuple[tuple[str, str, object], ...] = (
    ("spacing", "number", 0),
    ("search", "int", 2),
    ("refine_search", "int", 2),
    ("threshold", "number", 0),
    ("rounds", "int", 1),
    ("max_corners", "int", 1),
    ("min_corners", "int", 0),
    ("erode", "int", 0),
    ("fb_threshold", "number", 0),
    ("iterations", "int", 1),
    ("min_scale", "number", 0),
    ("min_rows", "int", 0),
    ("grazing", "angle", 90),
    ("choose", "choice", ("strongest", "nearest")),
    ("ratio", "ratio", 1),
    ("edges", "choice", ("all", "outline")),
    ("predict", "choice", ("velocity", "still")),
    ("recast", "bool", None),
    ("use_edges", "bool", None),
    ("use_points", "bool", None),
)


def _check_field(name: str, value, kind: str, bound) -> None:
    """ValueError naming `options.<name>` when `value` is not of its `kind` within
    `bound` (see `_CHECKS`)."""
    number = not isinstance(value, bool) and isinstance(value, int | float)
    if kind == "int":
        good, want = number and isinstance(value, int) and value >= bound, f"an int >= {bound}"
    elif kind == "number":
        good, want = number and value > bound, f"a number > {bound}"
    elif kind == "choice":
        good, want = value in bound, f"one of {bound}"
    elif kind == "bool":
        good, want = isinstance(value, bool), "a bool"
    elif kind == "ratio":
        good, want = value is None or (number and value > bound), f"> {bound} or None"
    else:  # "angle"
        good, want = number and 0 < value <= bound, f"in (0, {bound}]"
    if not good:
        raise ValueError(f"options.{name} must be {want}, got {value!r}")


class TrackedFrame(NamedTuple):
    """One frame's result.

    **Fields:**
    - `frame`: the frame's number (from 0).
    - `R`, `t`: the pose, model to camera (`x = R m + t`).
    - `ok`: whether the pose was measured (enough edges and points took part; where
      False, the pose is the previous one).
    - `edges`, `points`: how many edge matches and KLT points took part (with a
      nonzero weight).
    - `rms`: the weighted RMS pixel residual of those.
    """

    frame: int
    R: np.ndarray
    t: np.ndarray
    ok: bool
    edges: int
    points: int
    rms: float


def _rotation(w: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.Rodrigues(np.asarray(w, np.float64).reshape(3, 1))[0]


def _orthonormal(R: np.ndarray) -> np.ndarray:
    """The rotation nearest `R` (products of many rotations drift off the group)."""
    u, _, vt = np.linalg.svd(R)
    return u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt


def _undistort(pixels: np.ndarray, K: np.ndarray, dist) -> np.ndarray:
    """Pixels of the pinhole camera `K` from distorted ones (unchanged without `dist`)."""
    if dist is None or len(pixels) == 0:
        return pixels
    import cv2

    out = cv2.undistortPoints(pixels.reshape(-1, 1, 2), K, dist, P=K)
    return out.reshape(-1, 2)


def _tukey(residual: np.ndarray, min_scale: float) -> tuple[np.ndarray, float]:
    """Tukey's biweight of residuals over their robust scale, and that scale."""
    if len(residual) == 0:
        return np.zeros(0), 1.0
    scale = max(1.4826 * float(np.median(np.abs(residual))), min_scale)
    z = residual / (_TUKEY * scale)
    return np.where(np.abs(z) < 1, (1 - z**2) ** 2, 0.0), scale


class _Measurements(NamedTuple):
    """Pinhole-frame measurements: edge lines and points, with their model points."""

    edge_model: np.ndarray  # (E, 3)
    edge_lines: np.ndarray  # (E, 3): n_x u + n_y v + c = 0, |n| = 1
    point_model: np.ndarray  # (P, 3)
    point_pixels: np.ndarray  # (P, 2)


def _rows(R, t, K, meas: _Measurements):
    """Residuals `(M,)` (px) and Jacobian rows `(M, 6)` (d residual / d(dt, r), rotation
    about the centroid of the measured points) at pose `(R, t)`: the `E` edge rows
    first, then two rows (u, v) per point; and the centroid."""
    Xe = meas.edge_model @ R.T + t
    Xp = meas.point_model @ R.T + t
    X = np.vstack([Xe, np.repeat(Xp, 2, axis=0)])
    if len(X) == 0:
        return np.zeros(0), np.zeros((0, 6)), np.zeros(3)
    z = np.maximum(X[:, 2], 1e-12)
    # Edge rows: the plane C^T l = (l^T K, 0), residual l . (u^, v^, 1); its normal at
    # the reprojected pixel, l^T K - residual e3.
    ne = meas.edge_lines @ K
    re = (ne * Xe).sum(axis=1) / z[: len(Xe)]
    ne[:, 2] -= re
    # Point rows: the planes of the pixel's visual ray, K_u - u^ e3 and K_v - v^ e3.
    uv = (Xp @ K[:2].T) / z[len(Xe) :: 2, None]
    rp = (uv - meas.point_pixels).reshape(-1)
    npt = np.broadcast_to(K[:2], (len(Xp), 2, 3)).copy()
    npt[:, :, 2] -= uv
    n = np.vstack([ne, npt.reshape(-1, 3)]) / z[:, None]
    centre = np.vstack([Xe, Xp]).mean(axis=0)
    L = X - centre
    J = np.empty((len(X), 6))
    J[:, :3] = n
    J[:, 3] = L[:, 1] * n[:, 2] - L[:, 2] * n[:, 1]  # (L x n): d residual / d r
    J[:, 4] = L[:, 2] * n[:, 0] - L[:, 0] * n[:, 2]
    J[:, 5] = L[:, 0] * n[:, 1] - L[:, 1] * n[:, 0]
    return np.concatenate([re, rp]), J, centre


def _solve(R, t, K, meas: _Measurements, options: TrackOptions):
    """Robust Gauss-Newton on the linear method's rows (see the module docstring).
    Returns `(R, t, edge_weights, point_weights, rms, ok)`."""
    n_e, n_p = len(meas.edge_model), len(meas.point_model)
    w_e, w_p = np.zeros(n_e), np.zeros(n_p)
    rms, ok = 0.0, False
    for _ in range(options.iterations):
        r, J, centre = _rows(R, t, K, meas)
        w_e, s_e = _tukey(r[:n_e], options.min_scale)
        r_p = r[n_e:].reshape(-1, 2)
        w_p, s_p = _tukey(np.sqrt((r_p**2).sum(axis=1)), options.min_scale)
        w = np.concatenate([w_e, np.repeat(w_p, 2)])
        if np.count_nonzero(w) < max(options.min_rows, 6):
            ok = False
            break
        # Each kind of measurement weighted by the inverse of its noise's variance, as
        # its robust scale estimates it (points tracked badly, e.g. on a plain face,
        # then count little against the edges, and the other way round).
        precision = np.concatenate([np.full(n_e, s_e**-2), np.full(2 * n_p, s_p**-2)])
        Jw = J * (w * precision)[:, None]
        A = Jw.T @ J
        b = -(Jw.T @ r)
        scale = np.sqrt(np.maximum(np.diag(A), 1e-300))
        try:
            step = np.linalg.solve(A / np.outer(scale, scale), b / scale) / scale
        except np.linalg.LinAlgError:
            break
        if not np.all(np.isfinite(step)):
            break
        dR = _rotation(step[3:])
        R, t = _orthonormal(dR @ R), dR @ (t - centre) + centre + step[:3]
        rms = float(np.sqrt((w * r**2).sum() / max(w.sum(), 1e-300)))  # (unscaled)
        ok = True
    return R, t, w_e, w_p, rms, ok


class _Corners(NamedTuple):
    pixels: np.ndarray  # (P, 2) distorted image pixels in the last frame
    model: np.ndarray  # (P, 3)


class _Contrasts(NamedTuple):
    """The signed contrast each edge match had, keyed by `edge + fraction along it`
    (sorted), for the next frame's samples at the same places on the model."""

    keys: np.ndarray
    values: np.ndarray


_NO_CONTRAST = _Contrasts(np.zeros(0), np.zeros(0))


def _expected(table: _Contrasts, keys: np.ndarray, reach: float = 0.05) -> np.ndarray:
    """The contrast of the nearest entry on the same edge within `reach` (a fraction of
    the edge's length) of each key, 0 where none."""
    if len(table.keys) == 0 or len(keys) == 0:
        return np.zeros(len(keys))
    i = np.searchsorted(table.keys, keys).clip(1, len(table.keys) - 1)
    lo, hi = table.keys[i - 1], table.keys[i]
    j = np.where(np.abs(keys - lo) <= np.abs(hi - keys), i - 1, i)
    near = table.keys[j]
    same = (np.floor(near) == np.floor(keys)) & (np.abs(near - keys) <= reach)
    return np.where(same, table.values[j], 0.0)


def _edge_measurements(grey, geo, K, dist, R, t, size, search, contrasts, options):
    samples = edge_samples(geo, K, dist, R, t, spacing=options.spacing, image_size=size,
                           margin=search + 2.0, grazing=options.grazing)  # fmt: skip
    ends = np.asarray(geo.model.edges)[samples.edge]
    a, b = geo.model.vertices[ends[:, 0]], geo.model.vertices[ends[:, 1]]
    frac = ((samples.points - a) * (b - a)).sum(axis=1) / np.maximum(
        ((b - a) ** 2).sum(axis=1), 1e-300
    )
    keys = samples.edge + np.clip(frac, 0.0, 0.999)
    found = moving_edges(grey, samples.pixels, samples.normals, search=search,
                         threshold=options.threshold, mask=samples.visible,
                         contrast=_expected(contrasts, keys), choose=options.choose,
                         ratio=options.ratio)  # fmt: skip
    keep = found.valid & (samples.outline | (options.edges == "all"))
    q = found.matched[keep]
    ahead = q + np.column_stack([found.normals[keep, 1], -found.normals[keep, 0]])
    qu, au = _undistort(q, K, dist), _undistort(ahead, K, dist)
    d = au - qu
    n = np.column_stack([-d[:, 1], d[:, 0]])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    lines = np.column_stack([n, -(n * qu).sum(axis=1)])
    return samples.points[keep], lines, keys[keep], found.strength[keep]


@no_type_check
def track(
    frames: Iterable[np.ndarray],
    model: Polyhedron | MeshGeometry,
    K,
    dist,
    initial_pose: tuple,
    *,
    options: TrackOptions | None = None,
) -> Iterator[TrackedFrame]:
    """Track a model through frames (see the module docstring), one result per frame.

    **Arguments:**
    - `frames`: grey or BGR images of one size (e.g. `jaxpose.features.open_frames`).
    - `model`: a `Polyhedron` (or its `MeshGeometry`).
    - `K` `(3, 3)`, `dist` (OpenCV's coefficients or None): the camera.
    - `initial_pose`: `(R, t)` in the first frame, model to camera (from recognition or
      by hand); it is refined on the first frame's edges.
    - `options`: `TrackOptions`.

    **Returns:** a generator of `TrackedFrame`.

    **Raises:** `ValueError` naming the argument (the frames' when they are iterated).
    """
    geo = mesh_geometry(model)
    if not isinstance(initial_pose, tuple | list) or len(initial_pose) != 2:
        raise ValueError("initial_pose must be a pair (R, t)")
    K, dist, R, t = _check_pose(K, dist, *initial_pose)
    options = TrackOptions() if options is None else options
    if not isinstance(options, TrackOptions):
        raise ValueError(f"options must be a TrackOptions, got {type(options).__name__}")

    def run() -> Iterator[TrackedFrame]:
        nonlocal R, t
        previous, size = None, None
        corners = _Corners(np.zeros((0, 2)), np.zeros((0, 3)))
        contrasts = _NO_CONTRAST
        last_seen, motion = None, None
        for index, frame in enumerate(frames):
            grey = _grey(frame)
            grey8 = np.clip(grey, 0, 255).astype(np.uint8) if grey.dtype != np.uint8 else grey
            if size is None:
                size = (grey.shape[1], grey.shape[0])
            elif (grey.shape[1], grey.shape[0]) != size:
                raise ValueError(f"frames must all have size {size}, got {grey.shape[::-1]}")
            # KLT points from the previous frame.
            points_px, points_model = np.zeros((0, 2)), np.zeros((0, 3))
            if previous is not None and len(corners.pixels) and options.use_points:
                tracks = track_points(previous, grey8, corners.pixels,
                                      fb_threshold=options.fb_threshold)  # fmt: skip
                corners = _Corners(tracks.points[tracks.valid], corners.model[tracks.valid])
                points_px, points_model = corners.pixels, corners.model
            R0, t0 = R, t
            if options.predict == "velocity" and motion is not None:
                R, t = _orthonormal(motion[0] @ R), motion[0] @ t + motion[1]
            ok, n_edges, w_p, rms = False, 0, np.zeros(len(points_px)), 0.0
            table = _NO_CONTRAST
            for round_ in range(max(options.rounds, 1)):
                search = options.search if round_ == 0 else options.refine_search
                if options.use_edges:
                    e_model, e_lines, e_index, e_strength = _edge_measurements(
                        grey, geo, K, dist, R, t, size, search, contrasts, options
                    )
                else:
                    e_model, e_lines = np.zeros((0, 3)), np.zeros((0, 3))
                    e_index, e_strength = np.zeros(0), np.zeros(0)
                meas = _Measurements(e_model, e_lines, points_model,
                                     _undistort(points_px, K, dist))  # fmt: skip
                R1, t1, w_e, w_p, rms, ok = _solve(R, t, K, meas, options)
                if not ok:
                    break
                R, t = R1, t1
                n_edges = int(np.count_nonzero(w_e))
                kept = w_e > 0
                order = np.argsort(e_index[kept])
                table = _Contrasts(e_index[kept][order], e_strength[kept][order])
            if not ok or not np.all(np.isfinite(t)):
                R, t = R0, t0
                ok, motion = False, None
            else:
                motion = (R @ R0.T, t - R @ R0.T @ t0) if index else None
                # An edge whose faces changed between seen and not changes its contrast.
                seen = facing(geo, R, t, options.grazing)
                sides = np.where(geo.edge_faces >= 0, seen[np.maximum(geo.edge_faces, 0)], False)
                if last_seen is not None:
                    changed = np.any(sides != last_seen, axis=1)
                    same = ~changed[np.floor(table.keys).astype(int)]
                    table = _Contrasts(table.keys[same], table.values[same])
                contrasts, last_seen = table, sides
                if len(points_px):  # drop the points the solve rejected
                    corners = _Corners(corners.pixels[w_p > 0], corners.model[w_p > 0])
                if options.recast and len(corners.pixels):
                    hits = cast_rays(geo, K, dist, R, t, corners.pixels)
                    corners = _Corners(corners.pixels[hits.hit], hits.points[hits.hit])
            if options.use_points and len(corners.pixels) < options.min_corners:
                region = face_mask(geo, K, dist, R, t, size, erode=options.erode)
                room = options.max_corners - len(corners.pixels)
                new = detect_corners(
                    grey8,
                    region,
                    max_corners=max(room, 1),
                    existing=corners.pixels if len(corners.pixels) else None,
                )
                hits = cast_rays(geo, K, dist, R, t, new)
                corners = _Corners(
                    np.vstack([corners.pixels, new[hits.hit]]),
                    np.vstack([corners.model, hits.points[hits.hit]]),
                )  # fmt: skip
            previous = grey8
            yield TrackedFrame(index, R.copy(), t.copy(), ok, n_edges,
                               int(np.count_nonzero(w_p)), rms)  # fmt: skip

    return run()
