"""Polyhedral models and their numpy geometry: the `Polyhedron` type, right prisms,
face normals, and the vertices a camera sees.

A `Polyhedron` lists its faces counter-clockwise seen from outside, so that the
right-hand normal points out. The functions here are plain numpy: they build data and
draw, they are not traced (`jaxpose.apps._pointing` holds the JAX counterparts used
under `jit`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ["Polyhedron", "polygon_normals", "prism", "seen_vertices"]


@dataclasses.dataclass(frozen=True)
class Polyhedron:
    """A polyhedral model: vertices `(V, 3)`, edges `(E, 2)` and faces (lists of indices,
    counter-clockwise seen from outside, so that the right-hand normal points out);
    `face_colours`, where the model has them (a PLY file's face or vertex colours), one
    RGB colour per face, `(F, 3)` in 0..255, else None."""

    name: str
    vertices: np.ndarray
    edges: np.ndarray
    faces: tuple[tuple[int, ...], ...]
    face_colours: np.ndarray | None = None


def prism(name: str, outline: np.ndarray, thickness: float) -> Polyhedron:
    """A right prism over a simple polygon `outline` `(k, 2)` (counter-clockwise seen from
    +z): vertices `0..k-1` on the top face `z = +thickness / 2`, `k..2k-1` below them;
    edges: the top ring, the bottom ring, then the `k` vertical edges; faces: the top,
    the bottom, then the `k` sides."""
    outline = np.asarray(outline, dtype=np.float64)
    k = len(outline)
    top = np.column_stack([outline, np.full(k, thickness / 2)])
    bottom = np.column_stack([outline, np.full(k, -thickness / 2)])
    ring = [(i, (i + 1) % k) for i in range(k)]
    edges = [(a, b) for a, b in ring] + [(a + k, b + k) for a, b in ring]
    edges += [(i, i + k) for i in range(k)]
    faces = [tuple(range(k)), tuple(range(2 * k - 1, k - 1, -1))]
    faces += [(a, a + k, b + k, b) for a, b in ring]
    return Polyhedron(
        name=name,
        vertices=np.vstack([top, bottom]),
        edges=np.asarray(edges, dtype=np.int32),
        faces=tuple(faces),
    )


def polygon_normals(vertices: np.ndarray, faces) -> np.ndarray:
    """Unit normals `(F, 3)` of polygon faces by Newell's method (exact for planar
    polygons, convex or not; a best fit for non-planar ones): outward for faces listed
    counter-clockwise seen from outside; zero for a face of zero area.

    **Arguments:** `vertices` `(V, 3)` (e.g. a `Polyhedron`'s, posed in the world);
    `faces`: index sequences into `vertices`.
    """
    normals = []
    for face in faces:
        p = vertices[list(face)]
        q = np.roll(p, -1, axis=0)
        n = np.sum(np.cross(p, q), axis=0)
        normals.append(n / max(np.linalg.norm(n), 1e-300))
    return np.array(normals).reshape(-1, 3)


def _inside_many(points: np.ndarray, polygon: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Even-odd test of points `(P, 3)` in the plane of a 3D polygon (projected along its
    normal's largest axis): `(P,)` bool."""
    keep = [i for i in range(3) if i != int(np.argmax(np.abs(normal)))]
    x, y = points[:, keep[0], None], points[:, keep[1], None]
    px, py = polygon[None, :, keep[0]], polygon[None, :, keep[1]]
    qx, qy = np.roll(px, -1, axis=1), np.roll(py, -1, axis=1)
    crosses = (py > y) != (qy > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        at = px + (y - py) * (qx - px) / (qy - py)
    return np.sum(crosses & (x < at), axis=1) % 2 == 1


def seen_vertices(
    model: Polyhedron, R: np.ndarray, t: np.ndarray, centre: np.ndarray
) -> np.ndarray:
    """Indices of the vertices a camera at `centre` sees when the model is at `(R, t)`
    (model to world): on a face turned towards the camera and not hidden behind another
    such face (the test that non-convex models need).

    **Returns:** the sorted vertex indices, int64.
    """
    world = model.vertices @ np.asarray(R).T + np.asarray(t)
    normals = polygon_normals(world, model.faces)
    front = [i for i, f in enumerate(model.faces) if normals[i] @ (centre - world[f[0]]) > 0]
    candidates = np.array(sorted({v for i in front for v in model.faces[i]}), dtype=np.int64)
    hidden = np.zeros(len(candidates), dtype=bool)
    rays = world[candidates] - centre
    for i in front:
        face = list(model.faces[i])
        n = normals[i]
        den = rays @ n
        ok = (np.abs(den) >= 1e-12) & ~np.isin(candidates, face)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(ok, n @ (world[face[0]] - centre) / np.where(ok, den, 1), 0)
        ok &= (s > 1e-9) & (s < 1 - 1e-9)
        if not ok.any():
            continue
        hits = centre + s[ok, None] * rays[ok]
        hidden[np.flatnonzero(ok)[_inside_many(hits, world[face], n)]] = True
    return candidates[~hidden]
