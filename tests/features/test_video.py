"""Tests of jaxpose.features._video: frames from a video file, a folder and a camera."""

import cv2
import numpy as np
import pytest

from jaxpose.apps import sample_path
from jaxpose.features import open_frames


def _write_folder(folder, count=12):
    folder.mkdir()
    for i in range(count):
        image = np.full((24, 32, 3), 10 * i, np.uint8)
        cv2.imwrite(str(folder / f"frame{i}.png"), image)
    (folder / "notes.txt").write_text("not an image")
    return folder


def test_folder_in_natural_order(tmp_path):
    folder = _write_folder(tmp_path / "seq")
    frames = open_frames(folder)
    assert frames.kind == "folder" and len(frames) == 12
    assert [p.name for p in frames.files][:3] == ["frame0.png", "frame1.png", "frame2.png"]
    got = list(frames)
    assert len(got) == 12 and got[0].shape == (24, 32, 3) and got[0].dtype == np.uint8
    assert [int(f[0, 0, 0]) for f in got] == [10 * i for i in range(12)]
    grey = list(open_frames(str(folder), gray=True, start=2, stop=5))
    assert [f.shape for f in grey] == [(24, 32)] * 3
    assert [int(f[0, 0]) for f in grey] == [20, 30, 40]
    assert len(open_frames(folder, start=10, stop=20)) == 2


def test_video_file(tmp_path):
    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (64, 48))
    assert writer.isOpened()
    for i in range(10):
        writer.write(np.full((48, 64, 3), 20 * i, np.uint8))
    writer.release()
    with open_frames(path, gray=True) as frames:
        assert frames.kind == "video" and len(frames) == 10
        assert frames.fps == pytest.approx(25.0)
        got = list(frames)
    assert len(got) == 10 and got[0].shape == (48, 64)
    np.testing.assert_allclose([f.mean() for f in got], 20 * np.arange(10), atol=3)
    part = list(open_frames(path, start=3, stop=6))
    assert len(part) == 3 and part[0].shape == (48, 64, 3)
    np.testing.assert_allclose([f.mean() for f in part], [60, 80, 100], atol=3)


def test_box_video():
    path = sample_path("opencv_pose_box", "box.mp4")
    frames = open_frames(path, gray=True, stop=5)
    got = list(frames)
    assert len(got) == 5 and got[0].shape == (480, 640) and got[0].dtype == np.uint8


def test_bad_sources(tmp_path):
    with pytest.raises(ValueError, match="source"):
        open_frames(tmp_path / "missing.mp4")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="source.*without images"):
        open_frames(tmp_path / "empty")
    (tmp_path / "junk.mp4").write_bytes(b"not a video")
    with pytest.raises(ValueError, match="source"):
        open_frames(tmp_path / "junk.mp4")
    with pytest.raises(ValueError, match="source"):
        open_frames(-1)
    with pytest.raises(ValueError, match="source"):
        open_frames(1.5)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="start"):
        open_frames(tmp_path, start=-1)
    with pytest.raises(ValueError, match="stop"):
        open_frames(0, start=3, stop=2)


def test_camera_is_opened_when_iterated():
    frames = open_frames(0, stop=3)
    assert frames.kind == "camera" and len(frames) == 3
    with pytest.raises(TypeError):
        len(open_frames(0))
