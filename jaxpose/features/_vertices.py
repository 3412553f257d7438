"""Junctions of line segments (the image vertices that the paper's recognition matches to
model vertices), the edges between them, and the whole image front end.

A vertex is where two or three segments meet: their end points come together (an L,
Y or arrow junction) or an end point meets the inside of another segment (a T). Its
position is the weighted least-squares intersection of the segments' lines, sub-pixel;
its covariance follows from each line's perpendicular uncertainty. A line fitted to an
edge of length `L` with perpendicular pixel noise `sigma` is known, at a distance `s`
from the segment's middle, to

$$ \\sigma_\\perp^2(s) = \\frac{\\sigma^2}{L} \\left(1 + \\frac{12 s^2}{L^2}\\right), $$

and the intersection `x` of lines `n_i . x = c_i` weighted by `w_i = 1 / sigma_perp,i^2`
solves `A x = b` with `A = sum w_i n_i n_i^T`, `b = sum w_i c_i n_i`: its covariance is
`A^{-1}`.

Plain numpy and OpenCV: nothing here is traced.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..geometry._validate import no_type_check
from ._segments import (
    Segments,
    _check_image,
    _check_positive,
    _check_segments,
    _components,
    detect_segments,
    edge_distance,
    segment_directions,
    segment_lengths,
)

__all__ = [
    "MAX_VERTICES",
    "Primitives",
    "Vertices",
    "find_vertices",
    "image_primitives",
    "vertex_links",
]

#: Image vertices `image_primitives` keeps by default (the best by score).
MAX_VERTICES = 60

_DEGREE = 3  # the most segments a vertex keeps


class Vertices(NamedTuple):
    """Junctions of segments (pixels, OpenCV's convention), by decreasing score."""

    points: np.ndarray
    """`(V, 2)` float64: sub-pixel position `(x, y)`."""
    covariance: np.ndarray
    """`(V, 2, 2)` float64: covariance of `points` (pixels squared)."""
    segments: np.ndarray
    """`(V, 3)` int64: indices of the segments meeting there, -1 padded (two for an L,
    three for a Y, an arrow or a T whose bar is broken)."""
    score: np.ndarray
    """`(V,)` float64, nonnegative: the sum of the meeting segments' scores."""


class Primitives(NamedTuple):
    """What an image offers the recognition of polyhedra: `segments` (`Segments`),
    `vertices` (`Vertices`), `links` (`(V, V)` bool, symmetric: an edge joins the two
    vertices) and `distance` (`(h, w)` float32: pixels to the nearest segment)."""

    segments: Segments
    vertices: Vertices
    links: np.ndarray
    distance: np.ndarray


def _empty_vertices() -> Vertices:
    return Vertices(
        np.zeros((0, 2)), np.zeros((0, 2, 2)), np.full((0, _DEGREE), -1, np.int64), np.zeros(0)
    )


def _check_vertices(vertices, name: str = "vertices") -> Vertices:
    if not isinstance(vertices, Vertices):
        raise ValueError(f"{name} must be a Vertices, got {type(vertices).__name__}")
    points = np.asarray(vertices.points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 2:
        raise ValueError(f"{name}.points must have shape (V, 2), got {points.shape}")
    if not np.all(np.isfinite(points)):
        raise ValueError(f"{name}.points contains NaN or infinite values")
    return vertices._replace(points=points)


def _check_count(value, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 0:
        raise ValueError(f"{name} must be an integer >= 0, got {value!r}")
    return int(value)


# --------------------------------------------------------------------------- vertices


def _intersect(
    origin: np.ndarray,
    direction: np.ndarray,
    length: np.ndarray,
    noise: np.ndarray,
    guess: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Weighted least-squares intersection of lines `origin + s direction` `(k, 2)` near
    `guess`, with its covariance (the module docstring's weights, evaluated twice)."""
    normal = np.column_stack([-direction[:, 1], direction[:, 0]])
    c = np.sum(normal * origin, axis=1)
    safe_length = np.maximum(length, 1.0)
    x = guess
    cov = np.eye(2)
    for _ in range(2):
        s = np.sum((x - origin) * direction, axis=1)
        offset = s - safe_length / 2
        var = noise**2 / safe_length * (1 + 12 * offset**2 / safe_length**2)
        w = 1 / var
        A = (normal * w[:, None]).T @ normal
        b = (normal * w[:, None]).T @ c
        if abs(np.linalg.det(A)) <= 1e-12 * max(float(np.trace(A)) ** 2, 1e-300):
            break
        cov = np.linalg.inv(A)
        x = cov @ b
    return x, (cov + cov.T) / 2


@no_type_check
def find_vertices(
    segments: Segments,
    *,
    radius: float = 8.0,
    min_angle: float = 20.0,
    merge: float = 3.0,
    noise: float = 1.0,
    max_vertices: int | None = None,
) -> Vertices:
    """Junctions of segments, sub-pixel.

    Every pair of segments whose lines cross at `min_angle` degrees or more is a junction
    candidate at the crossing `X` of its lines when `X` is within `radius` px of an end
    point of both (an L) or of an end point of one and inside the other (a T); that reach
    grows for acute angles `theta` to `radius * min(max(0.5 / sin(theta / 2), 1), 2.5)`,
    LSD stopping short of an acute corner. Candidates closer than `merge` px are one
    vertex: its segments are those of its candidates, the best by score first, up to
    three; its position the weighted least-squares intersection of their lines, its
    covariance that of the module docstring with perpendicular pixel noise `noise`
    (scaled by `30 / contrast`, within a factor 4, for a segment whose mean contrast is
    `contrast` grey levels). Vertices closer than `merge` px to a better one
    are dropped.

    **Arguments:** `segments`; `radius`, `merge` (pixels); `min_angle` (degrees, in
    (0, 90)); `noise` (pixels); `max_vertices`: keep only that many, the best by score.

    **Returns:** `Vertices`, by decreasing score.

    **Raises:** `ValueError` naming the argument for a bad argument.
    """
    segments = _check_segments(segments)
    radius = _check_positive(radius, "radius")
    min_angle = _check_positive(min_angle, "min_angle")
    if min_angle >= 90:
        raise ValueError(f"min_angle must be in (0, 90) degrees, got {min_angle!r}")
    merge = _check_positive(merge, "merge", zero=True)
    noise = _check_positive(noise, "noise")
    limit = None if max_vertices is None else _check_count(max_vertices, "max_vertices")
    ends, _, score = segments
    n = len(ends)
    if n < 2 or limit == 0:
        return _empty_vertices()
    d = segment_directions(ends)
    length = segment_lengths(ends)
    normal = np.column_stack([-d[:, 1], d[:, 0]])
    c = np.sum(normal * ends[:, 0], axis=1)
    # A faint edge is located less well: pixel noise scaled by a contrast of 30 grey
    # levels over the segment's (within a factor 4 either way).
    contrast = score / np.maximum(length, 1.0)
    sigma = noise * np.clip(30.0 / np.maximum(contrast, 1e-9), 0.25, 4.0)
    i, j = np.triu_indices(n, 1)
    det = normal[i, 0] * normal[j, 1] - normal[i, 1] * normal[j, 0]  # sin of the angle
    ok = np.abs(det) >= math.sin(math.radians(min_angle))
    i, j, det = i[ok], j[ok], det[ok]
    X = np.column_stack(
        [
            (c[i] * normal[j, 1] - c[j] * normal[i, 1]) / det,
            (normal[i, 0] * c[j] - normal[j, 0] * c[i]) / det,
        ]
    )
    si = np.sum((X - ends[i, 0]) * d[i], axis=1)
    sj = np.sum((X - ends[j, 0]) * d[j], axis=1)
    # Edges meeting at an acute angle blur into each other over a longer stretch.
    half = np.arcsin(np.clip(np.abs(det), 0, 1)) / 2
    reach = radius * np.clip(0.5 / np.sin(half), 1, 2.5)
    end_i = np.minimum(np.abs(si), np.abs(si - length[i])) <= reach
    end_j = np.minimum(np.abs(sj), np.abs(sj - length[j])) <= reach
    in_i = (si >= 0) & (si <= length[i])
    in_j = (sj >= 0) & (sj <= length[j])
    cand = (end_i & end_j) | (end_i & in_j) | (end_j & in_i)
    i, j, X = i[cand], j[cand], X[cand]
    if len(X) == 0:
        return _empty_vertices()
    pair_score = np.minimum(score[i], score[j])
    gaps = np.linalg.norm(X[:, None] - X[None], axis=2)
    labels = _components(len(X), np.argwhere(np.triu(gaps <= merge, 1)))
    points, covs, members, scores = [], [], [], []
    for label in np.unique(labels):
        group = np.flatnonzero(labels == label)
        best = group[np.argmax(pair_score[group])]
        chosen = [int(i[best]), int(j[best])]
        others = {int(k) for g in group for k in (i[g], j[g])} - set(chosen)
        for k in sorted(others, key=lambda k: (-score[k], k)):
            if len(chosen) == _DEGREE:
                break
            chosen.append(k)
        idx = np.array(chosen)
        x, cov = _intersect(ends[idx, 0], d[idx], length[idx], sigma[idx], X[best])
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(cov))):
            continue
        points.append(x)
        covs.append(cov)
        members.append(np.pad(idx, (0, _DEGREE - len(idx)), constant_values=-1))
        scores.append(float(np.sum(score[idx])))
    if not points:
        return _empty_vertices()
    P, C, M, S = np.array(points), np.array(covs), np.array(members), np.array(scores)
    order = np.argsort(-S, kind="stable")
    kept: list[int] = []
    for k in order:
        if kept and np.min(np.linalg.norm(P[kept] - P[k], axis=1)) <= merge:
            continue
        kept.append(int(k))
        if limit is not None and len(kept) == limit:
            break
    sel = np.array(kept)
    return Vertices(P[sel], C[sel], M[sel].astype(np.int64), S[sel])


# --------------------------------------------------------------------------- links


@no_type_check
def vertex_links(
    vertices: Vertices,
    segments: Segments,
    *,
    coverage: float = 0.6,
    distance: float = 2.0,
    angle: float = 4.0,
) -> np.ndarray:
    """Which vertices an image edge joins.

    Two vertices `a`, `b` are linked when the segments lying along the straight line
    between them (parallel to it within `angle` degrees, within `distance` px of it over
    their part between `a` and `b`) cover at least `coverage` of its length. Where three
    lines meet at a vertex they rarely cross at one point (a rounded corner): the vertex
    lies off its own segments' lines by up to some `slack` px, and the line to it may
    stray that much more near it, so the allowance grows to `distance + slack` at the
    vertex, falling linearly to `distance` at the other end (`slack` at most `distance`).

    **Arguments:** `vertices`, `segments`; `coverage` in (0, 1]; `distance` (pixels);
    `angle` (degrees).

    **Returns:** bool `(V, V)`, symmetric, False on the diagonal.
    """
    vertices = _check_vertices(vertices)
    segments = _check_segments(segments)
    coverage = _check_positive(coverage, "coverage")
    if coverage > 1:
        raise ValueError(f"coverage must be in (0, 1], got {coverage!r}")
    distance = _check_positive(distance, "distance")
    angle = _check_positive(angle, "angle")
    P = vertices.points
    V = len(P)
    links = np.zeros((V, V), dtype=bool)
    ends = segments.ends
    if V < 2 or len(ends) == 0:
        return links
    a, b = np.triu_indices(V, 1)
    ab = P[b] - P[a]
    L = np.linalg.norm(ab, axis=1)
    ok = L > 1e-9
    a, b, ab, L = a[ok], b[ok], ab[ok], L[ok]
    u = ab / L[:, None]
    nrm = np.column_stack([-u[:, 1], u[:, 0]])
    d = segment_directions(ends)
    parallel = np.abs(u @ d.T) >= math.cos(math.radians(angle))  # (P, S)
    # the rest only for the (pair, segment) entries that are parallel (a few in a hundred)
    p, k = np.nonzero(parallel)
    if len(p) == 0:
        return links
    origin, u, nrm, L_p = P[a[p]], u[p], nrm[p], L[p]
    rel0 = ends[k, 0] - origin
    rel1 = ends[k, 1] - origin
    s0 = rel0[:, 0] * u[:, 0] + rel0[:, 1] * u[:, 1]
    s1 = rel1[:, 0] * u[:, 0] + rel1[:, 1] * u[:, 1]
    h0 = rel0[:, 0] * nrm[:, 0] + rel0[:, 1] * nrm[:, 1]
    h1 = rel1[:, 0] * nrm[:, 0] + rel1[:, 1] * nrm[:, 1]
    lo = np.clip(np.minimum(s0, s1), 0, L_p)
    hi = np.clip(np.maximum(s0, s1), 0, L_p)
    span = s1 - s0
    safe = np.where(np.abs(span) > 1e-9, span, 1.0)

    def offset(s):
        return np.where(np.abs(span) > 1e-9, h0 + (h1 - h0) * (s - s0) / safe, h0)

    slack = _slack(vertices, segments, distance)

    def allowed(s):
        w = s / L_p
        return distance + slack[a[p]] * (1 - w) + slack[b[p]] * w

    near = (np.abs(offset(lo)) <= allowed(lo)) & (np.abs(offset(hi)) <= allowed(hi))
    use = near & (hi > lo)
    p, lo, hi = p[use], lo[use], hi[use]
    order = np.lexsort((lo, p))  # by pair, then by start along it
    p, lo, hi = p[order], lo[order], hi[order]
    bounds = np.flatnonzero(np.diff(p)) + 1
    for rows in np.split(np.arange(len(p)), bounds):
        if len(rows) == 0:
            continue
        covered, reach = 0.0, 0.0
        for s, e in zip(lo[rows].tolist(), hi[rows].tolist(), strict=True):
            if e > reach:
                covered += e - max(s, reach)
                reach = e
        q = p[rows[0]]
        if covered >= coverage * L[q]:
            links[a[q], b[q]] = links[b[q], a[q]] = True
    return links


def _slack(vertices: Vertices, segments: Segments, cap: float) -> np.ndarray:
    """`(V,)` each vertex's largest distance to the lines of its own segments (zero
    where two lines cross exactly), at most `cap` px."""
    ends = segments.ends
    index = np.asarray(vertices.segments, np.int64).reshape(len(vertices.points), -1)
    if index.size == 0:
        return np.zeros(len(vertices.points))
    d = segment_directions(ends)
    normal = np.column_stack([-d[:, 1], d[:, 0]])
    safe = np.clip(index, 0, len(ends) - 1)
    off = np.abs(np.sum((vertices.points[:, None] - ends[safe, 0]) * normal[safe], axis=-1))
    off = np.where((index >= 0) & (index < len(ends)), off, 0.0)
    return np.minimum(np.max(off, axis=1), cap)


# --------------------------------------------------------------------------- front end


@no_type_check
def image_primitives(
    image: np.ndarray,
    *,
    min_length: float = 8.0,
    radius: float = 8.0,
    min_angle: float = 20.0,
    coverage: float = 0.6,
    max_vertices: int = MAX_VERTICES,
) -> Primitives:
    """The image front end for polyhedral objects: `detect_segments` (with `min_length`),
    `find_vertices` (with `radius`, `min_angle`, the `max_vertices` best kept),
    `vertex_links` (with `coverage`) and `edge_distance`.

    **Arguments:** `image`: uint8 grey `(h, w)` or BGR `(h, w, 3)`; the options as the
    functions named.

    **Returns:** `Primitives`; empty arrays of the documented shapes when the image holds
    no edge.
    """
    grey = _check_image(image)
    max_vertices = _check_count(max_vertices, "max_vertices")
    segments = detect_segments(grey, min_length=min_length)
    vertices = find_vertices(
        segments, radius=radius, min_angle=min_angle, max_vertices=max_vertices
    )
    links = vertex_links(vertices, segments, coverage=coverage)
    return Primitives(segments, vertices, links, edge_distance(segments, grey.shape))
