"""A model's half-turn symmetries and near twins (issue #32's tracker): half-turns about
its principal axes that map its vertices onto themselves (a box's three: its edges alone
cannot tell them apart) or nearly (the bench's cross prism: recognition from the edges
may return the twin, whose edges fit the image a few pixels off). A model with face
colours tells its twins apart by them (`by_colour`)."""

from __future__ import annotations

import numpy as np

from ._visibility import MeshGeometry, face_labels

__all__ = ["NEAR_TWIN", "by_colour", "symmetries", "turned"]


def symmetries(geo: MeshGeometry, within: float = 1e-6) -> list[tuple[np.ndarray, np.ndarray]]:
    """The model's half-turn symmetries about its principal axes through its vertex
    centroid `c`, as `(S, c)` with `S (m - c) + c` mapping the vertices onto themselves
    (a box has three: seen by its edges alone, each is the same object), each vertex to
    within `within` times the model's largest extent of one (`NEAR_TWIN`: the near ones
    too). None for models of over 4,000 vertices (not searched)."""
    vertices = np.asarray(geo.model.vertices, np.float64)
    if len(vertices) > 4000 or len(vertices) < 3:
        return []
    c = vertices.mean(axis=0)
    X = vertices - c
    tol = within * max(float(np.ptp(vertices, axis=0).max()), 1e-300)
    out = []
    for axis in np.linalg.eigh(X.T @ X)[1].T:
        S = 2 * np.outer(axis, axis) - np.eye(3)
        moved = X @ S.T
        if all(np.linalg.norm(X[None] - moved[i : i + 256, None], axis=2).min(axis=1).max()
               <= tol for i in range(0, len(X), 256)):  # fmt: skip
            out.append((S, c))
    return out


#: A half-turn that maps every vertex within this fraction of the model's extent of one
#: makes a near twin (`symmetries(geo, NEAR_TWIN)`): the bench's cross prism is one about
#: each of its axes (its vertices mapped within 1.5 mm about its long in-plane axis, 5.4 mm
#: about the others, on a 155 mm span). Recognition from the edges may return the twin;
#: its edges fit the image a pixel or two off.
NEAR_TWIN = 0.1


def turned(R: np.ndarray, t: np.ndarray, S: np.ndarray, c: np.ndarray) -> tuple:
    """The pose `(R, t)` of the model turned by its symmetry `(S, c)` (`symmetries`):
    `R S` and `t + R (c - S c)`, so that each vertex lands where its image under the
    turn was."""
    return R @ S, t + R @ (c - S @ c)


#: Pixels taken off each face's area before its grey level is read (`by_colour`): its
#: edges, blurred or a pixel off, are left out.
FACE_INSET = 3

#: The fewest pixels a face shows, after `FACE_INSET`, for `by_colour` to read it.
FACE_PIXELS = 30


def by_colour(grey: np.ndarray, geo: MeshGeometry, K, dist, poses: list[tuple]) -> int:
    """Of `poses` (a pose and its twins: each shows the same faces' outlines), the index
    of the one whose faces' colours agree best with the frame's grey levels; 0 where the
    model has no `face_colours` or no pose agrees better than the first.

    Each face the pose shows (over `FACE_PIXELS` pixels, `FACE_INSET` in from its
    border) is read as the median grey of the frame there; a pose scores, over the pairs
    of faces it shows, the order of their greys weighted by how far apart the model's
    greys are (`sum sign(g_i - g_j) (c_i - c_j)`, `c` the faces' colours as grey). Only
    the order counts: whatever the lighting's gain and offset, and most clutter and
    occlusion (medians), the right pose scores highest.
    """
    import cv2

    colours = geo.model.face_colours
    if colours is None or len(poses) < 2:
        return 0
    tone = np.asarray(colours, np.float64) @ np.array([0.299, 0.587, 0.114])
    size = (grey.shape[1], grey.shape[0])
    kernel = np.ones((2 * FACE_INSET + 1, 2 * FACE_INSET + 1), np.uint8)
    scores = []
    for R, t in poses:
        labels = face_labels(geo, K, dist, R, t, size)
        seen, levels = [], []
        for f in np.unique(labels[labels >= 0]):
            inside = cv2.erode((labels == f).astype(np.uint8), kernel).astype(bool)
            if np.count_nonzero(inside) >= FACE_PIXELS:
                seen.append(f)
                levels.append(float(np.median(grey[inside])))
        c, g = tone[seen], np.array(levels)
        scores.append(float(np.sum(np.sign(g[:, None] - g[None]) * (c[:, None] - c[None]))) / 2)
    best = int(np.argmax(scores))
    return best if scores[best] > scores[0] else 0
