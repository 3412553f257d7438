"""`examples/box_photograph.py`: the documentation's figure of the box photograph is drawn
from its saved result, which holds one box detection and the keypoint path's pose."""

import importlib.util
import json
from pathlib import Path

import cv2

PATH = Path(__file__).resolve().parents[1] / "examples" / "box_photograph.py"


def test_figure_from_the_saved_result(tmp_path):
    spec = importlib.util.spec_from_file_location("box_photograph", PATH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    saved = json.loads(module.RESULT.read_text())
    assert [d["model"] for d in saved["detections"]] == ["box"]
    assert saved["keypoints"]["ok"] and saved["keypoints"]["inliers"] >= 50
    assert module.main(["--draw-only", "--out", str(tmp_path)]) == 0
    picture = cv2.imread(str(tmp_path / "box_photograph.png"))
    assert picture.shape == (480, 2 * 718, 3)
