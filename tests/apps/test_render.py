"""Tests of jaxpose.apps._render: drawn images agree with the projected model, textures
move with the pose, the options do what they say, trajectories are smooth."""

import cv2
import numpy as np
import pytest

from jaxpose.apps import (
    Polyhedron,
    face_mask,
    face_textures,
    noise_texture,
    read_ply,
    render,
    render_sequence,
    sample_path,
    smooth_trajectory,
)

BOX = read_ply(sample_path("opencv_pose_box", "box.ply"))
K = np.array([[800.0, 0.0, 320.0], [0.0, 800.0, 240.0], [0.0, 0.0, 1.0]])
SIZE = (640, 480)
# A 20 x 20 square facing the camera (its normal along -z, towards it).
SQUARE = Polyhedron(
    "square",
    np.array([[0, 0, 0], [0, 20, 0], [20, 20, 0], [20, 0, 0]], float),
    np.array([[0, 1], [1, 2], [2, 3], [0, 3]]),
    ((0, 1, 2, 3),),
)


def _box_pose():
    R = cv2.Rodrigues(np.array([2.2, -0.6, 0.4]))[0]
    return R, np.array([0.0, 0.0, 80.0]) - R @ BOX.vertices.mean(axis=0)


@pytest.mark.parametrize("dist", [None, np.array([-0.15, 0.05, 0.0, 0.0, 0.0])])
def test_box_drawn_where_it_projects(dist):
    R, t = _box_pose()
    image = render(BOX, K, dist, R, t, SIZE, background=0, ambient=0.3)
    mask = face_mask(BOX, K, dist, R, t, SIZE)
    inner = cv2.erode(mask, np.ones((5, 5), np.uint8)) > 0
    outer = cv2.dilate(mask, np.ones((3, 3), np.uint8)) == 0
    assert image[inner].min() >= 0.3 * 255 - 1 and np.all(image[outer] == 0)
    _, counts = np.unique(image[inner], return_counts=True)
    assert np.sort(counts)[-3:].sum() > 0.97 * inner.sum()  # three flat faces (and creases)


@pytest.mark.parametrize("x0", [100.0, 100.3, 100.55, 100.8])
def test_edges_land_within_a_fraction_of_a_pixel(x0):
    # The square spans x0 .. x0 + 200 px and 40 .. 240 px at depth 80 (f = 800: 10 px/unit).
    t = np.array([(x0 - 320) / 10, (40 - 240) / 10, 80.0])
    for s in (4, 8):
        image = render(
            SQUARE, K, None, np.eye(3), t, SIZE, shades=[255.0], background=0, supersample=s
        )
        covered = image[140].astype(float).sum() / 255
        assert abs(covered - 200.0) <= 1.0 / s + 0.02  # each edge within 1/(2s) px
        left = np.flatnonzero(image[140] > 0)[0]
        assert abs(left - x0) < 1.0


def test_texture_moves_with_the_pose():
    texture = noise_texture(128, feature=2.0, seed=3)
    assert texture.dtype == np.uint8 and texture.std() > 30
    t0 = np.array([-10.0, -10.0, 80.0])
    shift = np.array([0.037, -0.052, 0.0])  # model units: (0.37, -0.52) px
    a = render(
        SQUARE, K, None, np.eye(3), t0, SIZE, texture=texture, texture_scale=0.05, shades=[255.0]
    )
    b = render(
        SQUARE,
        K,
        None,
        np.eye(3),
        t0 + shift,
        SIZE,
        texture=texture,
        texture_scale=0.05,
        shades=[255.0],
    )
    crop = (slice(180, 300), slice(260, 380))
    assert a[crop].std() > 10
    (dx, dy), _ = cv2.phaseCorrelate(a[crop].astype(np.float64), b[crop].astype(np.float64))
    assert abs(dx - 0.37) < 0.08 and abs(dy + 0.52) < 0.08


def test_box_textured_from_its_photograph():
    photo = cv2.imread(str(sample_path("opencv_pose_box", "resized_IMG_3875.JPG")))
    K_photo = np.array([[1384.484, 0, 359], [0, 1385.235, 240], [0, 0, 1.0]])
    R = cv2.Rodrigues(np.array([2.05445, -0.78674, 0.31403]))[0]  # the reference pose
    t = np.array([-1.0904, 11.6255, 91.0701])
    textures = face_textures(photo, BOX, K_photo, None, R, t, texture_scale=0.05)
    assert len(textures) == len(BOX.faces) and all(x.dtype == np.uint8 for x in textures)
    grey = cv2.cvtColor(photo, cv2.COLOR_BGR2GRAY)
    again = render(
        BOX,
        K_photo,
        None,
        R,
        t,
        (718, 480),
        texture=textures,
        texture_scale=0.05,
        shades=[255.0] * 6,
        background=grey,
    )
    inside = face_mask(BOX, K_photo, None, R, t, (718, 480), erode=3) > 0
    a, b = again[inside].astype(float), grey[inside].astype(float)
    assert np.corrcoef(a, b)[0, 1] > 0.9 and np.median(np.abs(a - b)) < 6
    away = cv2.dilate(face_mask(BOX, K_photo, None, R, t, (718, 480)), np.ones((9, 9))) == 0
    diff = np.abs(again[away].astype(float) - grey[away])
    assert np.median(diff) <= 2  # the background, resampled up and down
    with pytest.raises(ValueError, match="photograph"):
        face_textures(photo.astype(float), BOX, K_photo, None, R, t)


def test_options():
    R, t = _box_pose()
    plain = render(BOX, K, None, R, t, SIZE, supersample=2).astype(float)
    bright = render(BOX, K, None, R, t, SIZE, gain=1.2, offset=5, supersample=2).astype(float)
    np.testing.assert_allclose(bright, np.clip(np.round(plain * 1.2 + 5), 0, 255), atol=1.5)
    hidden = render(
        BOX, K, None, R, t, SIZE, occluder=(300, 200, 360, 260), occluder_grey=7, supersample=2
    )
    assert np.all(hidden[200:260, 300:360] == 7)
    noisy = render(BOX, K, None, R, t, SIZE, noise=4.0, supersample=2).astype(float)
    assert 3.0 < np.std(noisy - plain) < 5.0
    blurred = render(BOX, K, None, R, t, SIZE, blur=2.0, supersample=2).astype(float)
    assert np.abs(np.diff(blurred, axis=1)).max() < np.abs(np.diff(plain, axis=1)).max()
    background = np.full((480, 640), 90, np.uint8)
    on = render(BOX, K, None, R, t, SIZE, background=background, supersample=2)
    assert on[0, 0] == 90
    shades = render(BOX, K, None, R, t, SIZE, shades=np.linspace(50, 250, 6), supersample=2)
    assert len(np.unique(shades)) > 3


def test_trajectory_and_sequence():
    R0, t0 = _box_pose()
    centre = BOX.vertices.mean(axis=0)
    Rs, ts = smooth_trajectory(R0, t0, 50, centre=centre, rotation=8.0, translation=3.0)
    assert Rs.shape == (50, 3, 3) and ts.shape == (50, 3)
    np.testing.assert_allclose(Rs[0], R0, atol=1e-12)
    np.testing.assert_allclose(ts[0], t0, atol=1e-12)
    steps = [np.degrees(np.linalg.norm(cv2.Rodrigues(b @ a.T)[0])) for a, b in zip(Rs, Rs[1:])]
    assert max(steps) < 2.0 and max(steps) > 0.1
    moves = np.linalg.norm(np.diff(Rs @ centre + ts, axis=0), axis=1)
    assert moves.max() < 1.0
    frames = list(render_sequence(BOX, K, None, Rs[:3], ts[:3], SIZE, noise=2.0, supersample=2))
    assert len(frames) == 3 and frames[0].shape == (480, 640) and frames[0].dtype == np.uint8
    assert not np.array_equal(frames[0], frames[1])


def test_bad_arguments():
    R, t = _box_pose()
    with pytest.raises(ValueError, match="image_size"):
        render(BOX, K, None, R, t, (0, 4))
    with pytest.raises(ValueError, match="supersample"):
        render(BOX, K, None, R, t, SIZE, supersample=0)
    with pytest.raises(ValueError, match="shades"):
        render(BOX, K, None, R, t, SIZE, shades=[1.0, 2.0])
    with pytest.raises(ValueError, match="texture"):
        render(BOX, K, None, R, t, SIZE, texture=np.zeros((4, 4)))
    with pytest.raises(ValueError, match="background"):
        render(BOX, K, None, R, t, SIZE, background=np.zeros((4, 4), np.uint8))
    with pytest.raises(ValueError, match="noise"):
        render(BOX, K, None, R, t, SIZE, noise=-1)
    with pytest.raises(ValueError, match="gain"):
        render(BOX, K, None, R, t, SIZE, gain=float("nan"))
    with pytest.raises(ValueError, match="occluder"):
        render(BOX, K, None, R, t, SIZE, occluder=(1, 2, 3))
    with pytest.raises(ValueError, match="count"):
        smooth_trajectory(R, t, 0)
    with pytest.raises(ValueError, match="Rs"):
        render_sequence(BOX, K, None, np.eye(3), t, SIZE)
    with pytest.raises(ValueError, match="size"):
        noise_texture(2)
