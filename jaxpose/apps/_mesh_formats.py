"""Polyhedral models from Wavefront OBJ and ViSP `.cao` files, and one reader for the
three mesh formats (`read_mesh`: PLY, OBJ, CAO by the file's suffix).

**OBJ.** `v x y z [w]` lines are vertices; `f` lines faces, each corner `i`, `i/t`,
`i/t/n` or `i//n` with 1-based indices (negative ones count back from the last vertex
read); `l` lines are polylines, kept as edges. Materials give the faces their colours
(`face_colours`: a material's diffuse colour `Kd`, from the `mtllib` files beside the
OBJ, for the faces after its `usemtl`) where every face has one. Other statements
(normals, texture coordinates, groups) are read past. Faces are then rebuilt as
`read_ply` rebuilds them (coplanar neighbours of one colour merged into polygons,
oriented outward).

**CAO** (the CAD format of ViSP's model-based tracker, as its tutorial describes it):
text sections, each a count followed by that many rows, `#` starting a comment:
an optional `V1` line; 3D points (`X Y Z`); 3D lines (two point indices); faces from
3D lines (a count then line indices); faces from 3D points (a count then point indices,
counter-clockwise seen from outside); 3D cylinders (two point indices and a radius) and
3D circles (a radius and three point indices). Rows may end with `name=value`
parameters, which are read past. Cylinders and circles are not polyhedral: they are
read past (`curved="skip"`, the default) or refused (`curved="error"`). `load(...)` lines
(hierarchical models) are not supported.

Plain numpy, not traced.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..geometry._validate import no_type_check
from ._mesh import _assemble, read_ply
from ._polyhedron import Polyhedron

__all__ = ["read_cao", "read_mesh", "read_obj"]


def _as_path(path: object) -> Path:
    if not isinstance(path, str | os.PathLike):
        raise ValueError(f"path must be a str or a path, got {type(path).__name__}")
    return Path(path)


def _read_text(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise ValueError(f"path {str(path)!r} could not be read: {exc}") from exc


def _check_tol(angle_tol: float, plane_tol: float) -> None:
    for label, tol in (("angle_tol", angle_tol), ("plane_tol", plane_tol)):
        if isinstance(tol, bool) or not isinstance(tol, int | float) or not 0 <= tol < 1:
            raise ValueError(f"{label} must be a number in [0, 1), got {tol!r}")


def _check_name(name: object) -> None:
    if name is not None and not isinstance(name, str):
        raise ValueError(f"name must be a str or None, got {type(name).__name__}")


def _build(
    path: Path,
    name: str | None,
    vertices,
    faces: list[list[int]],
    lines: list[tuple[int, int]],
    **options,
) -> Polyhedron:
    """The model read from `path`, named `name` or after the file (its name without
    its suffix), built by the mesh readers' one builder (`_mesh._assemble`)."""
    stem = path.name[: -len(path.suffix)] if path.suffix else path.name
    vertices = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    return _assemble(stem if name is None else name, vertices, faces, lines, path=path,
                     **options)  # fmt: skip


def _obj_index(word: str, count: int, path: Path, line: int) -> int:
    try:
        i = int(word.split("/")[0])
    except ValueError as exc:
        raise ValueError(f"path {str(path)!r}: line {line}: bad index {word!r}") from exc
    if i == 0:
        raise ValueError(f"path {str(path)!r}: line {line}: OBJ indices start at 1")
    return i - 1 if i > 0 else count + i


@no_type_check
def read_obj(
    path: str | os.PathLike,
    name: str | None = None,
    *,
    merge: bool = True,
    angle_tol: float = 1e-6,
    plane_tol: float = 1e-6,
) -> Polyhedron:
    """Read a Wavefront OBJ mesh as a `Polyhedron` (see the module docstring).

    **Arguments:**
    - `path`: the `.obj` file.
    - `name`: the model's name (`None`: the file's name without its suffix).
    - `merge`, `angle_tol`, `plane_tol`: as for `read_ply` (coplanar neighbouring faces
      merged into polygons, normals within `angle_tol` radians, planes within
      `plane_tol` of the mesh's largest extent).

    **Returns:** a `Polyhedron` in the file's units; `l` polylines add edges; its
    `face_colours` from the materials where every face has one with a `Kd`.

    **Raises:** `ValueError` naming the path for an unreadable or malformed file.
    """
    path = _as_path(path)
    _check_name(name)
    _check_tol(angle_tol, plane_tol)
    vertices: list[list[float]] = []
    faces: list[list[int]] = []
    lines: list[tuple[int, int]] = []
    diffuse: dict[str, list[float]] = {}  # the materials' Kd, 0..255
    material: list[float] | None = None
    colours: list[list[float] | None] = []
    for number, raw in enumerate(_read_text(path).splitlines(), start=1):
        words = raw.split("#", 1)[0].split()
        if not words:
            continue
        if words[0] == "v":
            try:
                xyz = [float(w) for w in words[1:4]]
            except ValueError as exc:
                raise ValueError(f"path {str(path)!r}: line {number}: bad vertex") from exc
            if len(xyz) != 3:
                raise ValueError(f"path {str(path)!r}: line {number}: a vertex needs x y z")
            vertices.append(xyz)
        elif words[0] == "f":
            faces.append([_obj_index(w, len(vertices), path, number) for w in words[1:]])
            colours.append(material)
        elif words[0] == "mtllib":
            for library in words[1:]:
                diffuse |= _read_mtl(path.parent / library)
        elif words[0] == "usemtl":
            material = diffuse.get(" ".join(words[1:]))
        elif words[0] == "l":
            chain = [_obj_index(w, len(vertices), path, number) for w in words[1:]]
            lines.extend(zip(chain[:-1], chain[1:], strict=True))
    coloured = bool(faces) and all(c is not None for c in colours)
    return _build(path, name, vertices, faces, lines, merge=merge, orient=True,
                  angle_tol=angle_tol, plane_tol=plane_tol,
                  colours=np.array(colours, np.float64) if coloured else None)  # fmt: skip


def _read_mtl(path: Path) -> dict[str, list[float]]:
    """The diffuse colours (`Kd`, 0..1, as 0..255) of the materials of an MTL file; none
    where the file cannot be read."""
    try:
        text = _read_text(path)
    except ValueError:
        return {}
    out, name = {}, None
    for raw in text.splitlines():
        words = raw.split("#", 1)[0].split()
        if words[:1] == ["newmtl"]:
            name = " ".join(words[1:])
        elif words[:1] == ["Kd"] and name is not None:
            try:
                rgb = [255.0 * float(w) for w in words[1:4]]
            except ValueError:
                continue
            if len(rgb) == 3 and all(np.isfinite(rgb)):
                out[name] = rgb
    return out


def _cao_rows(text: str, path: Path) -> list[list[str]]:
    """The file's rows as words, comments and blank lines removed, `name=value`
    parameters dropped."""
    rows = []
    for raw in text.splitlines():
        words = [w for w in raw.split("#", 1)[0].split() if "=" not in w]
        if not words:
            continue
        if words[0].startswith("load("):
            raise ValueError(f"path {str(path)!r}: load(...) (hierarchical models) unsupported")
        rows.append(words)
    return rows


def _loop_from_lines(lines: list[tuple[int, int]], chosen: list[int], path: Path) -> list[int]:
    """The closed polygon that the lines `chosen` form, its corners in the order they
    are met starting from the first line."""
    pieces = [lines[i] for i in chosen]
    loop = [pieces[0][0], pieces[0][1]]
    rest = pieces[1:]
    while rest:
        for k, (a, b) in enumerate(rest):
            if a == loop[-1] or b == loop[-1]:
                loop.append(b if a == loop[-1] else a)
                rest.pop(k)
                break
        else:
            raise ValueError(f"path {str(path)!r}: a face's lines do not form a closed loop")
    if loop[-1] != loop[0]:
        raise ValueError(f"path {str(path)!r}: a face's lines do not form a closed loop")
    return loop[:-1]


@no_type_check
def read_cao(
    path: str | os.PathLike,
    name: str | None = None,
    *,
    orient: bool = True,
    curved: str = "skip",
) -> Polyhedron:
    """Read a ViSP `.cao` CAD model as a `Polyhedron` (see the module docstring).

    **Arguments:**
    - `path`: the `.cao` file.
    - `name`: the model's name (`None`: the file's name without its suffix).
    - `orient`: turn the faces consistently, outward for a closed model (as `read_ply`
      does); `False` keeps the file's order.
    - `curved`: what to do with cylinders and circles: `"skip"` (read past them) or
      `"error"` (a `ValueError`).

    **Returns:** a `Polyhedron`: the 3D points as vertices, the faces from points and
    from lines as polygon faces, edges their sides plus the 3D lines.

    **Raises:** `ValueError` naming the path for an unreadable or malformed file (or a
    curved primitive with `curved="error"`), naming `curved` for a bad option.
    """
    path = _as_path(path)
    _check_name(name)
    if curved not in ("skip", "error"):
        raise ValueError(f"curved must be 'skip' or 'error', got {curved!r}")
    rows = _cao_rows(_read_text(path), path)
    if rows and rows[0][0].upper() == "V1":
        rows = rows[1:]
    at = 0

    def section(min_words: int, label: str) -> list[list[str]]:
        nonlocal at
        if at >= len(rows):  # trailing sections may be left out
            return []
        try:
            count = int(rows[at][0])
        except ValueError as exc:
            raise ValueError(f"path {str(path)!r}: expected the number of {label}") from exc
        body = rows[at + 1 : at + 1 + count]
        if count < 0 or len(body) != count or any(len(r) < min_words for r in body):
            raise ValueError(f"path {str(path)!r}: the {label} section is truncated")
        at += 1 + count
        return body

    try:
        points = np.array([[float(w) for w in r[:3]] for r in section(3, "3D points")])
        lines = [(int(r[0]), int(r[1])) for r in section(2, "3D lines")]
        line_faces = [[int(w) for w in r[1 : 1 + int(r[0])]] for r in section(1, "line faces")]
        point_faces = [[int(w) for w in r[1 : 1 + int(r[0])]] for r in section(1, "point faces")]
        cylinders = section(3, "cylinders")
        circles = section(4, "circles")
    except (ValueError, IndexError) as exc:
        if isinstance(exc, ValueError) and str(exc).startswith("path"):
            raise
        raise ValueError(f"path {str(path)!r}: malformed CAO row ({exc})") from exc
    if (cylinders or circles) and curved == "error":
        raise ValueError(
            f"path {str(path)!r}: {len(cylinders)} cylinders and {len(circles)} circles "
            "are not polyhedral (curved='skip' reads past them)"
        )
    faces = [f for f in point_faces if len(f) >= 3]
    for chosen in line_faces:
        if any(i < 0 or i >= len(lines) for i in chosen) or len(chosen) < 3:
            raise ValueError(f"path {str(path)!r}: a face from lines has a bad line index")
        faces.append(_loop_from_lines(lines, chosen, path))
    lines += [(f[0], f[1]) for f in point_faces if len(f) == 2]  # two-point "faces"
    return _build(path, name, points, faces, lines, merge=False, orient=orient,
                  angle_tol=0.0, plane_tol=0.0)  # fmt: skip


@no_type_check
def read_mesh(path: str | os.PathLike, name: str | None = None, **options) -> Polyhedron:
    """Read a model from a PLY, OBJ or CAO file, chosen by its suffix (`.ply`, `.obj`,
    `.cao`, any case): `read_ply`, `read_obj` or `read_cao` with `options`.

    **Raises:** `ValueError` naming the path for an unknown suffix, and what the chosen
    reader raises.
    """
    path = _as_path(path)
    readers = {".ply": read_ply, ".obj": read_obj, ".cao": read_cao}
    reader = readers.get(path.suffix.lower())
    if reader is None:
        raise ValueError(f"path {str(path)!r}: unknown mesh suffix (expected .ply, .obj, .cao)")
    return reader(path, name, **options)
