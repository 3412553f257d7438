"""Keypoints tracked from frame to frame (KLT): corners found inside a region (the model's
visible faces) with OpenCV's `goodFeaturesToTrack` (Shi and Tomasi's minimum-eigenvalue
score), followed with OpenCV's pyramidal Lucas-Kanade `calcOpticalFlowPyrLK`, and each
track checked forward-backward: the point found in the new frame is tracked back to the
old one, and the track is kept only when it lands within `fb_threshold` pixels of where
it started (Kalal, Mikolajczyk and Matas, "Forward-backward error", ICPR 2010), and,
with `min_correlation`, when the patch around it in the new frame correlates with the
patch it left (normalised cross-correlation): on a plain face the only corners are the
image noise, drawn afresh on every frame, which the flow cannot follow (such a point
stays put while the object moves, and passes the forward-backward check).

Their 3D points come from casting rays through them onto the model at the current pose
(`jaxpose.apps.cast_rays`); with the next frame's tracked pixels they give the
point correspondences of the paper's small-movement linear method (Section 3).

Plain numpy and OpenCV: nothing here is traced.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..geometry._validate import no_type_check
from ._moving_edges import _grey, _read
from ._raster import _dots

__all__ = ["EXPOSURE_STEP", "Tracks", "detect_corners", "relit", "track_points"]


class Tracks(NamedTuple):
    """Points followed from one frame to the next.

    **Fields:**
    - `points`: `(N, 2)` float64, where each point is in the new frame (where it was in
      the old one when `valid` is False).
    - `valid`: `(N,)` bool: found, inside the image, and back within `fb_threshold` of
      its start when tracked backwards.
    - `fb_error`: `(N,)` the forward-backward distance in pixels (0 where not tracked).
    - `correlation`: `(N,)` the normalised cross-correlation of each point's patch in
      the old frame and where it went in the new one (`patch` x `patch` pixels, read
      bilinearly; 0 where not tracked or where either patch is flat), or None where
      `track_points` was not asked for it.
    """

    points: np.ndarray
    valid: np.ndarray
    fb_error: np.ndarray
    correlation: np.ndarray | None = None


def _grey8(image, name: str) -> np.ndarray:
    try:
        grey = _grey(image)
    except ValueError as exc:
        raise ValueError(str(exc).replace("image", name, 1)) from None
    if np.asarray(image).dtype == np.uint8:
        return np.asarray(grey, dtype=np.uint8)
    return np.clip(np.round(grey), 0, 255).astype(np.uint8)


def _as_points(points, name: str) -> np.ndarray:
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 2 or not np.all(np.isfinite(points)):
        raise ValueError(f"{name} must be finite with shape (N, 2), got {points.shape}")
    return points


@no_type_check
def detect_corners(
    image,
    mask=None,
    *,
    max_corners: int = 300,
    quality: float = 0.01,
    min_distance: float = 8.0,
    block_size: int = 5,
    existing=None,
) -> np.ndarray:
    """Corners to track inside a region of an image (OpenCV's `goodFeaturesToTrack`).

    **Arguments:**
    - `image`: grey or BGR, uint8 (other depths are clipped to 0..255).
    - `mask`: `(h, w)` uint8 or bool, nonzero where to look (e.g. the model's visible
      faces, `jaxpose.apps.face_mask` eroded a few pixels); None: everywhere.
    - `max_corners`, `quality` (a fraction of the best corner's score), `min_distance`
      (pixels between corners), `block_size`: as OpenCV's.
    - `existing`: `(M, 2)` points already tracked: no new corner within `min_distance`
      of them (to top a set of tracks up).

    **Returns:** `(N, 2)` float64 pixels, `N <= max_corners`, strongest first.

    **Raises:** `ValueError` naming the argument.
    """
    import cv2

    grey = _grey8(image, "image")
    h, w = grey.shape
    if mask is None:
        region = np.full((h, w), 255, np.uint8)
    else:
        mask = np.asarray(mask)
        if mask.shape != (h, w):
            raise ValueError(f"mask must have the image's shape {(h, w)}, got {mask.shape}")
        region = np.where(mask != 0, 255, 0).astype(np.uint8)
    if isinstance(max_corners, bool) or not isinstance(max_corners, int) or max_corners < 1:
        raise ValueError(f"max_corners must be an int >= 1, got {max_corners!r}")
    if not 0 < quality < 1:
        raise ValueError(f"quality must be in (0, 1), got {quality!r}")
    if not min_distance >= 0:
        raise ValueError(f"min_distance must be >= 0, got {min_distance!r}")
    if isinstance(block_size, bool) or not isinstance(block_size, int) or block_size < 3:
        raise ValueError(f"block_size must be an int >= 3, got {block_size!r}")
    if existing is not None:
        existing = _as_points(existing, "existing")
        radius = max(int(round(min_distance)), 1)
        dots = np.where(_dots(existing, (h, w)), 255, 0).astype(np.uint8)
        disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
        region[cv2.dilate(dots, disc) > 0] = 0
    if not region.any():
        return np.zeros((0, 2))
    # Within the region's bounding box only (ten times as fast as a masked whole image
    # for an object covering a quarter of it).
    x, y, bw, bh = cv2.boundingRect(region)
    pad = block_size
    x0, y0 = max(x - pad, 0), max(y - pad, 0)
    x1, y1 = min(x + bw + pad, w), min(y + bh + pad, h)
    corners = cv2.goodFeaturesToTrack(
        np.ascontiguousarray(grey[y0:y1, x0:x1]), max_corners, float(quality),
        float(min_distance), mask=np.ascontiguousarray(region[y0:y1, x0:x1]),
        blockSize=block_size,
    )  # fmt: skip
    if corners is None:
        return np.zeros((0, 2))
    return corners.reshape(-1, 2).astype(np.float64) + [x0, y0]


@no_type_check
def track_points(
    previous,
    current,
    points,
    *,
    window: int = 15,
    levels: int = 3,
    fb_threshold: float = 1.0,
    iterations: int = 20,
    min_correlation: float | None = None,
    patch: int = 7,
) -> Tracks:
    """Follow points from one frame to the next (pyramidal Lucas-Kanade, checked
    forward-backward; see the module docstring).

    **Arguments:**
    - `previous`, `current`: the two frames, grey or BGR, of one size.
    - `points`: `(N, 2)` pixels in `previous`.
    - `window`: the side of the matching window (odd, >= 5); `levels`: pyramid levels
      above the image (>= 0); `iterations`: Lucas-Kanade steps per level.
    - `fb_threshold`: the largest forward-backward distance kept, pixels.
    - `min_correlation`: the least normalised cross-correlation (in [-1, 1]) of a
      point's `patch` x `patch` neighbourhood (odd, >= 3) in the two frames that keeps
      it (`Tracks.correlation`); None: not checked. Noise alone correlates about 0
      (two frames of pure noise, sigma 2, 7 x 7: 0.38 at the 99th percentile, 0.49 at
      the 99.9th), a textured patch about 1.

    **Returns:** `Tracks`.

    **Raises:** `ValueError` naming the argument.
    """
    import cv2

    prev = _grey8(previous, "previous")
    curr = _grey8(current, "current")
    if prev.shape != curr.shape:
        raise ValueError(f"current must have previous's shape {prev.shape}, got {curr.shape}")
    points = _as_points(points, "points")
    if isinstance(window, bool) or not isinstance(window, int) or window < 5 or window % 2 == 0:
        raise ValueError(f"window must be an odd int >= 5, got {window!r}")
    if isinstance(levels, bool) or not isinstance(levels, int) or levels < 0:
        raise ValueError(f"levels must be an int >= 0, got {levels!r}")
    if isinstance(iterations, bool) or not isinstance(iterations, int) or iterations < 1:
        raise ValueError(f"iterations must be an int >= 1, got {iterations!r}")
    if not fb_threshold > 0:
        raise ValueError(f"fb_threshold must be > 0, got {fb_threshold!r}")
    if min_correlation is not None and (
        isinstance(min_correlation, bool) or not -1 <= min_correlation <= 1
    ):
        raise ValueError(f"min_correlation must be None or in [-1, 1], got {min_correlation!r}")
    if isinstance(patch, bool) or not isinstance(patch, int) or patch < 3 or patch % 2 == 0:
        raise ValueError(f"patch must be an odd int >= 3, got {patch!r}")
    count = len(points)
    if count == 0:
        none = None if min_correlation is None else np.zeros(0)
        return Tracks(np.zeros((0, 2)), np.zeros(0, bool), np.zeros(0), none)
    size = (window, window)
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, iterations, 0.01)
    start = points.astype(np.float32).reshape(-1, 1, 2)
    ahead, ok_f, _ = cv2.calcOpticalFlowPyrLK(
        prev, curr, start, start.copy(), winSize=size, maxLevel=levels, criteria=criteria
    )
    back, ok_b, _ = cv2.calcOpticalFlowPyrLK(
        curr, prev, ahead, ahead.copy(), winSize=size, maxLevel=levels, criteria=criteria
    )
    ahead = ahead.reshape(-1, 2).astype(np.float64)
    back = back.reshape(-1, 2).astype(np.float64)
    found = (ok_f.reshape(-1) == 1) & (ok_b.reshape(-1) == 1)
    found &= np.all(np.isfinite(ahead), axis=1) & np.all(np.isfinite(back), axis=1)
    ahead = np.where(found[:, None], ahead, points)
    back = np.where(found[:, None], back, points)
    error = np.where(found, np.linalg.norm(back - points, axis=1), 0.0)
    h, w = prev.shape
    inside = (ahead[:, 0] >= 0) & (ahead[:, 0] <= w - 1)
    inside &= (ahead[:, 1] >= 0) & (ahead[:, 1] <= h - 1)
    valid = found & inside & (error <= fb_threshold)
    correlation = None
    if min_correlation is not None:
        correlation = np.where(valid, _correlation(prev, curr, points, ahead, patch), 0.0)
        valid &= correlation >= min_correlation
    return Tracks(np.where(valid[:, None], ahead, points), valid, error, correlation)


def _correlation(prev, curr, a: np.ndarray, b: np.ndarray, patch: int) -> np.ndarray:
    """`(N,)` the normalised cross-correlation of the `patch` x `patch` neighbourhoods of
    `a` in `prev` and `b` in `curr` (bilinear; 0 where either is flat)."""
    r = np.arange(patch, dtype=np.float64) - patch // 2
    grid = np.stack(np.meshgrid(r, r), axis=-1).reshape(1, -1, 1, 2)  # (1, P, 1, 2)
    x = _read(prev.astype(np.float32), a[:, None, None, :] + grid)  # (N, P)
    y = _read(curr.astype(np.float32), b[:, None, None, :] + grid)
    x -= x.mean(axis=1, keepdims=True)
    y -= y.mean(axis=1, keepdims=True)
    norm = np.sqrt((x * x).sum(axis=1) * (y * y).sum(axis=1))
    return np.where(norm > 1e-9, (x * y).sum(axis=1) / np.maximum(norm, 1e-9), 0.0)


#: The change of the mean grey level between two frames (a fraction of it) above which
#: the last frame is brought to the new one's exposure before the KLT points are followed.
EXPOSURE_STEP = 0.05


def relit(previous: np.ndarray, grey: np.ndarray) -> np.ndarray:
    """`previous` (uint8) with the mean and spread of `grey` where the mean grey level
    changed by more than `EXPOSURE_STEP` (a light switched, an exposure step): Lucas
    and Kanade's flow assumes the grey levels constant, and a frame dimmed by 30% lost
    90% of the points (81 to 8, photo-textured box) and pulled the pose by 1.8 degrees.
    Below it, `previous` as it is (a gradual change: no effect on the points)."""
    a, b = float(previous.mean()), float(grey.mean())
    if abs(b - a) <= EXPOSURE_STEP * max(a, 1.0):
        return previous
    spread = float(previous.std())
    gain = float(grey.std()) / spread if spread > 1e-6 else 1.0
    return np.clip((previous - np.float32(a)) * np.float32(gain) + np.float32(b), 0, 255
                   ).astype(np.uint8)  # fmt: skip
