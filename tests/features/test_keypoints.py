"""Tests of jaxpose.features._keypoints: OpenCV's textured model read, and the box
photograph's keypoints matched to it."""

import cv2
import numpy as np
import pytest

from jaxpose.apps import sample_path
from jaxpose.features import Matches, TexturedModel, match_keypoints, read_textured_model

DATA = sample_path("opencv_pose_box")
K = np.array([[1384.484, 0.0, 359.0], [0.0, 1385.235, 240.0], [0.0, 0.0, 1.0]])
# The box's pose in this photograph (jaxpose/data/README.md, opencv_pose_box/).
RVEC = np.array([2.0544509, -0.7867391, 0.3140298])
TVEC = np.array([-1.0903726, 11.6255476, 91.0700533])


@pytest.fixture(scope="module")
def model():
    return read_textured_model(DATA / "cookies_ORB.yml.gz")


@pytest.fixture(scope="module")
def photo():
    image = cv2.imread(str(DATA / "resized_IMG_3875.JPG"))
    assert image is not None and image.shape == (480, 718, 3)
    return image


def test_read_textured_model(model):
    assert isinstance(model, TexturedModel)
    assert model.name == "cookies_ORB"
    assert model.points.shape == (5914, 3) and model.points.dtype == np.float64
    assert model.descriptors.shape == (5914, 32) and model.descriptors.dtype == np.uint8
    # The points lie on the box (18.9 x 25.8 x 7.5 cm), on its faces.
    assert np.all(model.points > -1e-3) and np.all(model.points < [18.91, 25.81, 7.51])


def test_read_textured_model_errors(tmp_path):
    with pytest.raises(ValueError, match="nothing.yml"):
        read_textured_model(tmp_path / "nothing.yml")
    with pytest.raises(ValueError, match="path"):
        read_textured_model(None)
    fs = cv2.FileStorage(str(tmp_path / "half.yml"), cv2.FILE_STORAGE_WRITE)
    fs.write("points_3d", np.zeros((4, 3)))
    fs.release()
    with pytest.raises(ValueError, match="descriptors"):
        read_textured_model(tmp_path / "half.yml")
    fs = cv2.FileStorage(str(tmp_path / "uneven.yml"), cv2.FILE_STORAGE_WRITE)
    fs.write("points_3d", np.zeros((4, 3)))
    fs.write("descriptors", np.zeros((3, 32), np.uint8))
    fs.release()
    with pytest.raises(ValueError, match="descriptors"):
        read_textured_model(tmp_path / "uneven.yml", name="x")


def test_photograph_matches_lie_on_the_box(model, photo):
    matches = match_keypoints(photo, model)
    n = len(matches.distance)
    assert n >= 80
    assert matches.object_points.shape == (n, 3) and matches.image_points.shape == (n, 2)
    np.testing.assert_array_equal(matches.object_points, model.points[matches.model_index])
    projected = cv2.projectPoints(matches.object_points, RVEC, TVEC, K, None)[0].reshape(-1, 2)
    error = np.linalg.norm(projected - matches.image_points, axis=1)
    assert np.mean(error < 8.0) > 0.6  # most matches are right
    # A path reads the same as the array; grayscale gives the same keypoints.
    again = match_keypoints(DATA / "resized_IMG_3875.JPG", model)
    gray = match_keypoints(cv2.cvtColor(photo, cv2.COLOR_BGR2GRAY), model)
    np.testing.assert_array_equal(again.image_points, matches.image_points)
    np.testing.assert_array_equal(gray.image_points, matches.image_points)
    # A stricter ratio keeps fewer matches; ratio 1 keeps one per keypoint.
    assert len(match_keypoints(photo, model, ratio=0.6).distance) < n
    assert len(match_keypoints(photo, model, ratio=1.0, features=500).distance) >= 400


def test_sift_matches_a_sift_model_to_itself(photo):
    gray = cv2.cvtColor(photo, cv2.COLOR_BGR2GRAY)
    keypoints, descriptors = cv2.SIFT_create(nfeatures=300).detectAndCompute(gray, None)
    pixels = np.array([k.pt for k in keypoints])
    points = np.column_stack([pixels, np.arange(len(pixels), dtype=np.float64)])
    sift = TexturedModel(points, descriptors, "self")
    matches = match_keypoints(photo, sift, detector="sift", features=300)
    assert len(matches.distance) > 100
    exact = matches.distance < 1e-3
    assert np.mean(exact) > 0.9
    np.testing.assert_allclose(
        matches.object_points[exact, :2], matches.image_points[exact], atol=1e-3
    )
    with pytest.raises(ValueError, match="model"):
        match_keypoints(photo, sift)  # an ORB search in a SIFT model


def test_blank_image_has_no_matches(model):
    matches = match_keypoints(np.full((480, 640), 128, np.uint8), model)
    assert isinstance(matches, Matches)
    assert matches.object_points.shape == (0, 3) and matches.image_points.shape == (0, 2)
    assert matches.distance.shape == (0,) and matches.model_index.shape == (0,)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"detector": "surf"}, "detector"),
        ({"features": 0}, "features"),
        ({"features": 2.5}, "features"),
        ({"ratio": 0.0}, "ratio"),
        ({"ratio": 1.5}, "ratio"),
        ({"ratio": float("nan")}, "ratio"),
    ],
)
def test_option_errors(model, kwargs, name):
    with pytest.raises(ValueError, match=name):
        match_keypoints(np.zeros((8, 8), np.uint8), model, **kwargs)


def test_argument_errors(model, tmp_path):
    with pytest.raises(ValueError, match="image"):
        match_keypoints(np.zeros((8, 8), np.float32), model)
    with pytest.raises(ValueError, match="image"):
        match_keypoints(np.zeros((8, 8, 2), np.uint8), model)
    with pytest.raises(ValueError, match="image"):
        match_keypoints(tmp_path / "none.png", model)
    with pytest.raises(ValueError, match="image"):
        match_keypoints([[0, 1]], model)
    with pytest.raises(ValueError, match="model"):
        match_keypoints(np.zeros((8, 8), np.uint8), "cookies")
    bad = model._replace(points=model.points[:10])
    with pytest.raises(ValueError, match="model"):
        match_keypoints(np.zeros((8, 8), np.uint8), bad)
