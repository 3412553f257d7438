"""The tracker's point measurements' containers and, with a textured model, the frame's
ORB keypoints matched to the model's points near their predicted projections (issue #32;
`jaxpose.apps.track`'s `textured`)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ._visibility import face_mask

__all__: list[str] = []


class _Corners(NamedTuple):
    pixels: np.ndarray  # (P, 2) distorted image pixels in the last frame
    model: np.ndarray  # (P, 3)


_NO_CORNERS = _Corners(np.zeros((0, 2)), np.zeros((0, 3)))

#: Candidates (model points projected nearest a keypoint) whose descriptors are compared.
_CANDIDATES = 8
#: Set bits of each byte value (Hamming distances of ORB's binary descriptors).
_POPCOUNT = np.unpackbits(np.arange(256, dtype=np.uint8)[:, None], axis=1).sum(axis=1)


class _Keypoints(NamedTuple):
    """A textured model's keypoint matching per frame: ORB, the model's points and their
    descriptors, the search radius (px) around each point's predicted projection, the
    largest Hamming distance taken and Lowe's ratio among the candidates."""

    orb: object
    points: np.ndarray  # (M, 3)
    descriptors: np.ndarray  # (M, 32) uint8
    radius: float = 10.0
    max_distance: int = 64
    ratio: float = 0.9


def _keypoint_matches(grey8, keys: _Keypoints, geo, K, dist, R, t, size) -> _Corners:
    """The frame's ORB keypoints (inside the model's predicted area) matched to the
    textured model's points whose projection at the predicted pose `(R, t)` lies within
    `keys.radius` of them (the `_CANDIDATES` nearest): each keypoint takes the nearest
    descriptor among those candidates (at most `max_distance` bits, and under `ratio`
    times the second nearest's). Distorted pixels, like the KLT points'."""
    import cv2
    from scipy.spatial import KDTree  # (scipy: installed with jax, which needs it)

    region = face_mask(geo, K, dist, R, t, size, erode=0)
    found, descriptors = keys.orb.detectAndCompute(grey8, region)  # type: ignore[attr-defined]
    if descriptors is None or len(found) == 0:
        return _NO_CORNERS
    pixels = np.array([k.pt for k in found], np.float64)
    X = keys.points @ R.T + t
    front = np.flatnonzero(X[:, 2] > 1e-9)
    if len(front) == 0:
        return _NO_CORNERS
    rvec = cv2.Rodrigues(R)[0]
    proj = cv2.projectPoints(keys.points[front], rvec, t, K, dist)[0].reshape(-1, 2)
    # each keypoint's candidates: the `_CANDIDATES` nearest projections within the radius
    _, near = KDTree(proj).query(pixels, k=_CANDIDATES, distance_upper_bound=keys.radius)
    found_any = near < len(front)  # (Q, k): a candidate (missing ones are len(front))
    train = front[np.minimum(near, len(front) - 1)]
    bits = _POPCOUNT[descriptors[:, None, :] ^ keys.descriptors[train]].sum(axis=2)
    bits = np.where(found_any, bits, 256)
    two = np.partition(bits, 1, axis=1)[:, :2]
    best = np.argmin(bits, axis=1)
    keep = (two[:, 0] <= keys.max_distance) & (two[:, 0] < keys.ratio * two[:, 1])
    chosen = train[np.arange(len(pixels)), best][keep]
    return _Corners(pixels[keep], keys.points[chosen].astype(np.float64))
