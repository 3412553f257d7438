"""Points marked on an image grid: the one place where pixels `(x, y)` are rounded to
the pixels they fall on and those outside the image left out (used by corner detection
to keep new corners away from tracked ones, and by recognition for its distance map
to the image vertices).

Plain numpy, not traced.
"""

from __future__ import annotations

import numpy as np

__all__: list[str] = []


def _dots(points: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """`(H, W)` bool, True at the pixel each of `points` `(N, 2)` (x, y) rounds to;
    points outside the image are left out."""
    h, w = shape
    xy = np.round(np.asarray(points, dtype=np.float64).reshape(-1, 2)).astype(np.int64)
    keep = (xy[:, 0] >= 0) & (xy[:, 0] < w) & (xy[:, 1] >= 0) & (xy[:, 1] < h)
    out = np.zeros((h, w), bool)
    out[xy[keep, 1], xy[keep, 0]] = True
    return out
