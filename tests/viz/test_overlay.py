"""Superimposition: edges drawn where the projected edges are, images kept intact,
the renderer's faces where the model is, and argument validation."""

from __future__ import annotations

import cv2
import jax
import numpy as np
import pytest
from matplotlib.path import Path as PolygonPath

import jaxpose as jp
from jaxpose.apps import sample_path

DATA = sample_path("chessboard")
K = np.array([[400.0, 0.0, 160.0], [0.0, 400.0, 120.0], [0.0, 0.0, 1.0]])
CAMERA = np.column_stack([K, np.zeros(3)])


def _box_pose():
    R = cv2.Rodrigues(np.array([0.4, -0.5, 0.2]))[0]
    return R, np.array([30.0, 20.0, 420.0])


def _segment_distance(points, a, b):
    """Distance of pixels `points` (m, 2) to the segment `ab`."""
    d = b - a
    s = np.clip(((points - a) @ d) / max(d @ d, 1e-12), 0, 1)
    return np.linalg.norm(points - (a + s[:, None] * d), axis=1)


def _lit(image, channel=1):
    rows, cols = np.nonzero(image[..., channel])
    return np.column_stack([cols, rows]).astype(np.float64)  # pixel centres (x, y)


def test_edges_land_on_projected_edges():
    model = jp.apps.model_database()["box"]
    R, t = _box_pose()
    image = np.zeros((240, 320, 3), np.uint8)
    out = jp.viz.draw_model(image, CAMERA, model, (R, t), color=(0, 255, 0))
    uv, _ = cv2.projectPoints(model.vertices, cv2.Rodrigues(R)[0], t, K, None)
    uv = uv.reshape(-1, 2)
    lit = _lit(out)
    strong = _lit(out > 127)
    assert len(lit) > 200
    near = np.min([_segment_distance(lit, uv[a], uv[b]) for a, b in model.edges], axis=0)
    core = np.min([_segment_distance(strong, uv[a], uv[b]) for a, b in model.edges], axis=0)
    # Every drawn pixel is on some projected edge: antialiasing spreads a 1-px line's
    # faint fringe over about 1.5 px, and its round end caps reach about 2 px past the
    # vertices; the line's core (over half intensity) is within a pixel ...
    assert near.max() < 2.5 and core.max() < 1.0
    # ... and every projected edge is drawn along its whole length.
    for a, b in model.edges:
        samples = uv[a] + np.linspace(0.05, 0.95, 25)[:, None] * (uv[b] - uv[a])
        px = np.round(samples).astype(int)
        window = [out[y - 1 : y + 2, x - 1 : x + 2, 1].max() for x, y in px]
        assert min(window) > 0


def test_distorted_edges_follow_opencv_projection():
    model = jp.apps.model_database()["box"]
    R, t = _box_pose()
    dist = np.array([-0.27, -0.04, 0.002, -0.0003, 0.24])
    out = jp.viz.draw_model(np.zeros((240, 320), np.uint8), CAMERA, model, (R, t), dist_coeffs=dist)
    lit = np.column_stack(np.nonzero(out > 0)[::-1]).astype(np.float64)
    strong = np.column_stack(np.nonzero(out > 127)[::-1]).astype(np.float64)
    # Dense samples of the 3D edges projected by OpenCV with the distortion.
    s = np.linspace(0, 1, 200)[:, None]
    pts = np.concatenate(
        [model.vertices[a] + s * (model.vertices[b] - model.vertices[a]) for a, b in model.edges]
    )
    curve, _ = cv2.projectPoints(pts, cv2.Rodrigues(R)[0], t, K, dist)
    curve = curve.reshape(-1, 2)
    d_lit = np.min(np.linalg.norm(lit[:, None] - curve[None], axis=2), axis=1)
    d_core = np.min(np.linalg.norm(strong[:, None] - curve[None], axis=2), axis=1)
    assert d_lit.max() < 2.5 and d_core.max() < 1.0
    inside = (curve[:, 0] > 2) & (curve[:, 0] < 317) & (curve[:, 1] > 2) & (curve[:, 1] < 237)
    d_curve = np.min(np.linalg.norm(curve[inside][:, None] - lit[None], axis=2), axis=1)
    assert d_curve.max() < 1.0
    # The straight (undistorted) drawing is off the distorted curve: distortion applied.
    plain = jp.viz.draw_model(np.zeros((240, 320), np.uint8), CAMERA, model, (R, t))
    lit_plain = np.column_stack(np.nonzero(plain > 0)[::-1]).astype(np.float64)
    off = np.min(np.linalg.norm(lit_plain[:, None] - curve[None], axis=2), axis=1)
    assert off.max() > 3


@pytest.mark.parametrize(
    "shape, dtype",
    [
        ((60, 80), np.uint8),
        ((60, 80, 3), np.uint8),
        ((60, 80, 3), np.uint16),
        ((60, 80, 1), np.float32),
        ((60, 80, 4), np.float64),
    ],
)
def test_image_shape_and_dtype_are_kept(shape, dtype):
    model = jp.apps.model_database()["pyramid"]
    R, t = np.eye(3), np.array([0.0, 0.0, 900.0])
    camera = np.column_stack(
        [np.diag([200.0, 200.0, 1.0]) + [[0, 0, 40], [0, 0, 30], [0, 0, 0]], np.zeros(3)]
    )
    image = np.full(shape, 7, dtype=dtype)
    before = image.copy()
    out = jp.viz.overlay(
        image, camera, model, (R, t), vertices=np.arange(5), observed=np.full((5, 2), 30.0)
    )
    assert out.shape == image.shape and out.dtype == image.dtype
    np.testing.assert_array_equal(image, before)  # the input is not modified
    assert np.any(out != image)


def test_edges_behind_the_camera_are_clipped():
    model = jp.apps.model_database()["box"]
    image = np.zeros((240, 320, 3), np.uint8)
    # Entirely behind the camera: nothing drawn.
    behind = jp.viz.draw_model(image, CAMERA, model, (np.eye(3), np.array([0.0, 0.0, -500.0])))
    assert not behind.any()
    # Straddling the camera plane: only the part in front, never garbage, no error.
    straddle = jp.viz.draw_model(image, CAMERA, model, (np.eye(3), np.array([0.0, 0.0, 10.0])))
    assert straddle.dtype == np.uint8 and straddle.shape == image.shape


def test_cull_hides_the_back_edges_of_a_convex_model():
    model = jp.apps.model_database()["box"]
    R, t = _box_pose()
    image = np.zeros((240, 320, 3), np.uint8)
    full = jp.viz.draw_model(image, CAMERA, model, (R, t))
    culled = jp.viz.draw_model(image, CAMERA, model, (R, t), cull=True)
    assert np.count_nonzero(culled) < np.count_nonzero(full)
    assert not np.any((culled > 0) & (full == 0))


def test_draw_points_marks_the_pixels():
    image = np.zeros((50, 60, 3), np.uint8)
    pts = np.array([[10.0, 12.0], [40.5, 30.25]])
    for marker in ("circle", "cross"):
        out = jp.viz.draw_points(image, pts, color=(255, 0, 0), marker=marker, size=4)
        for x, y in pts:
            i, j = int(round(y)), int(round(x))
            assert out[i - 5 : i + 6, j - 5 : j + 6, 0].max() > 0
        assert out[..., 1:].max() == 0


def test_render_bench_shows_the_object_where_it_projects():
    b = jp.default_bench()
    img = jp.viz.render_bench(b)
    w, h = b.image_size
    assert img.shape == (h, w, 3) and img.dtype == np.uint8
    background = np.array([96, 96, 96])
    np.testing.assert_array_equal(img[5, 5], background)
    np.testing.assert_array_equal(img[h - 5, w - 5], background)
    # The centre of every face turned towards the camera is painted (not background).
    world = b.model.vertices @ b.R.T + b.t
    centre = -np.linalg.solve(b.camera[:, :3], b.camera[:, 3])
    top = b.model.faces[0]  # z = +10, the face the camera looks at
    p = world[list(top)]
    assert np.cross(p[1] - p[0], p[2] - p[0]) @ (centre - p[0]) > 0
    uv = jax.jit(jp.project)(b.camera, world[[0, 5, 8]])  # a triangle inside the top face
    x, y = np.asarray(uv).mean(axis=0).round().astype(int)
    assert not np.array_equal(img[y, x], background)
    # Pixels well outside the projected outline stay background.
    lo = b.clean_points.min(axis=0) - 40
    hi = b.clean_points.max(axis=0) + 40
    outside = np.ones((h, w), bool)
    outside[int(lo[1]) : int(hi[1]), int(lo[0]) : int(hi[0])] = False
    assert np.all(img[outside] == background)


def test_render_matches_ray_casting():
    # The non-convex L-block, turned so that one arm hides part of the other: every pixel
    # away from the edges shows the shade of the face its ray meets first.
    model = jp.apps.model_database()["l_block"]
    R = cv2.Rodrigues(np.array([1.2, 1.2, 0.0]))[0]
    t = np.array([0.0, 0.0, 500.0])
    light = np.array([0.3, -0.5, -1.0])
    base = np.array([150.0, 175.0, 205.0])
    img = jp.viz.render(CAMERA, model, (R, t), (320, 240), light=light, supersample=1)
    world = model.vertices @ R.T + t
    light = light / np.linalg.norm(light)
    normals, shades = [], []
    for face in model.faces:
        p = world[list(face)]
        n = np.sum(np.cross(p, np.roll(p, -1, axis=0)), axis=0)
        n /= np.linalg.norm(n)
        normals.append(n)
        shades.append(np.round(base * (0.3 + 0.7 * max(n @ light, 0.0))))
    uv = (world @ K.T)[:, :2] / (world @ K.T)[:, 2:]
    ys, xs = np.mgrid[1:239:2, 1:319:2]
    pixels = np.column_stack([xs.ravel(), ys.ravel()]) + 0.5
    edge = np.min([_segment_distance(pixels, uv[a], uv[b]) for a, b in model.edges], axis=0)
    pixels = pixels[edge >= 2]  # away from the edges: no rasterisation ambiguity
    rays = np.column_stack([pixels, np.ones(len(pixels))]) @ np.linalg.inv(K).T
    nearest = np.full(len(pixels), np.inf)
    overlap = np.zeros(len(pixels), int)
    expected = np.tile([96.0, 96.0, 96.0], (len(pixels), 1))
    for face, n, shade in zip(model.faces, normals, shades, strict=True):
        p = world[list(face)]
        den = rays @ n
        s = np.where(np.abs(den) > 1e-12, (n @ p[0]) / np.where(den == 0, 1, den), -1)
        q = s[:, None] * rays
        # inside the (planar) polygon, tested in the face's own 2D frame
        e1 = (p[1] - p[0]) / np.linalg.norm(p[1] - p[0])
        e2 = np.cross(n, e1)
        poly = PolygonPath(np.column_stack([(p - p[0]) @ e1, (p - p[0]) @ e2]))
        inside = poly.contains_points(np.column_stack([(q - p[0]) @ e1, (q - p[0]) @ e2]))
        hit = inside & (s > 0) & (s < nearest)
        overlap += inside & (s > 0) & (den < 0)  # faces turned towards the camera
        nearest[hit] = s[hit]
        expected[hit] = shade
    rows, cols = (pixels[:, 1] - 0.5).astype(int), (pixels[:, 0] - 0.5).astype(int)
    np.testing.assert_allclose(img[rows, cols], expected, atol=1)
    assert np.isfinite(nearest).sum() > 400  # many of them on the object
    assert np.sum(overlap > 1) > 40  # and some where a nearer face hides another one


def test_chessboard_grid_on_a_photograph():
    fs = cv2.FileStorage(str(DATA / "left_intrinsics.yml"), cv2.FILE_STORAGE_READ)
    Kc = fs.getNode("camera_matrix").mat()
    dist = fs.getNode("distortion_coefficients").mat().ravel()
    fs.release()
    gray = cv2.imread(str(DATA / "left01.jpg"), cv2.IMREAD_GRAYSCALE)
    found, corners = cv2.findChessboardCorners(gray, (9, 6))
    assert found
    corners = corners.reshape(-1, 2)
    model, inner = jp.apps.chessboard((9, 6), 0.025)
    ok, rvec, tvec = cv2.solvePnP(model.vertices[inner], corners, Kc, dist)
    assert ok
    pose = (cv2.Rodrigues(rvec)[0], tvec.ravel())
    drawn = jp.viz.draw_model(
        np.zeros_like(gray),
        np.column_stack([Kc, np.zeros(3)]),
        model,
        pose,
        dist_coeffs=dist,
        color=(255, 255, 255),
    )
    # The grid lines cross at the detected corners: every corner has ink within 1 px.
    for x, y in corners.round().astype(int):
        assert drawn[y - 1 : y + 2, x - 1 : x + 2].max() > 0


def test_chessboard_model():
    model, inner = jp.apps.chessboard((9, 6), 0.025, border=1)
    assert model.vertices.shape == (11 * 8, 3) and np.all(model.vertices[:, 2] == 0)
    assert len(model.edges) == 10 * 8 + 11 * 7 and len(model.faces) == 10 * 7
    expected = np.zeros((54, 3))
    expected[:, :2] = np.mgrid[0:9, 0:6].T.reshape(-1, 2) * 0.025
    np.testing.assert_allclose(model.vertices[inner], expected)
    lengths = np.linalg.norm(np.diff(model.vertices[model.edges], axis=1)[:, 0], axis=1)
    np.testing.assert_allclose(lengths, 0.025)
    with pytest.raises(ValueError, match="pattern"):
        jp.apps.chessboard((1, 6))
    with pytest.raises(ValueError, match="square"):
        jp.apps.chessboard((9, 6), -1.0)


def _good():
    return np.zeros((40, 50, 3), np.uint8), CAMERA, jp.apps.model_database()["box"], _box_pose()


@pytest.mark.parametrize(
    "change, name",
    [
        ({"image": [[0, 1]]}, "image"),
        ({"image": np.zeros((4, 5, 3, 2), np.uint8)}, "image"),
        ({"image": np.zeros((4, 5), np.int32)}, "image"),
        ({"image": np.zeros((0, 5), np.uint8)}, "image"),
        ({"camera": np.eye(3)}, "camera"),
        ({"camera": np.full((3, 4), np.nan)}, "camera"),
        ({"model": "box"}, "model"),
        ({"pose": (np.eye(2), np.zeros(3))}, "pose"),
        ({"pose": (np.eye(3), np.array([0.0, np.nan, 1.0]))}, "pose"),
        ({"pose": 3.0}, "pose"),
        ({"color": "red"}, "color"),
        ({"color": (1, 2)}, "color"),
        ({"thickness": 0}, "thickness"),
        ({"dist_coeffs": np.zeros(3)}, "dist_coeffs"),
    ],
)
def test_draw_model_validation(change, name):
    image, camera, model, pose = _good()
    args = {"image": image, "camera": camera, "model": model, "pose": pose}
    kwargs = {k: change.pop(k) for k in list(change) if k not in args}
    args.update(change)
    with pytest.raises(ValueError, match=name):
        jp.viz.draw_model(args["image"], args["camera"], args["model"], args["pose"], **kwargs)


def test_overlay_and_render_validation():
    image, camera, model, pose = _good()
    with pytest.raises(ValueError, match="together"):
        jp.viz.overlay(image, camera, model, pose, vertices=np.arange(3))
    with pytest.raises(ValueError, match="vertices"):
        jp.viz.overlay(
            image, camera, model, pose, vertices=np.array([0, 99]), observed=np.zeros((2, 2))
        )
    with pytest.raises(ValueError, match="observed"):
        jp.viz.overlay(image, camera, model, pose, vertices=np.arange(3), observed=np.zeros((2, 2)))
    with pytest.raises(ValueError, match="marker"):
        jp.viz.draw_points(image, np.zeros((1, 2)), marker="star")
    with pytest.raises(ValueError, match="image_size"):
        jp.viz.render(camera, model, pose, (0, 10))
    with pytest.raises(ValueError, match="light"):
        jp.viz.render(camera, model, pose, (10, 10), light=(0, 0, 0))
    with pytest.raises(ValueError, match="bench"):
        jp.viz.render_bench("bench")
