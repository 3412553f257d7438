"""Tests of jaxpose.apps._visibility: faces turned to the camera, edge samples with
hidden parts removed, the covered area, rays cast onto the model."""

import cv2
import numpy as np
import pytest

from jaxpose.apps import (
    Polyhedron,
    cast_rays,
    edge_samples,
    face_mask,
    front_faces,
    mesh_geometry,
    read_ply,
    sample_path,
)

BOX = read_ply(sample_path("opencv_pose_box", "box.ply"))  # cm, 18.9 x 25.8 x 7.5
K = np.array([[800.0, 0.0, 320.0], [0.0, 800.0, 240.0], [0.0, 0.0, 1.0]])
SIZE = (640, 480)


def _pose(rvec, tvec):
    return cv2.Rodrigues(np.asarray(rvec, np.float64))[0], np.asarray(tvec, np.float64)


def _box_pose():
    # The box's centre about 80 cm in front, seen from above one corner.
    R, _ = _pose([2.2, -0.6, 0.4], [0, 0, 0])
    centre = BOX.vertices.mean(axis=0)
    return R, np.array([0.0, 0.0, 80.0]) - R @ centre


def _two_boxes():
    """Two boxes, the second 10 cm nearer the camera (-z) and across the first one's edge."""
    cube = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    back = cube * [20, 20, 4]
    front = cube * [12, 8, 4] + [14, 6, -14]  # nearer the camera, across an edge
    faces = tuple(quads) + tuple(tuple(i + 8 for i in q) for q in quads)
    sides = {(min(a, b), max(a, b)) for f in faces for a, b in zip(f, f[1:] + f[:1])}
    return Polyhedron("two", np.vstack([back, front]), np.array(sorted(sides)), faces)


def test_front_faces_and_box_edges():
    R, t = _box_pose()
    front = front_faces(BOX, R, t)
    assert front.sum() == 3
    samples = edge_samples(BOX, K, None, R, t, spacing=5.0, image_size=SIZE)
    seen = set(samples.edge[samples.visible].tolist())
    assert len(seen) == 9  # three faces: nine distinct edges
    outline = set(samples.edge[samples.visible & samples.outline].tolist())
    assert len(outline) == 6  # the hexagon around them; the three creases inside
    # Samples lie on their edges and project where the model does.
    edges = np.asarray(BOX.edges)
    a, b = BOX.vertices[edges[samples.edge, 0]], BOX.vertices[edges[samples.edge, 1]]
    ab = b - a
    s = ((samples.points - a) * ab).sum(1) / (ab * ab).sum(1)
    assert np.all((s > 0) & (s < 1))
    np.testing.assert_allclose(samples.points, a + s[:, None] * ab, atol=1e-12)
    uv, _ = cv2.projectPoints(samples.points, cv2.Rodrigues(R)[0], t, K, None)
    np.testing.assert_allclose(samples.pixels, uv.reshape(-1, 2), atol=1e-9)
    # Tangents follow the projected edge; normals are turned a quarter left.
    pa, _ = cv2.projectPoints(a, cv2.Rodrigues(R)[0], t, K, None)
    pb, _ = cv2.projectPoints(b, cv2.Rodrigues(R)[0], t, K, None)
    d = (pb - pa).reshape(-1, 2)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    np.testing.assert_allclose(samples.tangents, d, atol=1e-6)
    np.testing.assert_allclose((samples.normals * samples.tangents).sum(1), 0, atol=1e-12)
    # A face seen nearly edge-on gives no edges of its own with a grazing limit.
    normals = (R @ np.array([n for n in mesh_geometry(BOX).normals]).T).T
    sight = -(mesh_geometry(BOX).corners.mean(axis=1) @ R.T + t)
    angle = np.degrees(np.arccos((normals * sight).sum(1) / np.linalg.norm(sight, axis=1)))
    limit = float(np.sort(angle)[2]) - 1.0  # the third face seen is left out
    fewer = edge_samples(BOX, K, None, R, t, spacing=5.0, image_size=SIZE, grazing=limit)
    assert len(set(fewer.edge[fewer.visible].tolist())) == 7  # two faces: seven edges
    gaps = np.linalg.norm(np.diff(samples.pixels, axis=0), axis=1)
    same = np.diff(samples.edge) == 0
    assert np.all(np.abs(gaps[same] - 5.0) < 5.0)


def test_depth_test_hides_the_back_box():
    model = _two_boxes()
    R, t = _pose([0.15, -0.2, 0.0], [-10.0, -10.0, 90.0])
    samples = edge_samples(model, K, None, R, t, spacing=2.0)
    back = samples.edge < 12  # the first box's edges come first (lower vertex indices)
    assert np.asarray(model.edges)[samples.edge[back]].max() < 8
    # Independent check: the front box's projected outline.
    corners, _ = cv2.projectPoints(model.vertices[8:], cv2.Rodrigues(R)[0], t, K, None)
    hull = cv2.convexHull(corners.reshape(-1, 2).astype(np.float32))
    inside = np.array(
        [cv2.pointPolygonTest(hull, tuple(map(float, p)), True) for p in samples.pixels]
    )
    clear = np.abs(inside) > 0.5
    assert np.any(back & (inside > 0.5))  # some back edges pass behind the front box
    np.testing.assert_array_equal(samples.visible[back & clear], inside[back & clear] < 0)
    assert np.all(samples.visible[~back])  # the near box hides nothing of itself
    # Without the depth test every front-facing edge counts.
    plain = edge_samples(model, K, None, R, t, spacing=2.0, occlusion=False)
    assert plain.visible.sum() > samples.visible.sum()


def test_face_labels_show_the_nearest_face(rng):
    # Where the near box covers the far one, its faces are drawn (the ray cast's nearest
    # crossing); the labelled area is face_mask's.
    from jaxpose.apps._visibility import face_labels

    model = _two_boxes()
    R, t = _pose([0.15, -0.2, 0.0], [-10.0, -10.0, 90.0])
    labels = face_labels(model, K, None, R, t, SIZE)
    np.testing.assert_array_equal(labels >= 0, face_mask(model, K, None, R, t, SIZE) > 0)
    pixels = rng.uniform([0, 0], [639, 479], size=(4000, 2))
    hits = cast_rays(model, K, None, R, t, pixels)
    shown = labels[np.round(pixels[:, 1]).astype(int), np.round(pixels[:, 0]).astype(int)]
    inside = hits.hit & (shown >= 0)
    assert np.any(inside & (hits.face >= 6))  # the near box in front of the far one
    assert np.mean(shown[inside] == hits.face[inside]) > 0.99  # (rounding at the seams)


@pytest.mark.parametrize("dist", [None, np.array([-0.2, 0.08, 0.001, -0.002, 0.0])])
def test_cast_rays_land_on_the_mesh(dist, rng):
    R, t = _box_pose()
    geo = mesh_geometry(BOX)
    mask = face_mask(geo, K, dist, R, t, SIZE)
    inner = face_mask(geo, K, dist, R, t, SIZE, erode=2)
    assert 0 < inner.sum() < mask.sum()
    pixels = rng.uniform([0, 0], [639, 479], size=(4000, 2))
    hits = cast_rays(geo, K, dist, R, t, pixels)
    iy, ix = np.round(pixels[:, 1]).astype(int), np.round(pixels[:, 0]).astype(int)
    np.testing.assert_array_equal(hits.hit[inner[iy, ix] > 0], True)
    outer = cv2.dilate(mask, np.ones((5, 5), np.uint8))
    np.testing.assert_array_equal(hits.hit[outer[iy, ix] == 0], False)
    p, f = hits.points[hits.hit], hits.face[hits.hit]
    size = np.ptp(BOX.vertices, axis=0).max()
    offset = (geo.normals[f] * p).sum(1) - geo.offsets[f]
    assert np.abs(offset).max() <= 1e-6 * size
    assert np.all(front_faces(geo, R, t)[f])  # the nearest crossing is on a front face
    uv, _ = cv2.projectPoints(p, cv2.Rodrigues(R)[0], t, K, dist)
    np.testing.assert_allclose(uv.reshape(-1, 2), pixels[hits.hit], atol=1e-6)
    depth = (p @ R.T + t)[:, 2]
    np.testing.assert_allclose(hits.depth[hits.hit], depth, rtol=1e-12)
    assert np.all(hits.points[~hits.hit] == 0) and np.all(hits.face[~hits.hit] == -1)


def test_bad_arguments():
    R, t = _box_pose()
    with pytest.raises(ValueError, match="model"):
        edge_samples("box", K, None, R, t)
    with pytest.raises(ValueError, match="K"):
        edge_samples(BOX, np.eye(2), None, R, t)
    with pytest.raises(ValueError, match="R"):
        edge_samples(BOX, K, None, 2 * R, t)
    with pytest.raises(ValueError, match="t"):
        edge_samples(BOX, K, None, R, [0, 0, np.nan])
    with pytest.raises(ValueError, match="spacing"):
        edge_samples(BOX, K, None, R, t, spacing=0)
    with pytest.raises(ValueError, match="margin"):
        edge_samples(BOX, K, None, R, t, margin=-1.0)
    with pytest.raises(ValueError, match="grazing"):
        edge_samples(BOX, K, None, R, t, grazing=0)
    with pytest.raises(ValueError, match="dist"):
        cast_rays(BOX, K, [1.0, 2.0], R, t, np.zeros((1, 2)))
    with pytest.raises(ValueError, match="pixels"):
        cast_rays(BOX, K, None, R, t, np.zeros((1, 3)))
    with pytest.raises(ValueError, match="image_size"):
        face_mask(BOX, K, None, R, t, (0, 10))
    empty = cast_rays(BOX, K, None, R, t, np.zeros((0, 2)))
    assert empty.points.shape == (0, 3)
