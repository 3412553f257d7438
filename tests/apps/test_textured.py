"""Tests of jaxpose.apps._textured: a textured object's pose from a photograph (OpenCV's
cookie box), matches to pose by jaxpose's robust mode, compared with
`cv2.solvePnPRansac` on the same matches."""

import time

import cv2
import numpy as np
import pytest

from jaxpose.apps import TexturedPose, locate_matches, locate_textured, read_ply, sample_path
from jaxpose.apps._bench import random_rotation
from jaxpose.features import Matches, read_textured_model

DATA = sample_path("opencv_pose_box")
K = np.array([[1384.484, 0.0, 359.0], [0.0, 1385.235, 240.0], [0.0, 0.0, 1.0]])
# The box's pose in this photograph (jaxpose/data/README.md, opencv_pose_box/), and the
# pixels its eight vertices project to.
RVEC = np.array([2.0544509, -0.7867391, 0.3140298])
TVEC = np.array([-1.0903726, 11.6255476, 91.0700533])


@pytest.fixture(scope="module")
def box():
    return read_ply(DATA / "box.ply")


@pytest.fixture(scope="module")
def model():
    return read_textured_model(DATA / "cookies_ORB.yml.gz")


@pytest.fixture(scope="module")
def photo():
    return cv2.imread(str(DATA / "resized_IMG_3875.JPG"))


@pytest.fixture(scope="module")
def located(photo, model):
    start = time.perf_counter()
    pose = locate_textured(photo, model, K)
    return pose, time.perf_counter() - start


def vertex_errors(box, rvec, tvec) -> np.ndarray:
    reference = cv2.projectPoints(box.vertices, RVEC, TVEC, K, None)[0].reshape(-1, 2)
    ours = cv2.projectPoints(box.vertices, rvec, tvec, K, None)[0].reshape(-1, 2)
    return np.linalg.norm(ours - reference, axis=1)


def test_box_photograph(located, box, model):
    pose, seconds = located
    assert isinstance(pose, TexturedPose) and pose.ok
    n = len(pose.matches.distance)
    assert n >= 80 and pose.inliers.shape == (n,) and pose.inliers.sum() >= 0.5 * n
    assert pose.rvec.shape == (3, 1) and pose.tvec.shape == (3, 1)
    assert 0 < pose.rms < 4.0
    errors = vertex_errors(box, pose.rvec, pose.tvec)
    print(
        f"\njaxpose: {n} matches, {pose.inliers.sum()} inliers, rms {pose.rms:.3f} px, "
        f"vertex errors max {errors.max():.3f} px (mean {errors.mean():.3f}), {seconds:.2f} s"
    )
    assert errors.max() < 3.0


def test_same_matches_as_opencv(located, box):
    pose, _ = located
    m = pose.matches
    cv2.setRNGSeed(0)
    start = time.perf_counter()
    ok, rvec, tvec, inliers = cv2.solvePnPRansac(
        m.object_points, m.image_points, K, None, reprojectionError=8.0
    )
    seconds = time.perf_counter() - start
    assert ok
    theirs = vertex_errors(box, rvec, tvec)
    ours = vertex_errors(box, pose.rvec, pose.tvec)
    print(
        f"\ncv2.solvePnPRansac: {len(inliers)} inliers, vertex errors max "
        f"{theirs.max():.3f} px (mean {theirs.mean():.3f}), {seconds * 1e3:.1f} ms; "
        f"jaxpose max {ours.max():.3f} px"
    )
    assert ours.max() <= theirs.max() + 0.5
    assert pose.inliers.sum() >= len(inliers) - 5


def test_synthetic_matches_with_outliers(located, model, box):
    """The model's own points seen at random poses, 30 % of the matches wrong: the pose
    comes back (as many matches as the photograph's, so the compiled program is reused)."""
    n = len(located[0].matches.distance)
    rng = np.random.default_rng(7)
    for _ in range(3):
        index = rng.choice(len(model.points), n, replace=False)
        R = random_rotation(rng)
        rvec = cv2.Rodrigues(R)[0]
        centre = box.vertices.mean(axis=0)
        tvec = (
            np.array([rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(80, 120)]) - R @ centre
        ).reshape(3, 1)
        pixels = cv2.projectPoints(model.points[index], rvec, tvec, K, None)[0].reshape(-1, 2)
        wrong = rng.random(n) < 0.3
        pixels[wrong] = rng.uniform([0, 0], [718, 480], size=(wrong.sum(), 2))
        matches = Matches(model.points[index], pixels, np.zeros(n), index)
        pose = locate_matches(matches, K)
        assert pose.ok
        assert pose.inliers[~wrong].all()
        errors = np.linalg.norm(
            cv2.projectPoints(box.vertices, pose.rvec, pose.tvec, K, None)[0]
            - cv2.projectPoints(box.vertices, rvec, tvec, K, None)[0],
            axis=-1,
        )
        assert errors.max() < 1e-3
        assert pose.rms < 1e-3


def test_blank_image_fails_cleanly(model):
    pose = locate_textured(np.full((480, 640, 3), 200, np.uint8), model, K)
    assert not pose.ok
    assert len(pose.matches.distance) == 0 and pose.inliers.shape == (0,)
    for value in (pose.rvec, pose.tvec, pose.rms):
        assert np.all(np.isfinite(value))
    np.testing.assert_array_equal(pose.rvec, np.zeros((3, 1)))


def test_too_few_matches_fail_cleanly(model):
    few = Matches(model.points[:3], np.array([[1.0, 2], [3, 4], [5, 7]]), np.zeros(3), np.arange(3))
    pose = locate_matches(few, K)
    assert not pose.ok and pose.inliers.shape == (3,) and not pose.inliers.any()
    assert np.all(np.isfinite(pose.tvec)) and pose.rms == 0.0


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"threshold": 0.0}, "threshold"),
        ({"threshold": float("nan")}, "threshold"),
        ({"detector": "brisk"}, "detector"),
        ({"ratio": 2.0}, "ratio"),
        ({"features": -1}, "features"),
        ({"min_inliers": 1}, "min_inliers"),
        ({"no_such_option": 1}, "no_such_option"),
    ],
)
def test_option_errors(model, kwargs, name):
    with pytest.raises(ValueError, match=name):
        locate_textured(np.zeros((8, 8), np.uint8), model, K, **kwargs)


def test_argument_errors(model):
    image = np.zeros((8, 8), np.uint8)
    with pytest.raises(ValueError, match="camera_matrix"):
        locate_textured(image, model, np.eye(2))
    with pytest.raises(ValueError, match="dist_coeffs"):
        locate_textured(image, model, K, np.zeros(3))
    with pytest.raises(ValueError, match="model"):
        locate_textured(image, None, K)
    with pytest.raises(ValueError, match="image"):
        locate_textured(np.zeros((8, 8)), model, K)
    with pytest.raises(ValueError, match="matches"):
        locate_matches((np.zeros((4, 3)), np.zeros((4, 2))), K)
    bad = Matches(np.zeros((4, 3)), np.full((4, 2), np.nan), np.zeros(4), np.arange(4))
    with pytest.raises(ValueError, match="image_points"):
        locate_matches(bad, K)
