r"""A detection's pose refined on its edges as well as its vertices.

Vertices are few (a box shows at most seven) and a real corner is rarely sharp; edges are
long and well measured. Each seen model edge, projected at the current pose, takes the
detected segments that lie along it (direction within `angle` degrees, both end points
within `distance` px of its line, overlapping its extent); every such end point `q`
gives the residual $n^\top (q - a)$, its signed distance to the projected edge through
`a` with unit normal `n`. With the matched vertices' pixel residuals, the pose
minimising the sum of squares is found by Gauss-Newton steps on a rotation vector and a
translation (six parameters: central differences for the Jacobian); the segments are
associated again from the new pose, `rounds` times, with the distance halved after the
first. Camera frame throughout (`x_cam = R m + t`, pixels through `K`).
"""

from __future__ import annotations

import math

import numpy as np

from ._polyhedron import Polyhedron, seen_vertices

__all__ = ["project_vertices", "refine_on_edges"]


def _rotations(w: np.ndarray) -> np.ndarray:
    """Rodrigues' formula for rotation vectors `w` `(k, 3)`: the matrices `(k, 3, 3)`."""
    w = np.asarray(w, np.float64)
    theta = np.linalg.norm(w, axis=1)
    small = theta < 1e-12
    axis = w / np.where(small, 1.0, theta)[:, None]
    c, s = np.cos(theta), np.sin(theta)
    x, y, z = axis.T
    zero = np.zeros_like(x)
    cross = np.stack([zero, -z, y, z, zero, -x, -y, x, zero], axis=1).reshape(-1, 3, 3)
    outer = axis[:, :, None] * axis[:, None, :]
    R = c[:, None, None] * np.eye(3) + (1 - c)[:, None, None] * outer
    R = R + s[:, None, None] * cross
    return np.where(small[:, None, None], np.eye(3), R)


def _project_poses(K, R, t, x) -> np.ndarray:
    """`project_vertices` at `k` poses at once: `R` `(k, 3, 3)`, `t` `(k, 3)`, `x`
    `(n, 3)`; pixels `(k, n, 2)`."""
    uv = (np.einsum("kij,nj->kni", R, x) + t[:, None, :]) @ K.T
    return uv[..., :2] / np.where(np.abs(uv[..., 2:]) > 1e-12, uv[..., 2:], 1e-12)


def project_vertices(K, R, t, x) -> np.ndarray:
    """Pixels `(n, 2)` of points `x` `(n, 3)` at camera-frame pose `(R, t)` through `K`."""
    uv = (np.asarray(x) @ R.T + t) @ K.T
    return uv[:, :2] / np.where(np.abs(uv[:, 2:]) > 1e-12, uv[:, 2:], 1e-12)


def _associate(uv, edges, ends, distance: float, angle: float):
    """`(edge, end point)` pairs: the end points of the segments lying along each
    projected edge."""
    cos_tol = math.cos(math.radians(angle))
    d = ends[:, 1] - ends[:, 0]
    length = np.linalg.norm(d, axis=1)
    unit = d / np.maximum(length, 1e-12)[:, None]
    rows = []
    for e, (a, b) in enumerate(edges):
        axis = uv[b] - uv[a]
        span = float(np.linalg.norm(axis))
        if span < 1e-9:
            continue
        axis = axis / span
        normal = np.array([-axis[1], axis[0]])
        off = (ends - uv[a]) @ normal  # (S, 2)
        along = (ends - uv[a]) @ axis
        keep = (
            (np.abs(unit @ axis) >= cos_tol)
            & np.all(np.abs(off) <= distance, axis=1)
            & (np.max(along, axis=1) >= 0)
            & (np.min(along, axis=1) <= span)
            & (length > 0)
        )
        for s in np.flatnonzero(keep):
            rows.extend((e, q) for q in ends[s])
    return rows


def refine_on_edges(
    K: np.ndarray,
    R: np.ndarray,
    t: np.ndarray,
    model: Polyhedron,
    vertices: np.ndarray,
    pixels: np.ndarray,
    ends: np.ndarray,
    *,
    distance: float = 3.0,
    angle: float = 5.0,
    min_edge: float = 10.0,
    rounds: int = 3,
    steps: int = 5,
) -> tuple[np.ndarray, np.ndarray]:
    """The camera-frame pose `(R, t)` refined on the matched `vertices` (model indices, at
    image `pixels`) and on the detected segments `ends` `(S, 2, 2)` along the seen model
    edges (see the module docstring). A step is taken only when it lowers the sum of
    squares and leaves the model in front of the camera."""
    verts = np.asarray(model.vertices, np.float64)
    R, t = np.asarray(R, np.float64), np.asarray(t, np.float64)
    ends = np.asarray(ends, np.float64).reshape(-1, 2, 2)
    vertices = np.asarray(vertices, np.int64)
    pixels = np.asarray(pixels, np.float64).reshape(-1, 2)
    for r in range(rounds):
        seen = set(seen_vertices(model, R, t, np.zeros(3)).tolist())
        uv = project_vertices(K, R, t, verts)
        edges = [
            (int(a), int(b))
            for a, b in np.asarray(model.edges)
            if int(a) in seen and int(b) in seen and np.linalg.norm(uv[b] - uv[a]) >= min_edge
        ]
        pairs = _associate(uv, edges, ends, distance if r == 0 else distance / 2, angle)
        if not pairs:
            break
        which = np.array([edges[e] for e, _ in pairs])
        points = np.array([q for _, q in pairs])

        def residuals(P, R0=R, t0=t, which=which, points=points):
            """The residuals `(k, m)` at the parameters `P` `(k, 6)`, all at once."""
            Rp, tp = _rotations(P[:, :3]) @ R0, t0 + P[:, 3:]
            a = _project_poses(K, Rp, tp, verts[which[:, 0]])
            b = _project_poses(K, Rp, tp, verts[which[:, 1]])
            axis = b - a
            axis = axis / np.maximum(np.linalg.norm(axis, axis=2, keepdims=True), 1e-12)
            normal = np.stack([-axis[..., 1], axis[..., 0]], axis=2)
            line = np.sum((points - a) * normal, axis=2)
            corner = (_project_poses(K, Rp, tp, verts[vertices]) - pixels).reshape(len(P), -1)
            return np.concatenate([line, corner], axis=1)

        p = np.zeros(6)
        h = np.array([1e-6] * 3 + [1e-6 * max(float(np.linalg.norm(t)), 1.0)] * 3)
        # the point and its 12 central-difference neighbours, evaluated together
        offsets = np.concatenate([np.zeros((1, 6)), np.diag(h), -np.diag(h)])
        for _ in range(steps):
            F = residuals(p + offsets)
            f = F[0]
            J = ((F[1:7] - F[7:13]) / (2 * h[:, None])).T
            dp = np.linalg.lstsq(J, -f, rcond=None)[0]
            if not np.all(np.isfinite(dp)):
                break
            if np.sum(residuals((p + dp)[None])[0] ** 2) >= np.sum(f**2):
                break
            p = p + dp
        R_new, t_new = _rotations(p[None, :3])[0] @ R, t + p[3:]
        if not np.all(verts @ R_new[2] + t_new[2] > 0):
            break
        R, t = R_new, t_new
    return R, t
