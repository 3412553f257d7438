"""Straight edges of an image: line segments detected with OpenCV's LSD (von Gioi et al.,
"LSD: a fast line segment detector with a false detection control", IPOL 2012), pieces
of one edge chained into one segment, and the distance map of the detected edges.

Pixel coordinates follow OpenCV: `(x, y)`, x to the right, y down, integer coordinates at
pixel centres (the edge between columns 9 and 10 is at `x = 9.5`). A segment's direction
`ends[1] - ends[0]` keeps LSD's polarity: the brighter side is on its left in the image
(x right, y down), so segments of one edge seen against different sides keep their
orientation.

Plain numpy and OpenCV (imported inside the functions, so that `import jaxpose` stays
fast): nothing here is traced.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..geometry._validate import no_type_check

__all__ = ["Segments", "chain_segments", "detect_segments", "edge_distance"]


class Segments(NamedTuple):
    """Line segments of an image (pixels, OpenCV's convention)."""

    ends: np.ndarray
    """`(S, 2, 2)` float64: segment, end, `(x, y)`; `ends[:, 1] - ends[:, 0]` is the
    direction, the brighter side on its left."""
    width: np.ndarray
    """`(S,)` float64: width of the edge's support region (pixels)."""
    score: np.ndarray
    """`(S,)` float64, nonnegative: length times the mean grey-level contrast across the
    segment (the larger, the stronger the edge)."""


def _empty_segments() -> Segments:
    return Segments(np.zeros((0, 2, 2)), np.zeros(0), np.zeros(0))


# --------------------------------------------------------------------------- validation


def _check_image(image) -> np.ndarray:
    """The image as grey uint8 `(h, w)`, or ValueError naming `image`."""
    import cv2

    if not isinstance(image, np.ndarray):
        raise ValueError(f"image must be a numpy array, got {type(image).__name__}")
    if image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] not in (1, 3, 4)):
        raise ValueError(f"image must have shape (h, w) or (h, w, 1|3|4), got {image.shape}")
    if image.shape[0] < 2 or image.shape[1] < 2:
        raise ValueError(f"image must be at least 2 x 2 pixels, got shape {image.shape}")
    if image.dtype != np.uint8:
        raise ValueError(f"image must be uint8, got dtype {image.dtype}")
    if image.ndim == 2:
        return np.ascontiguousarray(image)
    if image.shape[2] == 1:
        return np.ascontiguousarray(image[..., 0])
    code = cv2.COLOR_BGR2GRAY if image.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
    return cv2.cvtColor(np.ascontiguousarray(image), code)


def _check_positive(value, name: str, *, zero: bool = False) -> float:
    """A finite number `> 0` (`>= 0` with `zero`), or ValueError naming it."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise ValueError(f"{name} must be a number, got {value!r}")
    x = float(value)
    if not math.isfinite(x) or x < 0 or (x == 0 and not zero):
        bound = ">= 0" if zero else "> 0"
        raise ValueError(f"{name} must be finite and {bound}, got {value!r}")
    return x


def _check_segments(segments, name: str = "segments") -> Segments:
    """A `Segments` with consistent, finite arrays, or ValueError naming it."""
    if not isinstance(segments, Segments):
        raise ValueError(f"{name} must be a Segments, got {type(segments).__name__}")
    ends = np.asarray(segments.ends, dtype=np.float64)
    width = np.asarray(segments.width, dtype=np.float64)
    score = np.asarray(segments.score, dtype=np.float64)
    if ends.ndim != 3 or ends.shape[1:] != (2, 2):
        raise ValueError(f"{name}.ends must have shape (S, 2, 2), got {ends.shape}")
    n = len(ends)
    if width.shape != (n,) or score.shape != (n,):
        raise ValueError(
            f"{name}.width and {name}.score must have shape ({n},), "
            f"got {width.shape} and {score.shape}"
        )
    if not (
        np.all(np.isfinite(ends)) and np.all(np.isfinite(width)) and np.all(np.isfinite(score))
    ):
        raise ValueError(f"{name} contains NaN or infinite values")
    return Segments(ends, width, score)


# --------------------------------------------------------------------------- geometry


def segment_lengths(ends: np.ndarray) -> np.ndarray:
    """Lengths `(S,)` of segments `(S, 2, 2)`."""
    return np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1)


def segment_directions(ends: np.ndarray) -> np.ndarray:
    """Unit directions `(S, 2)` of segments (`(1, 0)` for a segment of zero length)."""
    d = ends[:, 1] - ends[:, 0]
    n = np.linalg.norm(d, axis=1, keepdims=True)
    safe = np.where(n > 1e-12, n, 1.0)
    return np.where(n > 1e-12, d / safe, np.array([1.0, 0.0]))


def _contrast(grey: np.ndarray, ends: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """Mean absolute grey-level difference across each segment, sampled at `offset` px on
    either side (bilinear, `cv2.remap`) at 16 points along it."""
    import cv2

    if len(ends) == 0:
        return np.zeros(0)
    d = segment_directions(ends)
    normal = np.column_stack([-d[:, 1], d[:, 0]])
    s = (np.arange(16) + 0.5) / 16
    along = ends[:, None, 0] + s[None, :, None] * (ends[:, None, 1] - ends[:, None, 0])
    shift = (offset[:, None] * normal)[:, None, :]
    left = (along + shift).astype(np.float32)
    right = (along - shift).astype(np.float32)
    image = grey.astype(np.float32)

    def sample(points):
        return cv2.remap(
            image,
            np.ascontiguousarray(points[..., 0]),
            np.ascontiguousarray(points[..., 1]),
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_REPLICATE,
        )

    return np.mean(np.abs(sample(left) - sample(right)), axis=1).astype(np.float64)


# --------------------------------------------------------------------------- detection


@no_type_check
def detect_segments(
    image: np.ndarray,
    *,
    min_length: float = 8.0,
    scale: float = 0.8,
    min_contrast: float = 4.0,
    chain: bool = True,
    angle: float = 2.0,
    gap: float = 6.0,
) -> Segments:
    """Line segments of an image: OpenCV's LSD (`cv2.createLineSegmentDetector`,
    `LSD_REFINE_STD`), pieces of one edge chained (`chain_segments`), short and faint
    segments dropped.

    LSD smooths and subsamples the image by `scale`; the half-pixel shift that the
    subsampling puts into its coordinates is taken out, so that a step edge between
    columns 9 and 10 is found at `x = 9.5`.

    **Arguments:**
    - `image`: uint8 `(h, w)` grey or `(h, w, 3)` BGR (`(h, w, 4)` BGRA) image.
    - `min_length`: shortest segment kept (pixels), after chaining.
    - `scale`: LSD's image scale, in `(0, 1]`.
    - `min_contrast`: faintest segment kept: its mean grey-level difference across it.
    - `chain`: merge collinear, nearly touching pieces (`chain_segments` with `angle` and
      `gap`).

    **Returns:** `Segments`, by decreasing score; empty arrays when the image has none.

    **Raises:** `ValueError` naming the argument for a bad image or option.
    """
    import cv2

    grey = _check_image(image)
    min_length = _check_positive(min_length, "min_length")
    scale = _check_positive(scale, "scale")
    if scale > 1:
        raise ValueError(f"scale must be in (0, 1], got {scale!r}")
    min_contrast = _check_positive(min_contrast, "min_contrast", zero=True)
    angle = _check_positive(angle, "angle")
    gap = _check_positive(gap, "gap", zero=True)
    lsd = cv2.createLineSegmentDetector(cv2.LSD_REFINE_STD, scale)
    lines, widths, _, _ = lsd.detect(grey)
    if lines is None or len(lines) == 0:
        return _empty_segments()
    ends = lines.reshape(-1, 2, 2).astype(np.float64) + 0.5 * (1.0 / scale - 1.0)
    width = np.asarray(widths, dtype=np.float64).reshape(-1)
    length = segment_lengths(ends)
    keep = length >= 1.0
    ends, width, length = ends[keep], width[keep], length[keep]
    contrast = _contrast(grey, ends, np.maximum(width / 2 + 1.0, 1.5))
    segments = Segments(ends, width, length * contrast)
    if chain:
        segments = chain_segments(segments, angle=angle, gap=gap)
    length = segment_lengths(segments.ends)
    safe = np.where(length > 0, length, 1.0)
    keep = (length >= min_length) & (segments.score >= min_contrast * safe)
    order = np.argsort(-segments.score[keep], kind="stable")
    return Segments(*(np.ascontiguousarray(x[keep][order]) for x in segments))


def _components(n: int, pairs: np.ndarray) -> np.ndarray:
    """Connected-component labels `(n,)` of a graph given by index pairs `(m, 2)`."""
    parent = np.arange(n)

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for a, b in pairs:
        ra, rb = find(int(a)), find(int(b))
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)
    return np.array([find(i) for i in range(n)], dtype=np.int64)


def fit_line(points: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted total least squares line through points `(m, 2)`: `(centroid, unit
    direction)`, the direction the principal axis of the weighted scatter."""
    w = weights / max(float(np.sum(weights)), 1e-300)
    centre = w @ points
    r = points - centre
    scatter = (r * w[:, None]).T @ r
    _, vectors = np.linalg.eigh(scatter)
    return centre, vectors[:, 1]


@no_type_check
def chain_segments(
    segments: Segments, *, angle: float = 2.0, gap: float = 6.0, offset: float = 1.5
) -> Segments:
    """Merge collinear, nearly touching segments (one edge broken in pieces by texture,
    noise or a crossing line) into chains, each replaced by one segment on its fitted line.

    Two segments join when their lines are parallel within `angle` degrees (polarity
    ignored), the end points of each lie within `offset` px of the other's line, and the
    gap between them along the lines is at most `gap` px (overlap counts as no gap);
    chains are the connected groups. A chain's line is the total least squares fit to its
    pieces' end points weighted by their lengths; its ends are the extreme projections of
    those end points; its direction is that of the longer pieces (length-weighted vote);
    its width the length-weighted mean, its score the sum.

    **Arguments:** `segments`; `angle` (degrees), `gap` and `offset` (pixels).

    **Returns:** `Segments`; single pieces pass unchanged (in their input order, chains
    after them).
    """
    segments = _check_segments(segments)
    angle = _check_positive(angle, "angle")
    gap = _check_positive(gap, "gap", zero=True)
    offset = _check_positive(offset, "offset")
    ends, width, score = segments
    n = len(ends)
    if n < 2:
        return segments
    d = segment_directions(ends)
    length = segment_lengths(ends)
    mid = ends.mean(axis=1)
    parallel = np.abs(d @ d.T) >= math.cos(math.radians(angle))
    normal = np.column_stack([-d[:, 1], d[:, 0]])
    # the rest only for the parallel pairs (a few in a hundred), `i < j`
    i, j = np.nonzero(np.triu(parallel, 1))

    def along_line(a, b):
        """Whether both end points of segments `b` lie within `offset` of the lines of
        segments `a`, and the gap between them along those lines is at most `gap` (an
        overlap is no gap)."""
        rel = ends[b] - mid[a][:, None, :]  # (P, 2 ends, 2)
        dist = np.abs(rel[..., 0] * normal[a, None, 0] + rel[..., 1] * normal[a, None, 1])
        along = rel[..., 0] * d[a, None, 0] + rel[..., 1] * d[a, None, 1]
        lo, hi = np.min(along, axis=1), np.max(along, axis=1)
        half = length[a] / 2
        separation = np.maximum(lo - half, -half - hi)  # (< 0: overlap)
        return (np.max(dist, axis=1) <= offset) & (separation <= gap)

    joined = along_line(i, j) & along_line(j, i)
    pairs = np.column_stack([i[joined], j[joined]])
    if len(pairs) == 0:
        return segments
    labels = _components(n, pairs)
    groups: dict[int, list[int]] = {}
    for i, label in enumerate(labels):
        groups.setdefault(int(label), []).append(i)
    singles = [g[0] for g in groups.values() if len(g) == 1]
    out_ends = [ends[singles]]
    out_width = [width[singles]]
    out_score = [score[singles]]
    for members in (g for g in groups.values() if len(g) > 1):
        m = np.array(members)
        points = ends[m].reshape(-1, 2)
        centre, direction = fit_line(points, np.repeat(length[m], 2))
        if np.sum(length[m] * (d[m] @ direction)) < 0:
            direction = -direction
        s = (points - centre) @ direction
        chained = centre + np.array([[s.min()], [s.max()]]) * direction
        out_ends.append(chained[None])
        out_width.append(np.array([np.sum(width[m] * length[m]) / max(np.sum(length[m]), 1e-300)]))
        out_score.append(np.array([np.sum(score[m])]))
    return Segments(
        np.concatenate(out_ends).reshape(-1, 2, 2),
        np.concatenate(out_width),
        np.concatenate(out_score),
    )


@no_type_check
def edge_distance(segments: Segments, shape) -> np.ndarray:
    """Distance (pixels) from every pixel to the nearest detected segment: the segments
    drawn one pixel wide (`cv2.line`, sub-pixel ends) on a mask, then
    `cv2.distanceTransform` (exact Euclidean, `DIST_MASK_PRECISE`).

    **Arguments:** `segments`; `shape`: the image's shape, `(h, w)` or `(h, w, c)`.

    **Returns:** float32 `(h, w)`: 0 on the segments, growing away from them; with no
    segment, the image's diagonal everywhere (farther than any segment could be).
    """
    import cv2

    segments = _check_segments(segments)
    try:
        h, w = (int(x) for x in tuple(shape)[:2])
    except (TypeError, ValueError) as exc:
        raise ValueError(f"shape must be (h, w) or (h, w, c), got {shape!r}") from exc
    if h < 1 or w < 1 or len(tuple(shape)) not in (2, 3):
        raise ValueError(f"shape must be (h, w) or (h, w, c) with h, w >= 1, got {shape!r}")
    if len(segments.ends) == 0:
        return np.full((h, w), math.hypot(h, w), dtype=np.float32)
    mask = np.full((h, w), 255, dtype=np.uint8)
    shift = 4
    fixed = np.round(segments.ends * (1 << shift))
    fixed = np.clip(fixed, -(1 << 24), 1 << 24).astype(np.int64)
    for (x0, y0), (x1, y1) in fixed:
        cv2.line(mask, (int(x0), int(y0)), (int(x1), int(y1)), 0, 1, cv2.LINE_8, shift)
    if mask.min() > 0:  # every segment outside the image
        return np.full((h, w), math.hypot(h, w), dtype=np.float32)
    distance = cv2.distanceTransform(mask, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return np.asarray(distance, dtype=np.float32)


def oriented_edge_distance(segments: Segments, shape, bins: int = 8) -> np.ndarray:
    """`edge_distance` by direction: map `b` holds the distance to the segments whose
    direction (modulo 180 degrees) lies within one bin width (`180 / bins` degrees) of
    bin `b`'s centre, `(b + 0.5) * 180 / bins`. A predicted edge of direction `phi`
    looks up map `floor(phi / (180 / bins))`: segments within half a bin to one and a
    half bins of its direction count, crossing ones do not.

    **Arguments:** `segments`; `shape` as `edge_distance`; `bins` (>= 2).

    **Returns:** float32 `(bins, h, w)`.
    """
    segments = _check_segments(segments)
    if isinstance(bins, bool) or not isinstance(bins, int | np.integer) or bins < 2:
        raise ValueError(f"bins must be an integer >= 2, got {bins!r}")
    width = math.pi / bins
    d = segments.ends[:, 1] - segments.ends[:, 0]
    angle = np.mod(np.arctan2(d[:, 1], d[:, 0]), math.pi)
    maps = []
    for b in range(bins):
        off = np.abs(np.mod(angle - (b + 0.5) * width + math.pi / 2, math.pi) - math.pi / 2)
        keep = off <= width
        maps.append(edge_distance(Segments(*(f[keep] for f in segments)), shape))
    return np.stack(maps)
