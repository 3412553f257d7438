"""Tests of jaxpose.features._files: OpenCV camera files read and written."""

import numpy as np
import pytest

from jaxpose.apps import sample_path
from jaxpose.features import read_camera, write_camera

DATA = sample_path()
K = np.array([[800.0, 0.5, 320.0], [0.0, 810.0, 240.0], [0.0, 0.0, 1.0]])


@pytest.mark.parametrize("suffix", [".yml", ".yaml", ".xml", ".json", ".yml.gz"])
@pytest.mark.parametrize("size", [4, 5, 8, 14])
def test_round_trip(tmp_path, suffix, size):
    dist = np.linspace(-0.3, 0.2, size)
    path = tmp_path / f"camera{suffix}"
    write_camera(path, K, dist)
    K2, dist2 = read_camera(path)
    assert K2.dtype == np.float64 and dist2.dtype == np.float64
    np.testing.assert_array_equal(K2, K)
    np.testing.assert_array_equal(dist2, dist)


def test_no_distortion_reads_as_zeros(tmp_path):
    write_camera(tmp_path / "c.yml", K)
    _, dist = read_camera(str(tmp_path / "c.yml"))
    np.testing.assert_array_equal(dist, np.zeros(5))
    import cv2

    fs = cv2.FileStorage(str(tmp_path / "only_k.yml"), cv2.FILE_STORAGE_WRITE)
    fs.write("camera_matrix", K)
    fs.release()
    K2, dist = read_camera(tmp_path / "only_k.yml")
    np.testing.assert_array_equal(K2, K)
    np.testing.assert_array_equal(dist, np.zeros(5))


def test_reads_opencv_calibration_sample_output():
    K2, dist = read_camera(DATA / "chessboard" / "left_intrinsics.yml")
    assert K2.shape == (3, 3) and dist.shape == (5,)
    assert K2[0, 0] == pytest.approx(535.9157, abs=1e-3)
    assert dist[0] == pytest.approx(-0.26637, abs=1e-4)


def test_read_errors(tmp_path):
    with pytest.raises(ValueError, match="missing.yml"):
        read_camera(tmp_path / "missing.yml")
    with pytest.raises(ValueError, match="path"):
        read_camera(12)
    (tmp_path / "garbage.yml").write_text("%YAML:1.0\n: : [\n")
    with pytest.raises(ValueError, match="garbage.yml"):
        read_camera(tmp_path / "garbage.yml")
    import cv2

    fs = cv2.FileStorage(str(tmp_path / "no_k.yml"), cv2.FILE_STORAGE_WRITE)
    fs.write("distortion_coefficients", np.zeros((5, 1)))
    fs.release()
    with pytest.raises(ValueError, match="camera_matrix"):
        read_camera(tmp_path / "no_k.yml")
    fs = cv2.FileStorage(str(tmp_path / "bad.yml"), cv2.FILE_STORAGE_WRITE)
    fs.write("camera_matrix", K)
    fs.write("distortion_coefficients", np.zeros((3, 1)))
    fs.release()
    with pytest.raises(ValueError, match="distortion_coefficients"):
        read_camera(tmp_path / "bad.yml")
    fs = cv2.FileStorage(str(tmp_path / "bad_k.yml"), cv2.FILE_STORAGE_WRITE)
    fs.write("camera_matrix", np.ones((3, 3)))
    fs.release()
    with pytest.raises(ValueError, match="camera_matrix"):
        read_camera(tmp_path / "bad_k.yml")


def test_write_errors(tmp_path):
    path = tmp_path / "c.yml"
    with pytest.raises(ValueError, match="camera_matrix"):
        write_camera(path, np.eye(2))
    with pytest.raises(ValueError, match="camera_matrix"):
        write_camera(path, np.full((3, 3), np.nan))
    with pytest.raises(ValueError, match="dist_coeffs"):
        write_camera(path, K, np.zeros(3))
    with pytest.raises(ValueError, match="dist_coeffs"):
        write_camera(path, K, [np.nan] * 5)
    with pytest.raises(ValueError, match="dist_coeffs"):
        write_camera(path, K, np.zeros((2, 5)))
    with pytest.raises(ValueError, match="path"):
        write_camera(None, K)
    assert not path.exists()
