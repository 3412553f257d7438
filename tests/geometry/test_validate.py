"""Tests of jaxpose.geometry._validate: the numpy boundary raises ValueError naming the argument."""

import numpy as np
import pytest

from jaxpose.geometry._validate import (
    as_camera,
    as_dist_coeffs,
    as_intrinsics,
    as_matching,
    as_points,
)

K = np.array([[800.0, 0.0, 320.0], [0.0, 780.0, 240.0], [0.0, 0.0, 1.0]])
C = np.hstack([K, np.array([[1.0], [2.0], [3.0]])])

# --------------------------------------------------------------------------- points


def test_as_points_layouts_and_dtypes():
    pts = np.arange(12, dtype=np.float64).reshape(4, 3)
    for layout in (pts, pts.reshape(4, 1, 3), pts.reshape(1, 4, 3), pts.tolist()):
        out = as_points(layout, "object_points", 3)
        assert out.shape == (4, 3) and out.dtype == np.float64
        np.testing.assert_array_equal(out, pts)
    assert as_points(pts.astype(np.float32), "p", 3).dtype == np.float32
    assert as_points(pts.astype(np.int32), "p", 3).dtype == np.float64
    assert as_points(pts.astype(np.float16), "p", 3).dtype == np.float64
    one = as_points(np.zeros((1, 1, 2)), "image_points", 2)
    assert one.shape == (1, 2)


@pytest.mark.parametrize(
    "bad",
    [
        np.zeros((4, 2)),
        np.zeros((5, 4)),  # neither (n, 3) nor (3, n)
        np.zeros(3),
        np.zeros((2, 2, 3)),
        np.zeros((4, 1, 2)),
        np.zeros((0, 3)),
        np.zeros((1, 4, 3, 1)),
        5.0,
    ],
)
def test_as_points_rejects_shapes(bad):
    with pytest.raises(ValueError, match="object_points"):
        as_points(bad, "object_points", 3)


def test_as_points_reads_the_transposed_layout():
    """`(3, n)` with `n != 3` is one point per column; `(3, 3)` one per row, as cv2."""
    pts = np.arange(12.0).reshape(4, 3)
    np.testing.assert_array_equal(as_points(pts.T, "object_points", 3), pts)
    square = np.arange(9.0).reshape(3, 3)
    np.testing.assert_array_equal(as_points(square, "object_points", 3), square)


def test_as_points_rejects_values():
    pts = np.zeros((4, 3))
    for value in (np.nan, np.inf, -np.inf):
        bad = pts.copy()
        bad[2, 1] = value
        with pytest.raises(ValueError, match="model_points.*NaN or infinite"):
            as_points(bad, "model_points", 3)
    with pytest.raises(ValueError, match="model_points.*real numbers"):
        as_points(pts.astype(complex), "model_points", 3)
    with pytest.raises(ValueError, match="model_points.*real numbers"):
        as_points(pts.astype(bool), "model_points", 3)
    with pytest.raises(ValueError, match="model_points.*real numbers"):
        as_points([["a", "b", "c"]], "model_points", 3)
    with pytest.raises(ValueError, match="model_points"):
        as_points([[1, 2, 3], [1, 2]], "model_points", 3)  # ragged
    with pytest.raises(ValueError, match="model_points is required"):
        as_points(None, "model_points", 3)


def test_as_points_min_count():
    assert as_points(np.zeros((3, 2)), "image_points", 2, min_count=3).shape == (3, 2)
    with pytest.raises(ValueError, match="image_points needs at least 4 points, got 3"):
        as_points(np.zeros((3, 2)), "image_points", 2, min_count=4)


def test_as_matching():
    obj, img = as_matching(np.zeros((5, 1, 3)), np.zeros((1, 5, 2), dtype=np.float32))
    assert obj.shape == (5, 3) and img.shape == (5, 2) and img.dtype == np.float32
    with pytest.raises(ValueError, match="object_points has 5 points, image_points has 4"):
        as_matching(np.zeros((5, 3)), np.zeros((4, 2)))
    with pytest.raises(ValueError, match="image_points"):
        as_matching(np.zeros((5, 3)), np.zeros((5, 3)))
    with pytest.raises(ValueError, match="object_points"):
        as_matching(np.zeros((5, 2)), np.zeros((5, 2)))
    with pytest.raises(ValueError, match="object_points needs at least 4"):
        as_matching(np.zeros((3, 3)), np.zeros((3, 2)), min_count=4)


# --------------------------------------------------------------------------- camera


def test_as_camera():
    out = as_camera(C)
    assert out.shape == (3, 4) and out.dtype == np.float64
    np.testing.assert_array_equal(out, C)
    assert as_camera(C.astype(np.float32)).dtype == np.float32
    assert as_camera(-1e-3 * C).shape == (3, 4)  # any nonzero scale
    assert as_camera(C.tolist(), name="projection").shape == (3, 4)


def test_as_camera_rejects():
    with pytest.raises(ValueError, match="camera must be a 3x4"):
        as_camera(K)
    with pytest.raises(ValueError, match="projection must be a 3x4"):
        as_camera(C.T, name="projection")
    bad = C.copy()
    bad[1, 3] = np.nan
    with pytest.raises(ValueError, match="camera contains NaN"):
        as_camera(bad)
    singular = C.copy()
    singular[2, :3] = singular[0, :3] * 2 + singular[1, :3]
    with pytest.raises(ValueError, match="camera: .*singular"):
        as_camera(singular)
    nearly = C.copy()
    nearly[2, :3] = singular[2, :3] * (1 + 1e-15)
    with pytest.raises(ValueError, match="C: .*singular"):
        as_camera(nearly, name="C")
    with pytest.raises(ValueError, match="camera: .*singular"):
        as_camera(np.zeros((3, 4)))
    with pytest.raises(ValueError, match="camera"):
        as_camera(None)


# --------------------------------------------------------------------------- intrinsics


def test_as_intrinsics():
    np.testing.assert_array_equal(as_intrinsics(K), K)
    assert as_intrinsics(K.astype(np.float32)).dtype == np.float32
    assert as_intrinsics((2 * K).astype(int)).dtype == np.float64
    assert as_intrinsics(-K).shape == (3, 3)  # fx / K[2,2] > 0 still
    skewed = K.copy()
    skewed[0, 1] = 1.5
    assert as_intrinsics(skewed)[0, 1] == 1.5


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda k: k[:2], "must be a 3x3"),
        (lambda k: np.where(np.eye(3, dtype=bool), np.nan, k), "NaN"),
        (lambda k: k * np.array([1, 1, 0])[:, None], r"\[2, 2\] must be nonzero"),
        (lambda k: k + np.array([[0, 0, 0], [0, 0, 0], [0.1, 0, 0]]), "upper triangular"),
        (lambda k: k * np.array([-1, 1, 1])[:, None], "positive focal"),
        (lambda k: k * np.array([1, 0, 1])[:, None], "positive focal"),
    ],
)
def test_as_intrinsics_rejects(change, message):
    with pytest.raises(ValueError, match=f"camera_matrix.*{message}"):
        as_intrinsics(change(K.copy()))
    with pytest.raises(ValueError, match="^K"):
        as_intrinsics(change(K.copy()), name="K")


def test_as_intrinsics_rejects_singular():
    with pytest.raises(ValueError, match="camera_matrix.*singular"):
        as_intrinsics(np.array([[1e-20, 0, 320.0], [0, 1e-20, 240.0], [0, 0, 1.0]]))


# --------------------------------------------------------------------------- distortion


def test_as_dist_coeffs():
    assert as_dist_coeffs(None) is None
    assert as_dist_coeffs(np.zeros(5)) is None
    assert as_dist_coeffs(np.zeros((1, 8))) is None
    assert as_dist_coeffs([]) is None
    for k in (4, 5, 8, 12, 14):
        d = np.arange(1, k + 1, dtype=np.float32) * 1e-3
        for layout in (d, d.reshape(-1, 1), d.reshape(1, -1), d.tolist()):
            out = as_dist_coeffs(layout)
            assert out.shape == (k,) and out.dtype == np.float64
            np.testing.assert_allclose(out, d, rtol=1e-7)


@pytest.mark.parametrize(
    ("bad", "message"),
    [
        (np.ones(3), "must have 4, 5, 8, 12, 14 elements, got 3"),
        (np.ones(6), "got 6"),
        (np.ones((2, 4)), "must be a vector"),
        (np.ones((1, 1, 5)), "must be a vector"),
        (np.array([0.1, np.nan, 0, 0, 0]), "NaN"),
        (np.array(["a"] * 5), "real numbers"),
    ],
)
def test_as_dist_coeffs_rejects(bad, message):
    with pytest.raises(ValueError, match=f"dist_coeffs.*{message}"):
        as_dist_coeffs(bad)
    with pytest.raises(ValueError, match="^distortion"):
        as_dist_coeffs(bad, name="distortion")
