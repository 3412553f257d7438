"""`examples/track_video.py`: the box recognised in the video's first frame and tracked
through the next ones, the drawn video and the poses written."""

import importlib.util
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

PATH = Path(__file__).resolve().parents[1] / "examples" / "track_video.py"


@pytest.mark.slow  # (the first recognition compiles the robust mode)
def test_tracks_the_first_frames(tmp_path):
    spec = importlib.util.spec_from_file_location("track_video", PATH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    figure = tmp_path / "figure.jpg"
    args = ["--frames", "12", "--out", str(tmp_path), "--compare", "11", "--figure", str(figure)]
    assert module.main(args) == 0
    assert cv2.imread(str(figure)).shape == (480, 640, 3)
    saved = json.loads((tmp_path / "track_video.json").read_text())
    frames = saved["frames"]
    assert len(frames) == 12 and all(f["ok"] for f in frames)
    assert min(f["edges"] for f in frames) > 40 and min(f["points"] for f in frames[1:]) > 40
    # The box barely moves in the first frames: the poses stay together.
    tvecs = np.array([f["tvec"] for f in frames])
    assert np.ptp(tvecs, axis=0).max() < 5.0  # cm, at about 150 cm
    video = cv2.VideoCapture(str(tmp_path / "track_video.mp4"))
    assert int(video.get(cv2.CAP_PROP_FRAME_COUNT)) == 12
    video.release()
