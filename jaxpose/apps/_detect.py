r"""Recognition without correspondences (the paper's Sections 5-6, with the matcher
built in): which models of a database an image shows, and where.

Input: the image's primitives (`jaxpose.features.image_primitives`: vertices, the
links between them, the distance map of the detected segments) and a database of
polyhedral models. No match is given.

1. **Hypotheses.** Every image path (three vertices joined by two detected edges,
   `i - j - k`) is paired with every model path (`a - b - c`, two model edges), after a
   geometric filter: the ratio of the two edge lengths may change by at most
   `max_ratio` between the model and the image (perspective foreshortens, it does not
   swap a short edge for one four times longer). Each pairing is three matches.
2. **Solve and score, compiled** (`jaxpose.apps._hypotheses.score_paths`): the
   three-point solver's roots of every pairing, each scored by the model's vertices
   and edges that it predicts and the image holds, in fixed-shape chunks; each chunk
   keeps its best poses.
3. **Refine and verify** (`jaxpose.apps._detect_verify`). The best distinct poses of
   each model (`candidates`): their seen vertices matched one to one to image vertices
   whose segments leave in the projected edges' directions, the linear method over the
   matches (twice, all candidates in one compiled call), then the acceptance rule of
   `verify` (chi-square bounds on the Eq. 8 error and on every residual) at the pose
   the linear method reaches, again on the inliers alone; an accepted pose is refined
   on the detected segments along its edges (`jaxpose.apps._detect_edges`).
4. **Decide.** A detection's `support` is the fraction of what its pose predicts (seen
   vertices, and seen edges sampled every 2 px) that the image holds. It is reported
   when the verification accepted it, at least `min_vertices` vertices are matched
   and `support >= min_support`; detections are ranked by `score`, the evidence
   explained (so that a model that fits only part of a larger one's image loses to
   it), and one that reuses most image vertices of a better one is dropped.
"""

from __future__ import annotations

import itertools
import math
from typing import Any, cast

import jax
import numpy as np

from ..api._programs import stored_jit
from ..features._raster import _dots
from ..features._segments import oriented_edge_distance
from ..geometry._camera import decompose_camera
from ..geometry._validate import as_camera
from ._detect_edges import project_vertices
from ._detect_verify import Detection, Settings, refine_and_verify, vertex_directions
from ._hypotheses import ModelTables, score_paths
from ._polyhedron import Polyhedron, polygon_normals

# (A stored program: no operation is traced, lowered and compiled again in every process.)
_decompose = stored_jit(decompose_camera)

__all__ = ["Detection", "detect"]

SAMPLES = 4  # points per edge in the compiled score
TOP = 16  # poses kept per chunk
BINS = 8  # direction bins of the edge-distance maps


# --------------------------------------------------------------------------- the models


def _edge_faces(model: Polyhedron) -> np.ndarray:
    table = np.zeros((len(model.edges), len(model.faces)))
    for f, face in enumerate(model.faces):
        ring = {frozenset((face[i], face[(i + 1) % len(face)])) for i in range(len(face))}
        for e, (a, b) in enumerate(model.edges):
            table[e, f] = frozenset((int(a), int(b))) in ring
    return table


def _paths(model: Polyhedron) -> np.ndarray:
    """`(Q, 3)` every ordered path `a - b - c` along two model edges."""
    neighbours: dict[int, set[int]] = {}
    for a, b in np.asarray(model.edges):
        neighbours.setdefault(int(a), set()).add(int(b))
        neighbours.setdefault(int(b), set()).add(int(a))
    rows = [
        (a, b, c)
        for b, near in sorted(neighbours.items())
        for a, c in itertools.permutations(sorted(near), 2)
    ]
    return np.array(rows, dtype=np.int64).reshape(-1, 3)


def _round_up(x: int, step: int = 8) -> int:
    return max(step, -(-x // step) * step)


def _tables(model: Polyhedron, V: int, F: int, E: int) -> ModelTables:
    verts = np.asarray(model.vertices, np.float64)
    normals = polygon_normals(verts, model.faces)
    offsets = np.array([n @ verts[f[0]] for n, f in zip(normals, model.faces, strict=True)])
    vf = np.zeros((V, F))
    for f, face in enumerate(model.faces):
        vf[list(face), f] = 1
    ef = np.zeros((E, F))
    ef[: len(model.edges), : len(model.faces)] = _edge_faces(model)
    ev = np.zeros((E, V))
    for e, (a, b) in enumerate(np.asarray(model.edges)):
        ev[e, a] = ev[e, b] = 1
    ends = verts[np.asarray(model.edges)]  # (e, 2, 3)
    w = (np.arange(1, SAMPLES + 1) / (SAMPLES + 1))[None, :, None]
    samples = np.zeros((E, SAMPLES, 3))
    samples[: len(ends)] = ends[:, :1] * (1 - w) + ends[:, 1:] * w
    pad = (
        lambda a, n, fill=0.0: np.concatenate(  # noqa: E731
            [a, np.full((n - len(a), *a.shape[1:]), fill)]
        )
    )
    arrays = (
        pad(verts, V),
        pad(np.ones(len(verts)), V),
        pad(normals, F),
        pad(offsets, F, 1.0),
        vf,
        ef,
        samples,
        pad(np.ones(len(ends)), E),
        ev,
    )
    # numpy arrays: the stored programs take them as they are (no eager conversion)
    return ModelTables(*(cast(Any, np.asarray(a, np.float32)) for a in arrays))


# --------------------------------------------------------------------------- the image


def _image_paths(links: np.ndarray) -> np.ndarray:
    """`(P, 3)` paths `i - j - k` with `i < k` (the reversed path is the same pairing
    against the reversed model path)."""
    rows = []
    for j in range(len(links)):
        near = np.flatnonzero(links[j])
        rows.extend((i, j, k) for i, k in itertools.combinations(near, 2))
    return np.array(rows, dtype=np.int64).reshape(-1, 3)


def _vertex_distance(points: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    import cv2

    dots = _dots(points, shape)
    if not dots.any():
        return np.full(shape, np.float32(1e6))
    mask = np.where(dots, 0, 255).astype(np.uint8)
    return cv2.distanceTransform(mask, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)


def _length_ratio(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    return np.log(np.linalg.norm(a - b, axis=-1) + 1e-12) - np.log(
        np.linalg.norm(c - b, axis=-1) + 1e-12
    )


# --------------------------------------------------------------------------- refinement


def _check_database(database) -> dict[str, Polyhedron]:
    if isinstance(database, Polyhedron):
        database = {database.name: database}
    if not isinstance(database, dict) or not database:
        raise ValueError("database must be a Polyhedron or a non-empty dict name -> Polyhedron")
    for name, model in database.items():
        if not isinstance(model, Polyhedron):
            raise ValueError(f"database[{name!r}] must be a Polyhedron")
        if len(model.faces) == 0 or len(model.edges) < 2:
            raise ValueError(f"database[{name!r}] needs faces and edges")
    return dict(database)


def _check_primitives(primitives) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    try:
        points = np.asarray(primitives.vertices.points, np.float64).reshape(-1, 2)
        _ = primitives.segments.ends
        links = np.asarray(primitives.links, bool)
        edist = np.asarray(primitives.distance, np.float32)
    except (AttributeError, TypeError, ValueError) as exc:
        raise ValueError(
            "primitives must have vertices.points (V, 2), links (V, V), segments.ends "
            "(S, 2, 2) and distance (H, W)"
        ) from exc
    if links.shape != (len(points), len(points)):
        raise ValueError(f"primitives.links must be ({len(points)}, {len(points)})")
    if edist.ndim != 2 or min(edist.shape) < 1:
        raise ValueError("primitives.distance must be a (H, W) map")
    if not np.all(np.isfinite(points)):
        raise ValueError("primitives.vertices.points must be finite")
    return points, links | links.T, edist


def _positive(name: str, value) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        x = math.nan
    if not (math.isfinite(x) and x > 0) or isinstance(value, bool):
        raise ValueError(f"{name} must be a positive number, got {value!r}")
    return x


def detect(
    camera,
    primitives,
    database,
    *,
    noise: float = 2.0,
    vertex_radius: float = 4.0,
    edge_radius: float = 2.0,
    max_ratio: float = 4.0,
    min_edge: float = 10.0,
    candidates: int = 6,
    min_vertices: int = 7,
    min_support: float = 0.45,
    max_detections: int = 5,
    chunk: int = 1024,
) -> list[Detection]:
    """Recognise the database's models in an image from its primitives alone.

    **Arguments:**
    - `camera`: the 3x4 projection matrix `C` (world frame), as in `verify`.
    - `primitives`: the image's `jaxpose.features.Primitives` (any object with
      `vertices.points` `(V, 2)`, `links` `(V, V)` bool and `distance` `(H, W)`).
    - `database`: a `Polyhedron` or a dict name -> `Polyhedron`.
    - `noise`: the image vertices' noise (px, per coordinate) for the verification.
    - `vertex_radius`, `edge_radius`: px within which a predicted vertex / edge point
      counts as held by the image.
    - `max_ratio`: the pairing filter on edge-length ratios (see the module docstring).
    - `min_edge`: edges shorter than this in the image (px) are not scored.
    - `candidates`: distinct poses of each model refined and verified.
    - `min_vertices`, `min_support`: the acceptance of a detection.
    - `max_detections`: at most this many detections.
    - `chunk`: pairings per compiled pass.

    **Returns:** the detections, best first (empty when nothing is recognised).
    """
    C = np.asarray(as_camera(camera, "camera"), np.float64)
    models = _check_database(database)
    points, links, edist = _check_primitives(primitives)
    noise = _positive("noise", noise)
    vertex_radius = _positive("vertex_radius", vertex_radius)
    edge_radius = _positive("edge_radius", edge_radius)
    max_ratio = _positive("max_ratio", max_ratio)
    min_edge = _positive("min_edge", min_edge)
    for name, value in (
        ("candidates", candidates),
        ("min_vertices", min_vertices),
        ("max_detections", max_detections),
        ("chunk", chunk),
    ):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"{name} must be a positive integer, got {value!r}")
    if not 0 <= float(min_support) <= 1:
        raise ValueError(f"min_support must lie in [0, 1], got {min_support!r}")

    K, Rc, tc, _ = (np.asarray(a, np.float64) for a in _decompose(np.asarray(C, np.float64)))
    H, W = edist.shape
    vdist = _vertex_distance(points, (H, W))
    edist = oriented_edge_distance(primitives.segments, (H, W), BINS)
    paths = _image_paths(links)
    if len(paths) == 0:
        return []
    rays = np.column_stack([points, np.ones(len(points))]) @ np.linalg.inv(K).T
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    image_ratio = _length_ratio(*(points[paths[:, i]] for i in range(3)))

    V = _round_up(max(len(m.vertices) for m in models.values()))
    F = _round_up(max(len(m.faces) for m in models.values()))
    E = _round_up(max(len(m.edges) for m in models.values()))
    maps = (np.asarray(vdist.reshape(-1)), np.asarray(edist.reshape(-1)))
    radii = (np.float32(vertex_radius), np.float32(edge_radius), np.float32(min_edge))
    found: list[tuple[float, str, np.ndarray, np.ndarray]] = []
    for name, model in models.items():
        mpaths = _paths(model)
        verts = np.asarray(model.vertices, np.float64)
        model_ratio = _length_ratio(*(verts[mpaths[:, i]] for i in range(3)))
        close = np.abs(image_ratio[:, None] - model_ratio[None, :]) <= math.log(max_ratio)
        p, q = np.nonzero(close)
        if len(p) == 0:
            continue
        tables = _tables(model, V, F, E)
        size = chunk
        kept = []
        for start in range(0, len(p), size):
            rows = slice(start, start + size)
            n = len(p[rows])
            bearings = np.zeros((size, 3, 3), np.float32)
            model_pts = np.zeros((size, 3, 3), np.float32)
            bearings[:n] = rays[paths[p[rows]]]
            model_pts[:n] = verts[mpaths[q[rows]]]
            bearings[n:], model_pts[n:] = bearings[0], model_pts[0]
            mask = (np.arange(size) < n).astype(np.float32)
            out = score_paths(
                np.asarray(K, np.float32),
                bearings,
                model_pts,
                mask,
                tables,
                *maps,
                *radii,
                width=W,
                height=H,
                top=TOP,
            )
            out = jax.tree.map(np.asarray, out)
            for s, R, t in zip(out.score, out.R, out.t, strict=True):
                if s > 3:  # more than the three matched vertices
                    kept.append((float(s), R.astype(np.float64), t.astype(np.float64)))
        kept.sort(key=lambda x: -x[0])
        for s, R, t in _distinct(kept, model, K, candidates):
            found.append((s, name, R, t))
    if not found:
        return []
    settings = Settings(
        noise,
        vertex_radius,
        edge_radius,
        min_edge,
        min_vertices,
        float(min_support),
        max_detections,
        V,
        _round_up(candidates * len(models)),
    )
    directions = vertex_directions(primitives, points)
    ends = np.asarray(primitives.segments.ends, np.float64).reshape(-1, 2, 2)
    return refine_and_verify(C, K, Rc, tc, found, models, points, directions, edist, ends, settings)


def _distinct(kept, model: Polyhedron, K, count: int, tolerance: float = 8.0):
    """The best `count` poses, skipping any whose vertices project within `tolerance`
    px (RMS) of a better one's, or whose picture (the projected vertices and edge
    midpoints as a set of points) coincides with a better one's within `tolerance / 4`
    px: the poses that a symmetry of the model maps onto each other draw the same
    picture, and one slot is enough for them."""
    out: list[tuple[float, np.ndarray, np.ndarray]] = []
    shown: list[np.ndarray] = []
    verts = np.asarray(model.vertices, np.float64)
    edges = np.asarray(model.edges)
    points = np.concatenate([verts, (verts[edges[:, 0]] + verts[edges[:, 1]]) / 2])
    n = len(verts)
    for s, R, t in kept:
        uv = project_vertices(K, R, t, points)
        if any(
            np.sqrt(np.mean(np.sum((uv[:n] - o[:n]) ** 2, axis=1))) < tolerance
            or _picture_gap(uv, o) < tolerance / 4
            for o in shown
        ):
            continue
        out.append((s, R, t))
        shown.append(uv)
        if len(out) == count:
            break
    return out


def _picture_gap(a: np.ndarray, b: np.ndarray) -> float:
    """The largest distance from a point of `a` `(n, 2)` to the nearest point of `b`, or
    the other way round."""
    d = np.linalg.norm(a[:, None] - b[None], axis=-1)
    return float(max(d.min(axis=1).max(), d.min(axis=0).max()))
