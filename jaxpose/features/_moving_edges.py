r"""Moving edges: where the projected edges of a model went in a new image (the idea of
ViSP's moving-edge tracker, written here from its published description).

A sample point `p` of a projected model edge, with the edge's unit normal `n` in the
image, looks for the edge along that normal within `search` pixels on either side. The
grey level is read (bilinearly) at `p + (j \pm 1/2) n + \tau u` for `j = -k..k`, `u` the
edge's direction and `\tau` a few pixels along it (averaging along the edge smooths the
noise without blurring across it); the derivative across the edge at offset `j` is

$$ d_j = \bar I(j + 1/2) - \bar I(j - 1/2), $$

the image gradient's component along the expected normal: an edge of another
orientation gives a weak response. The match is the offset with the largest `|d_j|` (or
the largest `d_j` of the expected sign when the edge's contrast is known from the
previous frame), refined to sub-pixel by the parabola through the logarithms of it and
its neighbours (exact for a Gaussian-blurred edge; measured on rendered edges, it is
three times as accurate as a plain parabola for sharp edges). An edge smeared by motion
is a ramp whose derivative is a plateau: where the lobe around the peak (the contiguous
derivatives above a fifth of it) is over three samples wide, the match is the lobe's
centroid, the middle of the ramp (`_lobe_centre`); the smear also lowers the derivative,
so a wide lobe whose step (the grey levels it spans) is three times `threshold` is a
match even when its peak is below it (down to 0.4 of it). Where the smear is known
(`smear`, px: e.g. the motion along the normal over the exposure) and the frame shows
it, the sum of the derivatives over a box as wide as the smear (the step across it)
locates the ramp instead (`_ramp_matches`). A match is kept when its
derivative reaches `threshold` (or it is such a smeared edge), it (and a wide lobe) is
not at the end of the search range (where the edge may lie beyond it), and the whole
search line lies in the image.

Each kept match gives a 2D line measurement: the sample `p`, the normal `n`, and the
matched image point `p + d n`; the pose is moved so that the projected edge passes
through it (a point-to-line distance, as the paper's linear method uses lines through
image points, Section 3).

Plain numpy and OpenCV (one `cv2.remap` reads every sample's search line at once).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..geometry._validate import no_type_check

#: The least derivative the sub-pixel fit takes the logarithm of (grey levels per pixel).
_TINY = 1e-3
#: A match's lobe: the derivatives next to its peak (contiguous) above this fraction of it,
#: up to where they rise again by this fraction of it above the least one passed (the
#: next edge's lobe).
_LOBE_FLOOR = 0.2
_LOBE_RISE = 0.2
#: A lobe of more samples than this is a smeared edge: its centroid is the match.
_LOBE_WIDE = 3
#: A smeared edge's derivative is its step spread over the smear: with `"strongest"`, a
#: wide lobe (inside the search range) whose peak is below `threshold` but at least
#: `_WEAK_PEAK` of it is a match when its step (the sum of its derivatives, in grey
#: levels) is at least `_STEP` times `threshold`.
_WEAK_PEAK = 0.4
_STEP = 3.0
#: With `smear`, the ramp's match: the centroid of the box sums above this fraction of
#: their peak (the top of the triangle a ramp as wide as the box gives).
_RAMP_TOP = 0.7
#: A call's frame is taken as blurred when, over at least `_JUDGED` samples predicted to
#: smear over 4 px or more (boxes of 5), the median width of the ramps found (their step
#: over their steepest derivative) is at least `_BLURRED` of the box (`_ramp_matches`).
_BLURRED = 0.5
_JUDGED = 10

__all__ = ["EdgeMatches", "moving_edges"]


class EdgeMatches(NamedTuple):
    """Where the sample points of projected edges found an image edge.

    **Fields:**
    - `points`: `(S, 2)` the sample points (as given).
    - `normals`: `(S, 2)` their unit normals (as given, normalised).
    - `matched`: `(S, 2)` the image edge points found, `points + offset * normals`
      (the sample point itself where not `valid`).
    - `offset`: `(S,)` signed distance from the sample to its match along the normal,
      pixels (0 where not `valid`).
    - `strength`: `(S,)` the derivative across the edge at the match, grey levels per
      pixel, signed: positive when the image gets brighter along the normal (0 where not
      `valid`). Pass it as `contrast` on the next frame.
    - `valid`: `(S,)` bool.
    - `blurred`: whether the call took its frame as blurred (`smear` given and the ramps
      found about as wide as predicted: the smeared samples were matched as ramps).
    - `rival`: `(S,)` bool, on a blurred frame, whether a matched sample's line (out to
      `reach`) shows another image edge than its match (`_rivals`); False elsewhere.
    """

    points: np.ndarray
    normals: np.ndarray
    matched: np.ndarray
    offset: np.ndarray
    strength: np.ndarray
    valid: np.ndarray
    blurred: bool = False
    rival: np.ndarray | None = None


def _grey(image) -> np.ndarray:
    import cv2

    if not isinstance(image, np.ndarray):
        raise ValueError(f"image must be a numpy array, got {type(image).__name__}")
    if image.ndim == 3 and image.shape[2] in (3, 4):
        code = cv2.COLOR_BGR2GRAY if image.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
        image = cv2.cvtColor(image, code)
    elif image.ndim == 3 and image.shape[2] == 1:
        image = image[..., 0]
    if image.ndim != 2 or min(image.shape) < 2:
        raise ValueError(f"image must be (h, w) or (h, w, 1|3|4) of at least 2 x 2, got "
                         f"{image.shape}")  # fmt: skip
    dtype = np.dtype(image.dtype)
    if dtype not in (np.uint8, np.uint16, np.float32, np.float64):
        raise ValueError(f"image must be uint8, uint16, float32 or float64, got {dtype}")
    if dtype.kind == "f" and not np.all(np.isfinite(image)):
        raise ValueError("image contains NaN or infinite values")
    return np.ascontiguousarray(image, dtype=np.float32)


def _points(x, name: str, count: int | None) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 2 or (count is not None and len(x) != count):
        want = "(S, 2)" if count is None else f"({count}, 2)"
        raise ValueError(f"{name} must have shape {want}, got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError(f"{name} contains NaN or infinite values")
    return x


def _lobe_centre(score: np.ndarray, best: np.ndarray):
    """The centroid (an offset index) of each row's lobe around its peak `best` (the
    contiguous derivatives of the peak's sign above `_LOBE_FLOOR` of it, up to a rise of
    `_LOBE_RISE` of it above the least passed; weighted by their excess over the floor),
    whether the lobe is wide (over `_LOBE_WIDE` samples), whether it ends inside the
    search range (a wide lobe cut by the range's end may go on beyond it: no match), and
    its step (the sum of its derivatives).

    A moving edge smears its step into a ramp: the derivative is a plateau, whose peak
    noise places anywhere along it, while the centroid is the ramp's middle, the edge at
    mid-exposure. (Measured at the true poses of 24 rendered frames of the box turning
    up to 5 degrees a frame, each the mean of five renderings over half the frame
    interval: 90% of the offsets within 0.93 px by the peak's log-parabola, within 0.18 px
    by the lobe's centroid; for the bench's prism 1.71 and 0.33 px.) The rise test keeps
    a second edge of the same sign a few pixels away (clutter, a printed border) out of
    the lobe."""
    rows, idx = np.arange(len(score)), np.arange(score.shape[1])
    peak = score[rows, best][:, None]
    floor, rise = _LOBE_FLOOR * peak, _LOBE_RISE * peak
    # walking away from the peak on either side: the least value passed so far
    ahead = np.minimum.accumulate(np.where(idx >= best[:, None], score, np.inf), axis=1)
    behind = np.where(idx <= best[:, None], score, np.inf)[:, ::-1]
    behind = np.minimum.accumulate(behind, axis=1)[:, ::-1]
    stop_ahead = (score < floor) | (score > ahead + rise)
    stop_behind = (score < floor) | (score > behind + rise)
    left = np.where(stop_behind & (idx < best[:, None]), idx, -1).max(axis=1, initial=-1) + 1
    right = np.where(stop_ahead & (idx > best[:, None]), idx, len(idx)).min(
        axis=1, initial=len(idx)
    )
    lobe = (idx >= left[:, None]) & (idx < right[:, None])
    weight = np.where(lobe, score - floor, 0.0)
    total = weight.sum(axis=1)
    centre = (weight * idx).sum(axis=1) / np.where(total > 0, total, 1.0)
    wide = (right - left > _LOBE_WIDE) & (total > 0)
    inside = (left > 0) & (right < len(idx))
    step = np.where(lobe, score, 0.0).sum(axis=1)
    return centre, wide, inside, step


@no_type_check
def moving_edges(
    image,
    points,
    normals,
    *,
    search: int = 8,
    threshold: float = 10.0,
    contrast=None,
    mask=None,
    along: int = 1,
    choose: str = "strongest",
    ratio: float | None = None,
    smear=None,
    reach: int | None = None,
    others=None,
    limits=None,
) -> EdgeMatches:
    """Find, along each sample's normal, the image edge of the expected orientation (see
    the module docstring).

    **Arguments:**
    - `image`: grey `(h, w)` or BGR `(h, w, 3)`, uint8, uint16 or float.
    - `points`: `(S, 2)` sample points of the projected model edges (pixels).
    - `normals`: `(S, 2)` the edges' normals there (normalised here; a zero one makes
      its sample invalid).
    - `search`: `k`, the half-length of the search line in pixels (>= 2).
    - `threshold`: the least `|d|` (grey levels per pixel) a match needs.
    - `contrast`: `(S,)` the signed `strength` each sample had on the previous frame:
      only edges of that sign are taken where it is nonzero. None: either sign.
    - `ratio`: with `contrast`, also the size of the derivative: within `ratio` times
      (or one `ratio`-th of) the expected one (> 1; None: any size). A printed line next
      to an object's outline rarely has the outline's contrast.
    - `mask`: `(S,)` bool, the samples to look for (e.g. `EdgeSamples.visible`); None:
      all.
    - `along`: pixels either side along the edge averaged (0: the normal line only).
    - `choose`: `"strongest"`: the offset of the largest derivative; `"nearest"`: the
      local maximum nearest the sample among those reaching `threshold` (right when
      the prediction is good and another edge lies within the range, e.g. the far
      side of a face seen nearly edge-on).
    - `smear`: `(S,)` how far each sample's edge moved along its normal while the
      shutter was open (px), or None. Where the frame is blurred (the ramps found are
      about that wide, judged over the call's samples), a sample smeared over 2 px or
      more is matched to the middle of the ramp of that width (`_ramp_matches`); its
      `strength` is then the ramp's mean derivative. A smear wider than the image is
      taken as the image's width (a ramp no frame can show).

    - `reach`: on a blurred frame, how far (px, an int; None: `search`, never less)
      along each matched sample's normal `EdgeMatches.rival` looks for other image
      edges.
    - `others`: `(S, M)` offsets (px) along each sample's normal where other edges of
      the model are predicted to cross its line (NaN: none): an image edge there is no
      rival (the model explains it). None: none.
    - `limits`: `(S, 2)` the least and greatest offset (px along the normal, both
      excluded) each sample's match may take (-inf, inf: none), e.g. half the way to
      the other model edges predicted to cross its line, so that an image edge answers
      only the sample of the projected edge nearest it. None: any within `search`.

    **Returns:** `EdgeMatches`.

    **Raises:** `ValueError` naming the argument.
    """
    grey = _grey(image)
    points = _points(points, "points", None)
    normals = _points(normals, "normals", len(points))
    if isinstance(search, bool) or not isinstance(search, int | np.integer) or search < 2:
        raise ValueError(f"search must be an int >= 2, got {search!r}")
    if isinstance(along, bool) or not isinstance(along, int | np.integer) or along < 0:
        raise ValueError(f"along must be an int >= 0, got {along!r}")
    if isinstance(threshold, bool) or not isinstance(threshold, int | float) or threshold < 0:
        raise ValueError(f"threshold must be a number >= 0, got {threshold!r}")
    if choose not in ("strongest", "nearest"):
        raise ValueError(f"choose must be 'strongest' or 'nearest', got {choose!r}")
    count = len(points)
    sign = np.zeros(count)
    if contrast is not None:
        contrast = np.asarray(contrast, dtype=np.float64).reshape(-1)
        if contrast.shape != (count,) or not np.all(np.isfinite(contrast)):
            raise ValueError(f"contrast must be {count} finite values")
        sign = np.sign(contrast)
    expected = np.zeros(count) if contrast is None else contrast
    if ratio is not None and (isinstance(ratio, bool) or not ratio > 1):
        raise ValueError(f"ratio must be a number > 1 or None, got {ratio!r}")
    keep = np.ones(count, bool)
    if mask is not None:
        mask = np.asarray(mask)
        if mask.shape != (count,) or mask.dtype != bool:
            raise ValueError(f"mask must be a bool array of shape ({count},)")
        keep &= mask
    length = np.linalg.norm(normals, axis=1)
    keep &= length > 1e-12
    n = normals / np.where(length > 1e-12, length, 1.0)[:, None]
    u = np.column_stack([n[:, 1], -n[:, 0]])
    k = int(search)
    if reach is not None and (isinstance(reach, bool) or not isinstance(reach, int | np.integer)
                              or reach < 0):  # fmt: skip
        raise ValueError(f"reach must be an int >= 0 or None, got {reach!r}")
    if others is not None:
        others = np.asarray(others, dtype=np.float64)
        if others.ndim != 2 or len(others) != count or np.any(np.isinf(others)):
            raise ValueError(f"others must be ({count}, M) offsets, NaN for none")
    if limits is not None:
        limits = np.asarray(limits, dtype=np.float64)
        if limits.shape != (count, 2) or np.any(np.isnan(limits)):
            raise ValueError(f"limits must be ({count}, 2) offsets, -inf/inf for none")
    halves = np.zeros(count, int)  # the ramp's box of `2 h + 1` derivatives
    if smear is not None:
        smear = np.asarray(smear, dtype=np.float64).reshape(-1)
        if smear.shape != (count,) or not np.all(np.isfinite(smear)) or np.any(smear < 0):
            raise ValueError(f"smear must be {count} finite values >= 0")
        smear = np.minimum(smear, max(grey.shape))  # (read no profile past that)
        halves = np.floor(smear / 2).astype(int)  # (the box nearest the smear, odd)
    pad = int(halves.max(initial=0))  # (the profile read further for the boxes)
    m = np.arange(-k - pad, k + pad + 2, dtype=np.float64) - 0.5  # half-step positions
    tau = np.arange(-along, along + 1, dtype=np.float64)
    coords = _line_coords(points, n, u, m, tau)  # (S, 2 (k + pad) + 2, T, 2)
    h, w = grey.shape
    x, y = coords[:, pad : len(m) - pad, :, 0], coords[:, pad : len(m) - pad, :, 1]
    inside = ((x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1)).all(axis=(1, 2))
    keep &= inside
    if count == 0:
        z = np.zeros(0)
        return EdgeMatches(
            points, n, points.copy(), z, z, np.zeros(0, bool), False, np.zeros(0, bool)
        )
    profile = _read(grey, coords)
    further = np.diff(profile, axis=1)  # (S, 2 (k + pad) + 1)
    d = further[:, pad : further.shape[1] - pad]  # (S, 2k + 1) at offsets -k..k
    score = np.where(sign[:, None] == 0, np.abs(d), d * sign[:, None])
    # (with "strongest", a peak down to `_WEAK_PEAK` of the threshold is looked at: a
    # smeared edge's, taken when its lobe's step is large, see `_STEP`)
    weak = _WEAK_PEAK if choose == "strongest" else 1.0
    allowed = score >= weak * threshold
    if ratio is not None:  # the expected contrast's size, within a factor `ratio`
        size = np.abs(expected)[:, None]
        allowed &= (size == 0) | ((score >= size / ratio) & (score <= size * ratio))
    if limits is not None:  # (the offsets -k..k within each sample's limits)
        offsets = np.arange(-k, k + 1)[None, :]
        allowed &= (offsets > limits[:, :1]) & (offsets < limits[:, 1:])
    if choose == "nearest":
        padded = np.pad(score, ((0, 0), (1, 1)), constant_values=-np.inf)
        peaks = (score >= padded[:, :-2]) & (score > padded[:, 2:]) & allowed
        peaks[:, [0, 2 * k]] = False
        distance = np.where(peaks, np.abs(np.arange(2 * k + 1) - k), 4 * k)
        best = np.argmin(distance, axis=1)
        allowed_best = peaks.any(axis=1)
    else:
        best = np.argmax(np.where(allowed, score, -np.inf), axis=1)
        allowed_best = allowed.any(axis=1)
    rows = np.arange(count)
    interior = (best > 0) & (best < 2 * k)
    # Sub-pixel: the parabola through the logarithms of the derivatives of the peak's
    # sign (exact for a Gaussian-blurred edge; the same with or without `contrast`), an
    # opposite or zero neighbour counted as a tiny one; for a wide lobe (a smeared
    # edge), its centroid.
    polarity = np.sign(d[rows, best])
    near = np.stack([best - 1, best, best + 1], axis=1).clip(0, 2 * k)
    logs = np.log(np.maximum(d[rows[:, None], near] * polarity[:, None], _TINY))
    curve = logs[:, 0] - 2 * logs[:, 1] + logs[:, 2]
    fit = interior & (curve < -1e-12)
    delta = 0.5 * (logs[:, 0] - logs[:, 2]) / np.where(fit, curve, -1.0)
    delta = np.where(fit, np.clip(delta, -0.5, 0.5), 0.0)
    centre, wide, inside, step = _lobe_centre(d * polarity[:, None], best)
    delta = np.where(wide, centre - best, delta)
    interior &= ~wide | inside
    strong = score[rows, best] >= threshold
    smeared = wide & (step >= _STEP * threshold)
    valid = keep & interior & allowed_best & (strong | smeared)
    offset = np.where(valid, best - k + delta, 0.0)
    strength = np.where(valid, d[rows, best], 0.0)
    ramp = _ramp_matches(further, sign, expected, ratio, threshold, halves, pad, limits)
    if ramp is not None:  # a blurred frame: the smeared samples' ramps
        use, ramp_offset, ramp_strength, ramp_valid = ramp
        valid = np.where(use, keep & ramp_valid, valid)
        offset = np.where(use & valid, ramp_offset - k, np.where(use, 0.0, offset))
        strength = np.where(use & valid, ramp_strength, np.where(use, 0.0, strength))
    matched = points + offset[:, None] * n
    rival = np.zeros(count, bool)
    if ramp is not None and np.any(valid):  # (a blurred frame: the lines looked along)
        K = max(k, k if reach is None else int(reach))
        line = d[valid]
        if K > k:  # (read as far as `reach`)
            wide = np.arange(-K - pad, K + pad + 2, dtype=np.float64) - 0.5
            far = _read(grey, _line_coords(points[valid], n[valid], u[valid], wide, tau))
            line = np.diff(far, axis=1)[:, pad : 2 * (K + pad) + 1 - pad]
        explained = None if others is None else others[valid] + K
        rival[valid] = _rivals(line, offset[valid] + K, halves[valid], threshold, explained)
    return EdgeMatches(points, n, matched, offset, strength, valid, ramp is not None, rival)


def _line_coords(points, n, u, m, tau) -> np.ndarray:
    """`(S, M, T, 2)`: the points `m` along each sample's normal `n`, `tau` across it
    (along `u`)."""
    return (
        points[:, None, None, :]
        + m[None, :, None, None] * n[:, None, None, :]
        + tau[None, None, :, None] * u[:, None, None, :]
    )


def _read(grey: np.ndarray, coords: np.ndarray) -> np.ndarray:
    """The grey levels (bilinear) at `coords` `(S, M, T, 2)`, averaged over `T`: `(S, M)`."""
    import cv2

    count = len(coords)
    flat = coords.reshape(count, -1, 2).astype(np.float32)
    values = np.concatenate([  # (OpenCV maps have fewer than 32767 rows)
        cv2.remap(grey, part[..., 0], part[..., 1], cv2.INTER_LINEAR,
                  borderMode=cv2.BORDER_REPLICATE)
        for part in np.array_split(flat, -(-count // 32000))
    ])  # fmt: skip
    return values.reshape(coords.shape[:3]).mean(axis=2, dtype=np.float64)


def _rivals(d, at, h, threshold, others=None) -> np.ndarray:
    """Whether each row of derivatives `d` `(S, 2K + 1)` (offsets -K..K) shows another
    image edge than its match (at index `at`): a run of contiguous derivatives of one
    sign, one of them reaching `threshold`, none of them within `h + 1` of the match (`h`:
    half the box of the predicted smear, 0 for none), nor within `h + 1` of another edge
    of the model (`others` `(S, M)`, indices; NaN for none), nor at either end of the row
    (an edge that may lie beyond it).

    A smear merges an edge with any other within its reach into one ramp (on the
    photo-textured box, the crease at the box's origin with a printed border 2-3 px from
    it): where the line is clear of other image edges, the ramp found is the edge's own."""
    count, width = d.shape
    j = np.arange(width)
    own = np.abs(j[None, :] - np.asarray(at)[:, None]) <= (np.asarray(h) + 1)[:, None]
    if others is not None and others.shape[1]:  # (NaN: no edge, never near)
        near = np.abs(j[None, :, None] - others[:, None, :]) <= (np.asarray(h) + 1)[:, None, None]
        own |= near.any(axis=2)
    sign = np.sign(d)
    before = np.pad(sign, ((0, 0), (1, 0)))[:, :-1]
    label = np.cumsum(sign != before, axis=1)  # (each run of one sign numbered)
    rows = np.broadcast_to(np.arange(count)[:, None], label.shape)
    mine = np.zeros((count, width + 1), bool)
    np.logical_or.at(mine, (rows, label), own)  # (the runs the match touches)
    np.logical_or.at(mine, (rows[:, [0, -1]], label[:, [0, -1]]), True)  # (and the ends')
    return np.any((np.abs(d) >= threshold) & ~mine[rows, label], axis=1)


def _ramp_matches(d, sign, expected, ratio, threshold, h, pad, limits=None):
    """Each smeared sample's edge as a ramp of the predicted width, on a blurred frame:
    `(use, offset index, strength, valid)` (`use`: the samples whose box `2 h + 1` is 3
    or more), or None where no sample is smeared or the frame is not blurred.

    `d` `(S, 2 (k + pad) + 1)` are the derivatives along the normals, read `pad` further
    than the search range either side. An edge moving `v` px along its normal while the
    shutter is open is a ramp about `v` wide; the sum of the derivatives over a box as
    wide (the step across it) peaks at the ramp's middle, where noise and texture that
    break its derivatives into pieces leave it whole. The match is the largest box sum
    of the expected sign (a step of at least `threshold` grey levels, centred within the
    search range; with `ratio`, its mean derivative within `ratio` of the expected
    contrast; with `limits` `(S, 2)`, centred within them), at the centroid of the box
    sums above `_RAMP_TOP` of it; that top must end inside the range. The strength is
    the mean derivative over the box (the units of `strength`).

    A sharp edge also gives a flat-topped run of box sums, but its step is within a
    pixel or two; the frame is taken as blurred when, over at least `_JUDGED` samples
    with boxes of 5 or more, the median width of the ramps found (step over steepest
    derivative in the box) is at least `_BLURRED` of the box (measured per call over the
    rendered benchmark, 48 runs: sharp frames 0.25-0.58 where 10 or more samples were
    judged, the motion-blurred ones 0.55-0.75 at the 5th percentile)."""
    use = h >= 1
    if np.count_nonzero(h >= 2) < _JUDGED:  # (too few samples to judge the frame by)
        return None
    whole = d.shape[0]
    d, sign, expected, h = (np.asarray(a)[use] for a in (d, sign, expected, h))  # (the rest unused)
    count, width = d.shape
    j = np.arange(width)
    k = (width - 1) // 2 - pad  # (the search range)
    total = np.concatenate([np.zeros((count, 1)), np.cumsum(d, axis=1)], axis=1)
    rows = np.arange(count)
    hi = np.clip(j[None, :] + h[:, None] + 1, 0, width)
    lo = np.clip(j[None, :] - h[:, None], 0, width)
    step = total[rows[:, None], hi] - total[rows[:, None], lo]  # (S, width): box sums
    score = np.where(sign[:, None] == 0, np.abs(step), step * sign[:, None])
    allowed = (j >= pad) & (j < width - pad) & (score >= threshold)  # centres -k..k
    if limits is not None:  # (the centres within each sample's limits)
        low, high = limits[use, :1], limits[use, 1:]
        allowed &= (j[None, :] - pad - k > low) & (j[None, :] - pad - k < high)
    box = (2 * h + 1)[:, None]
    if ratio is not None:
        size = np.abs(expected)[:, None]
        allowed &= (size == 0) | ((score >= box * size / ratio) & (score <= box * size * ratio))
    best = np.argmax(np.where(allowed, score, -np.inf), axis=1)
    peak = score[rows, best]
    polarity = np.sign(step[rows, best])
    signed = step * polarity[:, None]
    above = signed >= _RAMP_TOP * peak[:, None]
    left = np.where(~above & (j < best[:, None]), j, -1).max(axis=1) + 1
    right = np.where(~above & (j > best[:, None]), j, width).min(axis=1)
    top = (j >= left[:, None]) & (j < right[:, None])
    weight = np.where(top, signed - _RAMP_TOP * peak[:, None], 0.0)
    centre = (weight * j).sum(axis=1) / np.maximum(weight.sum(axis=1), 1e-12) - pad
    valid = allowed.any(axis=1) & (left > pad) & (right < width - pad - 1)
    near = np.abs(j - best[:, None]) <= h[:, None]
    steepest = np.where(near, d * polarity[:, None], -np.inf).max(axis=1)
    found = peak / np.maximum(steepest, 1e-3) / box[:, 0]  # the ramp's width / the box's
    judged = valid & (h >= 2)
    if np.count_nonzero(judged) < _JUDGED or np.median(found[judged]) < _BLURRED:
        return None
    out = [np.zeros(whole), np.zeros(whole), np.zeros(whole, bool)]
    for full, part in zip(out, (centre, step[rows, best] / box[:, 0], valid), strict=True):
        full[use] = part
    return use, *out
