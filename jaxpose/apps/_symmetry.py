"""A model's half-turn symmetries and near twins (issue #32's tracker): half-turns about
its principal axes that map its vertices onto themselves (a box's three: its edges alone
cannot tell them apart) or nearly (the bench's cross prism: recognition from the edges
may return the twin, whose edges fit the image a few pixels off)."""

from __future__ import annotations

import numpy as np

from ._visibility import MeshGeometry

__all__ = ["NEAR_TWIN", "symmetries", "turned"]


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
