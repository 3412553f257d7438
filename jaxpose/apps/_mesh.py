"""Polyhedral models from meshes: PLY files read into a `Polyhedron` and written back.

A PLY file (ASCII, or binary little- or big-endian) lists `vertex` elements with `x y z`
and `face` elements with a `vertex_indices` (or `vertex_index`) list; colours (`red`,
`green`, `blue` on the faces, or else on the vertices, averaged over each face's) become
the model's `face_colours`; other properties and elements are read past. A
triangulated mesh does not list the faces the paper's method sees, so `read_ply`
rebuilds them:

1. faces of zero area are dropped;
2. the faces are oriented consistently (a face and its neighbour across an edge run
   that edge in opposite directions), and each connected part is turned so that its
   signed volume is positive: normals point out of a closed mesh;
3. neighbouring faces in one plane (normals within `angle_tol`, distances within
   `plane_tol` of the mesh's size, and of one colour) are merged, and each merged
   group's boundary, when
   it is one loop, becomes one polygon face, counter-clockwise seen from outside;
4. the polygons' sides are the edges: a box's twelve triangles give six quads and
   twelve edges, without the face diagonals.

Plain numpy, not traced.
"""

from __future__ import annotations

import os
import sys
from collections import deque
from pathlib import Path

import numpy as np

from ..geometry._validate import no_type_check
from ._polyhedron import Polyhedron, polygon_normals

__all__ = ["read_ply", "write_ply"]

#: PLY scalar types and their numpy equivalents.
_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}
_FORMATS = {"ascii": "", "binary_little_endian": "<", "binary_big_endian": ">"}


class _Element:
    """One element of a PLY header: its name, count and properties, each `(name, type)`
    for a scalar or `(name, (count type, item type))` for a list."""

    def __init__(self, name: str, count: int):
        self.name, self.count = name, count
        self.properties: list[tuple[str, str | tuple[str, str]]] = []


def _header(data: bytes, path: Path) -> tuple[str, list[_Element], int]:
    """The format, the elements and the offset of the body."""
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise ValueError(f"path {str(path)!r} is not a PLY file (no 'ply' ... 'end_header')")
    body = data.index(b"\n", end) + 1 if b"\n" in data[end:] else len(data)
    fmt, elements = None, []
    for raw in data[:end].decode("ascii", "replace").splitlines()[1:]:
        words = raw.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        try:
            if words[0] == "format":
                fmt = words[1]
            elif words[0] == "element":
                elements.append(_Element(words[1], int(words[2])))
            elif words[0] == "property" and words[1] == "list":
                elements[-1].properties.append((words[4], (_TYPES[words[2]], _TYPES[words[3]])))
            elif words[0] == "property":
                elements[-1].properties.append((words[2], _TYPES[words[1]]))
        except (IndexError, KeyError, ValueError) as exc:
            raise ValueError(f"path {str(path)!r}: bad PLY header line {raw!r}") from exc
    if fmt not in _FORMATS:
        raise ValueError(f"path {str(path)!r}: unknown PLY format {fmt!r}")
    return fmt, elements, body


def _read_ascii(text: bytes, elements: list[_Element], path: Path) -> dict[str, list]:
    """Each element's rows, each row a dict of property values."""
    words = text.split()
    at, out = 0, {}
    try:
        for el in elements:
            rows = []
            for _ in range(el.count):
                row = {}
                for name, kind in el.properties:
                    if isinstance(kind, tuple):
                        n = int(words[at])
                        row[name] = [float(w) for w in words[at + 1 : at + 1 + n]]
                        if len(row[name]) != n:
                            raise IndexError
                        at += 1 + n
                    else:
                        row[name] = float(words[at])
                        at += 1
                rows.append(row)
            out[el.name] = rows
    except (IndexError, ValueError) as exc:
        raise ValueError(f"path {str(path)!r}: the PLY body is truncated or malformed") from exc
    return out


def _read_binary(
    data: bytes, offset: int, elements: list[_Element], order: str, path: Path
) -> dict[str, list]:
    """As `_read_ascii` for a binary body (byte `order` `<` or `>`); elements without
    lists are read at once."""
    out: dict[str, list] = {}
    try:
        for el in elements:
            if all(not isinstance(kind, tuple) for _, kind in el.properties):
                dtype = np.dtype([(n, order + str(k)) for n, k in el.properties])
                table = np.frombuffer(data, dtype, count=el.count, offset=offset)
                offset += dtype.itemsize * el.count
                out[el.name] = [{n: float(r[n]) for n, _ in el.properties} for r in table]
                continue
            rows = []
            for _ in range(el.count):
                row = {}
                for name, kind in el.properties:
                    if isinstance(kind, tuple):
                        head = np.dtype(order + kind[0])
                        n = int(np.frombuffer(data, head, count=1, offset=offset)[0])
                        offset += head.itemsize
                        item = np.dtype(order + kind[1])
                        row[name] = np.frombuffer(data, item, count=n, offset=offset).tolist()
                        offset += item.itemsize * n
                    else:
                        scalar = np.dtype(order + kind)
                        row[name] = float(np.frombuffer(data, scalar, count=1, offset=offset)[0])
                        offset += scalar.itemsize
                rows.append(row)
            out[el.name] = rows
    except ValueError as exc:
        raise ValueError(f"path {str(path)!r}: the PLY body is truncated") from exc
    return out


def _vector_area(p: np.ndarray) -> np.ndarray:
    """Twice the vector area of a polygon `(k, 3)` (Newell's sum: its normal times twice
    its area, for any simple planar polygon)."""
    return np.cross(p, np.roll(p, -1, axis=0)).sum(axis=0)


def _sides(face: list[int]) -> list[tuple[int, int]]:
    """A face's directed sides, in order."""
    return list(zip(face, face[1:] + face[:1], strict=True))


def _neighbours(faces: list[list[int]]) -> dict[tuple[int, int], list[int]]:
    """The faces on each undirected edge `(low, high)`."""
    edges: dict[tuple[int, int], list[int]] = {}
    for i, face in enumerate(faces):
        for u, v in _sides(face):
            edges.setdefault((min(u, v), max(u, v)), []).append(i)
    return edges


def _orient(vertices: np.ndarray, faces: list[list[int]], edges) -> list[list[int]]:
    """The faces turned to run consistently across manifold edges (a face and its
    neighbour run their common side in opposite directions), each connected part then
    turned so that its signed volume is positive."""
    faces = [list(f) for f in faces]
    part = [-1] * len(faces)
    for seed in range(len(faces)):
        if part[seed] >= 0:
            continue
        part[seed] = seed
        queue = deque([seed])
        while queue:
            i = queue.popleft()
            for u, v in _sides(faces[i]):
                shared = edges[(min(u, v), max(u, v))]
                if len(shared) != 2 or shared[0] == shared[1]:
                    continue
                j = shared[0] if shared[1] == i else shared[1]
                if part[j] >= 0:
                    continue
                if (u, v) in _sides(faces[j]):
                    faces[j] = faces[j][::-1]
                part[j] = seed
                queue.append(j)
    volume: dict[int, float] = {}
    for i, face in enumerate(faces):
        p = vertices[face]
        volume[part[i]] = volume.get(part[i], 0.0) + float(_vector_area(p) @ p[0])
    return [f[::-1] if volume[part[i]] < 0 else f for i, f in enumerate(faces)]


def _loops(directed: list[tuple[int, int]]) -> list[list[int]] | None:
    """The closed loops of directed edges, or None when they do not form simple loops
    (a vertex left twice)."""
    following: dict[int, int] = {}
    for u, v in directed:
        if u in following:
            return None
        following[u] = v
    loops, seen = [], set()
    for start in sorted(following):
        if start in seen:
            continue
        loop, v = [], start
        while v not in seen:
            seen.add(v)
            loop.append(v)
            if v not in following:
                return None
            v = following[v]
        if v != start:
            return None
        loops.append(loop)
    return loops


def _polygons(
    vertices: np.ndarray,
    faces: list[list[int]],
    angle_tol: float,
    plane_tol: float,
    colours: np.ndarray | None = None,
) -> tuple[list[tuple[int, ...]], np.ndarray | None]:
    """The faces of a mesh with coplanar neighbours of one colour merged into polygons
    (see the module docstring), each starting at its smallest vertex index, in the order
    of their first face in the file; and their colours (`colours`: one per face)."""
    edges = _neighbours(faces)
    faces = _orient(vertices, faces, edges)
    normals = polygon_normals(vertices, faces)
    offsets = np.array([n @ vertices[f].mean(axis=0) for n, f in zip(normals, faces)])
    scale = max(float(np.ptp(vertices, axis=0).max()), sys.float_info.min)
    parent = list(range(len(faces)))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    cos_tol = np.cos(angle_tol)
    for shared in edges.values():
        if len(shared) != 2:
            continue
        i, j = shared
        same_plane = abs(offsets[i] - offsets[j]) <= plane_tol * scale
        same_colour = colours is None or np.array_equal(colours[i], colours[j])
        if normals[i] @ normals[j] >= cos_tol and same_plane and same_colour:
            parent[root(i)] = root(j)
    groups: dict[int, list[int]] = {}
    for i in range(len(faces)):
        groups.setdefault(root(i), []).append(i)
    out, kept = [], []
    for members in sorted(groups.values(), key=min):
        directed = {side for i in members for side in _sides(faces[i])}
        boundary = [(u, v) for u, v in sorted(directed) if (v, u) not in directed]
        loops = _loops(boundary)
        if loops is not None and len(loops) == 1 and len(loops[0]) >= 3:
            chosen = [loops[0]]
        else:  # a hole or a pinched boundary: the faces as they are
            chosen = [faces[i] for i in members]
        for loop in chosen:
            k = int(np.argmin(loop))
            out.append(tuple(loop[k:] + loop[:k]))
            kept.append(members[0])
    return out, None if colours is None else colours[kept]


def _face_edges(faces) -> np.ndarray:
    """The polygons' sides, `(E, 2)` int32, each `(low, high)`, sorted and unique."""
    sides = {(min(a, b), max(a, b)) for f in faces for a, b in zip(f, f[1:] + f[:1], strict=True)}
    return np.array(sorted(sides), dtype=np.int32).reshape(-1, 2)


@no_type_check
def read_ply(
    path: str | os.PathLike,
    name: str | None = None,
    *,
    merge: bool = True,
    angle_tol: float = 1e-6,
    plane_tol: float = 1e-6,
) -> Polyhedron:
    """Read a PLY mesh as a `Polyhedron` (see the module docstring).

    **Arguments:**
    - `path`: an ASCII or binary PLY file with `vertex` (`x`, `y`, `z`) and `face`
      (`vertex_indices` or `vertex_index` lists) elements.
    - `name`: the model's name (`None`: the file's name without its extension).
    - `merge`: merge coplanar neighbouring triangles into polygons (default); `False`
      keeps the file's faces as they are (their order and their sides as edges).
    - `angle_tol`: largest angle (radians) between the normals of merged triangles.
    - `plane_tol`: largest difference of their planes' distances to the origin, as a
      fraction of the mesh's largest extent.

    **Returns:** a `Polyhedron`: `vertices` `(V, 3)` float64 in the file's units, faces
    counter-clockwise seen from outside (with `merge`), `edges` the faces' sides.

    **Raises:** `ValueError` naming the path for an unreadable or malformed file.
    """
    if not isinstance(path, str | os.PathLike):
        raise ValueError(f"path must be a str or a path, got {type(path).__name__}")
    if name is not None and not isinstance(name, str):
        raise ValueError(f"name must be a str or None, got {type(name).__name__}")
    for label, tol in (("angle_tol", angle_tol), ("plane_tol", plane_tol)):
        if isinstance(tol, bool) or not isinstance(tol, int | float) or not 0 <= tol < 1:
            raise ValueError(f"{label} must be a number in [0, 1), got {tol!r}")
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ValueError(f"path {str(path)!r} could not be read: {exc}") from exc
    fmt, elements, body = _header(data, path)
    if fmt == "ascii":
        table = _read_ascii(data[body:], elements, path)
    else:
        table = _read_binary(data, body, elements, _FORMATS[fmt], path)
    rows = table.get("vertex")
    if not rows or any(c not in rows[0] for c in "xyz"):
        raise ValueError(f"path {str(path)!r}: no vertex element with x, y, z")
    vertices = np.array([[r["x"], r["y"], r["z"]] for r in rows], dtype=np.float64)
    if not np.all(np.isfinite(vertices)):
        raise ValueError(f"path {str(path)!r}: vertices contain NaN or infinite values")
    faces: list[list[int]] = []
    for r in table.get("face", []):
        key = "vertex_indices" if "vertex_indices" in r else "vertex_index"
        if key not in r:
            raise ValueError(f"path {str(path)!r}: faces without a vertex_indices list")
        faces.append([int(i) for i in r[key]])
    stem = path.name.removesuffix(".ply").removesuffix(".PLY")
    colours = _colours(table, faces, len(vertices), path)
    return _assemble(stem if name is None else name, vertices, faces, [], merge=merge,
                     orient=False, angle_tol=angle_tol, plane_tol=plane_tol, path=path,
                     drop_flat=merge, colours=colours)  # fmt: skip


_RGB = ("red", "green", "blue")


def _colours(table: dict[str, list], faces: list[list[int]], count: int, path: Path):
    """One RGB colour per face, `(F, 3)` float64: the faces' own `red green blue`, or
    else the mean of their vertices'; None where the file has neither."""
    for element in ("face", "vertex"):
        rows = table.get(element)
        if rows and all(c in rows[0] for c in _RGB):
            rgb = np.array([[r[c] for c in _RGB] for r in rows], np.float64)
            if not np.all(np.isfinite(rgb)):
                raise ValueError(f"path {str(path)!r}: colours contain NaN or infinite values")
            if element == "face":
                return rgb
            if len(rgb) != count:
                return None
            return np.array([rgb[f].mean(axis=0) for f in faces]).reshape(-1, 3)
    return None


def _assemble(
    name: str,
    vertices: np.ndarray,
    faces: list[list[int]],
    lines: list[tuple[int, int]],
    *,
    merge: bool,
    orient: bool,
    angle_tol: float,
    plane_tol: float,
    path: Path,
    drop_flat: bool = True,
    colours: np.ndarray | None = None,
) -> Polyhedron:
    """A `Polyhedron` from vertices, faces and extra edges (the one builder of the mesh
    readers: PLY, OBJ, CAO): indices checked, faces of no area dropped (`drop_flat`),
    merged into polygons (`merge`) or only oriented (`orient`), edges the faces' sides
    and `lines`; `colours`, one per face, carried to the polygons."""
    if len(vertices) == 0:
        raise ValueError(f"path {str(path)!r}: no vertices")
    if not np.all(np.isfinite(vertices)):
        raise ValueError(f"path {str(path)!r}: vertices contain NaN or infinite values")
    count = len(vertices)
    if any(len(f) < 3 or min(f) < 0 or max(f) >= count for f in faces):
        raise ValueError(f"path {str(path)!r}: a face has under 3 vertices or a bad index")
    if any(min(a, b) < 0 or max(a, b) >= count for a, b in lines):
        raise ValueError(f"path {str(path)!r}: a line has a bad vertex index")
    if drop_flat:
        extent = max(float(np.ptp(vertices, axis=0).max()), sys.float_info.min)
        solid = [np.linalg.norm(_vector_area(vertices[f])) > 1e-12 * extent**2 for f in faces]
        faces = [f for f, keep in zip(faces, solid, strict=True) if keep]
        colours = None if colours is None else colours[np.asarray(solid, bool)]
    if merge and faces:
        polygons, colours = _polygons(vertices, faces, angle_tol, plane_tol, colours)
    elif orient and faces:
        polygons = [tuple(f) for f in _orient(vertices, faces, _neighbours(faces))]
    else:
        polygons = [tuple(f) for f in faces]
    sides = _face_edges(polygons)
    extra = np.array([(min(a, b), max(a, b)) for a, b in lines if a != b], np.int32)
    edges = np.unique(np.vstack([sides, extra.reshape(-1, 2)]), axis=0).astype(np.int32)
    return Polyhedron(name=name, vertices=vertices, edges=edges, faces=tuple(polygons),
                      face_colours=colours)  # fmt: skip


@no_type_check
def write_ply(path: str | os.PathLike, model: Polyhedron, *, binary: bool = False) -> None:
    """Write a `Polyhedron` as a PLY file (`read_ply` reads it back): vertices as
    doubles, its polygon faces as `vertex_indices` lists (its edges are the faces'
    sides, so they are not written), with their `red green blue` (uchar) where the model
    has `face_colours`.

    **Arguments:**
    - `path`: the file.
    - `model`: a `Polyhedron`.
    - `binary`: binary little-endian instead of ASCII.

    **Raises:** `ValueError` naming the argument.
    """
    if not isinstance(path, str | os.PathLike):
        raise ValueError(f"path must be a str or a path, got {type(path).__name__}")
    if not isinstance(model, Polyhedron):
        raise ValueError(f"model must be a Polyhedron, got {type(model).__name__}")
    vertices = np.asarray(model.vertices, dtype=np.float64).reshape(-1, 3)
    faces = [tuple(int(i) for i in f) for f in model.faces]
    count = "uchar" if all(len(f) < 256 for f in faces) else "int"
    rgb = None
    if model.face_colours is not None:
        rgb = np.clip(np.round(np.asarray(model.face_colours, np.float64)), 0, 255)
        if rgb.shape != (len(faces), 3):
            raise ValueError(f"model.face_colours must be (F, 3), got {rgb.shape}")
        rgb = rgb.astype(np.uint8)
    header = "\n".join(
        [
            "ply",
            f"format {'binary_little_endian' if binary else 'ascii'} 1.0",
            f"comment {' '.join(str(model.name).split())}",
            f"element vertex {len(vertices)}",
            "property double x",
            "property double y",
            "property double z",
            f"element face {len(faces)}",
            f"property list {count} int vertex_indices",
            *([] if rgb is None else [f"property uchar {c}" for c in _RGB]),
            "end_header",
            "",
        ]
    ).encode("ascii")
    if binary:
        parts = [header, vertices.astype("<f8").tobytes()]
        for k, f in enumerate(faces):
            parts.append(np.array([len(f)], "<" + _TYPES[count]).tobytes())
            parts.append(np.array(f, "<i4").tobytes())
            if rgb is not None:
                parts.append(rgb[k].tobytes())
        body = b"".join(parts)
    else:
        lines = [" ".join(repr(float(x)) for x in v) for v in vertices]
        lines += [" ".join(str(i) for i in (len(f), *f, *([] if rgb is None else rgb[k])))
                  for k, f in enumerate(faces)]  # fmt: skip
        body = header + ("\n".join(lines) + "\n").encode("ascii")
    try:
        Path(path).write_bytes(body)
    except OSError as exc:
        raise ValueError(f"path {str(path)!r} could not be written: {exc}") from exc
