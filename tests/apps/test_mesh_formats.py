"""Tests of jaxpose.apps._mesh_formats: OBJ and ViSP .cao models, and read_mesh."""

import numpy as np
import pytest

from jaxpose.apps import read_cao, read_mesh, read_obj, read_ply, sample_path
from jaxpose.apps._polyhedron import polygon_normals

BOX_PLY = sample_path("opencv_pose_box", "box.ply")

# A tea box as ViSP's tutorial models it (metres), with comments and parameters.
TEABOX_CAO = """V1
# 3D Points
8                  # Number of points
0     0      0     # Point 0: X Y Z
0     0     -0.08
0.165 0     -0.08
0.165 0      0
0.165 0.068  0
0.165 0.068 -0.08
0     0.068 -0.08
0     0.068  0     # Point 7
# 3D Lines
1                  # Number of lines
0 4 name=diagonal
# Faces from 3D lines
0                  # Number of faces defined by lines
# Faces from 3D points
6                  # Number of faces defined by points
4 0 1 2 3          # Face 0: [number of points] [index of the 3D points]...
4 1 6 5 2
4 4 5 6 7 name=top
4 0 3 4 7
4 5 4 3 2
4 0 7 6 1          # Face 5
# 3D cylinders
0                  # Number of cylinders
# 3D circles
0                  # Number of circles
"""


def _outward(model):
    """Whether every face's normal points away from the model's centroid."""
    centre = model.vertices.mean(axis=0)
    normals = polygon_normals(model.vertices, model.faces)
    offsets = [
        n @ (model.vertices[list(f)].mean(axis=0) - centre)
        for n, f in zip(normals, model.faces, strict=True)
    ]
    return np.all(np.array(offsets) > 0)


def _edge_set(model):
    return {tuple(e) for e in np.asarray(model.edges).tolist()}


def test_cao_teabox(tmp_path):
    path = tmp_path / "teabox.cao"
    path.write_text(TEABOX_CAO)
    model = read_cao(path)
    assert model.name == "teabox" and model.vertices.shape == (8, 3)
    assert len(model.faces) == 6 and all(len(f) == 4 for f in model.faces)
    assert _outward(model)
    assert len(model.edges) == 13 and (0, 4) in _edge_set(model)  # 12 sides + the line
    assert read_mesh(path, "tea").name == "tea"


def test_cao_faces_from_lines_and_reversed_faces(tmp_path):
    # The box's six faces given by 12 lines; one face listed clockwise from outside.
    lines = [
        (0, 1),
        (1, 2),
        (2, 3),
        (3, 0),
        (4, 5),
        (5, 6),
        (6, 7),
        (7, 4),
        (0, 7),
        (1, 6),
        (2, 5),
        (3, 4),
    ]
    faces = [(0, 1, 2, 3), (4, 5, 6, 7), (0, 8, 6, 9), (2, 10, 4, 11), (3, 11, 7, 8), (1, 10, 5, 9)]
    points = TEABOX_CAO.split("# 3D Lines")[0]
    text = points + f"{len(lines)}\n" + "".join(f"{a} {b}\n" for a, b in lines)
    text += f"{len(faces)}\n" + "".join(f"4 {' '.join(map(str, f))}\n" for f in faces)
    text += "0\n1\n0 1 0.01\n0\n"  # no point faces; one cylinder, no circle
    path = tmp_path / "lines.cao"
    path.write_text(text)
    model = read_cao(path)
    assert len(model.faces) == 6 and _outward(model) and len(model.edges) == 12
    with pytest.raises(ValueError, match="cylinders"):
        read_cao(path, curved="error")


def test_obj_matches_ply(tmp_path):
    ply = read_ply(BOX_PLY)
    triangles = [
        [5, 1, 0],
        [5, 4, 0],
        [4, 0, 2],
        [4, 6, 2],
        [7, 5, 4],
        [7, 6, 4],
        [3, 2, 1],
        [1, 2, 0],
        [5, 7, 1],
        [7, 1, 3],
        [7, 6, 3],
        [6, 3, 2],
    ]
    lines = ["# the box", "o box", "g faces"]
    lines += [f"v {x} {y} {z}" for x, y, z in ply.vertices]
    lines += ["vn 0 0 1", "vt 0 0"]
    for k, (a, b, c) in enumerate(triangles):  # every corner style, negative indices too
        if k % 4 == 0:
            lines.append(f"f {a + 1} {b + 1} {c + 1}")
        elif k % 4 == 1:
            lines.append(f"f {a + 1}/1 {b + 1}/1 {c + 1}/1")
        elif k % 4 == 2:
            lines.append(f"f {a + 1}/1/1 {b + 1}//1 {c + 1}/1/1")
        else:
            lines.append(f"f {a - 8} {b - 8} {c - 8}")
    path = tmp_path / "box.OBJ"
    path.write_text("\n".join(lines) + "\n")
    model = read_mesh(path)
    assert model.name == "box"
    np.testing.assert_array_equal(model.vertices, ply.vertices)
    assert sorted(map(sorted, model.faces)) == sorted(map(sorted, ply.faces))
    assert _edge_set(model) == _edge_set(ply) and len(model.faces) == 6 and _outward(model)
    raw = read_obj(path, merge=False)
    assert len(raw.faces) == 12


def test_obj_materials_colour_the_faces(tmp_path):
    # A unit square split into two triangles of two materials, and a quad of a third:
    # the colours (Kd, 0..1) become face colours, and the two triangles stay apart.
    (tmp_path / "paint.mtl").write_text(
        "newmtl red\nKd 1 0 0\nnewmtl dark grey\nKd 0.2 0.2 0.2\n"
        "newmtl blue  # a comment\nKa 1 1 1\nKd 0 0 1\n"
    )
    text = ("mtllib paint.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\n"
            "usemtl red\nf 1 2 3\nusemtl dark grey\nf 1 3 4\nusemtl blue\nf 1 5 6 2\n")  # fmt: skip
    (tmp_path / "two.obj").write_text(text)
    model = read_obj(tmp_path / "two.obj")
    assert len(model.faces) == 3
    expected = {(0, 1, 2): [255, 0, 0], (0, 2, 3): [51, 51, 51], (0, 1, 4, 5): [0, 0, 255]}
    for f, c in zip(model.faces, model.face_colours, strict=True):
        np.testing.assert_allclose(c, expected[tuple(sorted(f))])
    # A face without a material (or an unknown one, or no MTL file): no colours at all.
    (tmp_path / "part.obj").write_text(text.replace("usemtl blue", "usemtl green"))
    assert read_obj(tmp_path / "part.obj").face_colours is None
    (tmp_path / "none.obj").write_text(text.replace("paint.mtl", "missing.mtl"))
    assert read_obj(tmp_path / "none.obj").face_colours is None


def test_obj_polyline_edges(tmp_path):
    path = tmp_path / "wire.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\nl 1 3\n")
    model = read_obj(path)
    assert len(model.faces) == 1 and (0, 2) in _edge_set(model) and len(model.edges) == 5


@pytest.mark.parametrize(
    "name, text, match",
    [
        ("a.obj", "v 0 0\n", "vertex needs"),
        ("b.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n", "bad index"),
        ("c.obj", "v 0 0 0\nf 0 1 2\n", "start at 1"),
        ("d.cao", "V1\n3\n0 0 0\n1 0 0\n", "truncated"),
        ("e.cao", "V1\n3\n0 0 0\n1 0 0\n0 1 0\n0\n0\n1\n3 0 1 5\n", "bad index"),
        ("f.cao", 'V1\nload("other.cao")\n', "load"),
        ("g.cao", "V1\nthree\n", "number of 3D points"),
        ("h.stl", "solid x\n", "suffix"),
    ],
)
def test_bad_files(tmp_path, name, text, match):
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(ValueError, match=match):
        read_mesh(path)


def test_bad_arguments(tmp_path):
    with pytest.raises(ValueError, match="path"):
        read_obj(3)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="path"):
        read_cao(tmp_path / "missing.cao")
    with pytest.raises(ValueError, match="curved"):
        read_cao(tmp_path / "x.cao", curved="maybe")
    with pytest.raises(ValueError, match="angle_tol"):
        read_obj(tmp_path / "x.obj", angle_tol=2.0)
