"""Tests of jaxpose.apps._mesh: PLY meshes read as polyhedra (coplanar triangles merged
into faces) and written back."""

from pathlib import Path

import numpy as np
import pytest

from jaxpose.apps import Polyhedron, read_ply, sample_path, write_ply
from jaxpose.apps._polyhedron import polygon_normals, prism

BOX = sample_path("opencv_pose_box", "box.ply")
BOX_EDGES = {(0, 1), (0, 2), (0, 4), (1, 3), (1, 5), (2, 3), (2, 6), (3, 7), (4, 5)}
BOX_EDGES |= {(4, 6), (5, 7), (6, 7)}


def outward(model: Polyhedron) -> np.ndarray:
    """Each face's normal dotted with the direction from the centre to the face."""
    normals = polygon_normals(model.vertices, model.faces)
    centre = model.vertices.mean(axis=0)
    return np.array(
        [n @ (model.vertices[list(f)].mean(axis=0) - centre) for n, f in zip(normals, model.faces)]
    )


def test_box():
    box = read_ply(BOX)
    assert box.name == "box"
    assert box.vertices.shape == (8, 3) and box.vertices.dtype == np.float64
    np.testing.assert_allclose(np.ptp(box.vertices, axis=0), [18.9, 25.8, 7.5], rtol=1e-6)
    assert len(box.faces) == 6 and all(len(f) == 4 for f in box.faces)
    assert np.all(outward(box) > 0)
    # Each quad is one side of the box: its four vertices share one coordinate.
    for f in box.faces:
        assert np.sum(np.ptp(box.vertices[list(f)], axis=0) < 1e-9) == 1
    assert box.edges.shape == (12, 2) and box.edges.dtype == np.int32
    assert {tuple(e) for e in box.edges.tolist()} == BOX_EDGES


def test_box_unmerged():
    box = read_ply(BOX, "triangles", merge=False)
    assert box.name == "triangles" and len(box.faces) == 12
    assert len(box.edges) == 18  # with the six diagonals


@pytest.mark.parametrize("binary", [False, True])
def test_round_trip(tmp_path, binary):
    box = read_ply(BOX)
    write_ply(tmp_path / "box.ply", box, binary=binary)
    again = read_ply(tmp_path / "box.ply")
    np.testing.assert_array_equal(again.vertices, box.vertices)
    assert again.faces == box.faces
    np.testing.assert_array_equal(again.edges, box.edges)


def triangulated(model: Polyhedron, rng) -> list[tuple[int, ...]]:
    """The model's faces as fans of triangles, half of them turned inside out. Each fan
    starts at the L's reflex corner (3 on top, 9 below) when the face has it: a fan from
    there stays inside the L."""
    starts = [next((k for k, v in enumerate(f) if v % 6 == 3), 0) for f in model.faces]
    rotated = [f[k:] + f[:k] for f, k in zip(model.faces, starts)]
    tris = [(f[0], f[i], f[i + 1]) for f in rotated for i in range(1, len(f) - 1)]
    return [t[::-1] if rng.random() < 0.5 else t for t in tris]


def write_binary(path: Path, vertices: np.ndarray, faces) -> None:
    """A binary little-endian PLY with float32 vertices, an extra vertex property and
    uchar / uint face lists (the layout of many exporters)."""
    head = (
        "ply\nformat binary_little_endian 1.0\ncomment test\n"
        f"element vertex {len(vertices)}\nproperty float x\nproperty float y\n"
        "property float z\nproperty uchar red\n"
        f"element face {len(faces)}\nproperty list uchar uint vertex_indices\nend_header\n"
    )
    table = np.zeros(len(vertices), [("p", "<f4", 3), ("red", "u1")])
    table["p"] = vertices
    body = b"".join(
        np.array([len(f)], "u1").tobytes() + np.array(f, "<u4").tobytes() for f in faces
    )
    path.write_bytes(head.encode() + table.tobytes() + body)


def test_binary_triangulated_non_convex(tmp_path):
    """An L-shaped prism (one concave side), triangulated with mixed orientations: the
    merge gives back its 8 faces, outward, and its 18 edges."""
    outline = np.array([[0, 0], [4, 0], [4, 1], [1, 1], [1, 3], [0, 3]], np.float64)
    solid = prism("ell", outline, 2.0)
    path = tmp_path / "ell.ply"
    write_binary(path, solid.vertices, triangulated(solid, np.random.default_rng(1)))
    again = read_ply(path)
    assert again.name == "ell"
    assert sorted(len(f) for f in again.faces) == [4] * 6 + [6, 6]
    assert {tuple(e) for e in again.edges.tolist()} == {
        (min(a, b), max(a, b)) for a, b in solid.edges.tolist()
    }
    same_outward_faces(again, solid)


def same_outward_faces(ours: Polyhedron, theirs: Polyhedron) -> None:
    """The same faces with the same normals (the prism's faces are listed outward)."""
    normals = dict(zip(map(frozenset, ours.faces), polygon_normals(ours.vertices, ours.faces)))
    assert set(normals) == set(map(frozenset, theirs.faces))
    for face, normal in zip(theirs.faces, polygon_normals(theirs.vertices, theirs.faces)):
        np.testing.assert_allclose(normals[frozenset(face)], normal, atol=1e-6)


def test_polygons_kept(tmp_path):
    box = read_ply(BOX)
    write_ply(tmp_path / "quads.ply", box)
    kept = read_ply(tmp_path / "quads.ply", merge=False)
    assert kept.faces == box.faces
    # Non-convex polygon faces come back as they were, merged or not.
    solid = prism("ell", np.array([[0, 0], [4, 0], [4, 1], [1, 1], [1, 3], [0, 3.0]]), 2.0)
    write_ply(tmp_path / "ell.ply", solid, binary=True)
    again = read_ply(tmp_path / "ell.ply")
    same_outward_faces(again, solid)


def write_coloured(path: Path, colours, where: str = "face") -> Polyhedron:
    """The box's twelve triangles as an ASCII PLY with `colours` (one RGB per triangle,
    or per vertex with `where="vertex"`); returns the triangles read unmerged."""
    tris = read_ply(BOX, merge=False)
    rgb = ["property uchar red", "property uchar green", "property uchar blue"]
    head = ["ply", "format ascii 1.0", f"element vertex {len(tris.vertices)}",
            "property double x", "property double y", "property double z",
            *(rgb if where == "vertex" else []), f"element face {len(tris.faces)}",
            "property list uchar int vertex_indices", *(rgb if where == "face" else []),
            "end_header"]  # fmt: skip
    c = [" ".join(str(int(x)) for x in row) for row in colours]
    vertices = [" ".join(map(repr, v.tolist())) for v in tris.vertices]
    faces = [" ".join(map(str, (3, *f))) for f in tris.faces]
    if where == "vertex":
        vertices = [f"{v} {k}" for v, k in zip(vertices, c, strict=True)]
    else:
        faces = [f"{f} {k}" for f, k in zip(faces, c, strict=True)]
    path.write_text("\n".join(head + vertices + faces) + "\n")
    return tris


@pytest.mark.parametrize("binary", [False, True])
def test_face_colours_read_merged_and_written_back(tmp_path, binary):
    # Each side of the box one colour, but for one side whose two triangles differ: its
    # triangles are not merged (the colour change is an edge), and each face keeps its
    # triangles' colour, written back and read again.
    tris = read_ply(BOX, merge=False)
    side = {}  # each triangle's side: the coordinate its three vertices share
    for k, f in enumerate(tris.faces):
        p = tris.vertices[list(f)]
        axis = int(np.argmin(np.ptp(p, axis=0)))
        side[k] = (axis, round(float(p[0, axis]), 6))
    names = sorted(set(side.values()))
    colours = np.array([[40 * names.index(side[k]), 10, 200] for k in range(len(side))])
    split = [k for k in side if side[k] == names[0]][1]
    colours[split] = [255, 0, 0]
    write_coloured(tmp_path / "c.ply", colours)
    box = read_ply(tmp_path / "c.ply")
    assert len(box.faces) == 7 and box.face_colours.shape == (7, 3)
    assert sorted(len(f) for f in box.faces) == [3, 3, 4, 4, 4, 4, 4]
    for f, c in zip(box.faces, box.face_colours, strict=True):
        # the colour of the triangles the face came from (its vertices cover theirs)
        mine = [k for k, t in enumerate(tris.faces) if set(t) <= set(f)]
        assert mine and all(np.array_equal(colours[k], c) for k in mine)
    write_ply(tmp_path / "again.ply", box, binary=binary)
    again = read_ply(tmp_path / "again.ply")
    assert again.faces == box.faces
    np.testing.assert_array_equal(again.face_colours, box.face_colours)
    assert read_ply(BOX).face_colours is None  # a mesh without colours has none


def test_vertex_colours_averaged_over_each_face(tmp_path):
    rng = np.random.default_rng(3)
    colours = rng.integers(0, 256, (8, 3))
    tris = write_coloured(tmp_path / "v.ply", colours, where="vertex")
    box = read_ply(tmp_path / "v.ply", merge=False)
    expected = np.array([colours[list(f)].mean(axis=0) for f in tris.faces])
    np.testing.assert_allclose(box.face_colours, expected)
    with pytest.raises(ValueError, match="face_colours"):
        bad = Polyhedron(box.name, box.vertices, box.edges, box.faces, np.zeros((2, 3)))
        write_ply(tmp_path / "bad.ply", bad)


def test_errors(tmp_path):
    with pytest.raises(ValueError, match="missing.ply"):
        read_ply(tmp_path / "missing.ply")
    (tmp_path / "text.ply").write_text("hello\n")
    with pytest.raises(ValueError, match="text.ply"):
        read_ply(tmp_path / "text.ply")
    text = BOX.read_text()
    (tmp_path / "short.ply").write_text(text[: text.index("3 5 1 0")])
    with pytest.raises(ValueError, match="short.ply"):
        read_ply(tmp_path / "short.ply")
    (tmp_path / "index.ply").write_text(text.replace("3 5 1 0", "3 5 1 9"))
    with pytest.raises(ValueError, match="index"):
        read_ply(tmp_path / "index.ply")
    with pytest.raises(ValueError, match="path"):
        read_ply(3)
    with pytest.raises(ValueError, match="angle_tol"):
        read_ply(BOX, angle_tol=-1.0)
    with pytest.raises(ValueError, match="model"):
        write_ply(tmp_path / "x.ply", "box")
