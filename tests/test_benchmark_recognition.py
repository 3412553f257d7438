"""`benchmarks/recognition.py` on a few scenes: its figures are what it says."""

from benchmarks import recognition


def test_a_few_scenes():
    res = recognition.scenes(2, 1, seed=0)
    assert res["scenes"] == 2 and res["empty_scenes"] == 1
    assert res["right"] == 1.0 and res["right_verdict"] == "met"
    assert res["false_detections"] == 0 and res["false_verdict"] == "met"
    assert 0 < res["median_rms_px"] < 2.0
    assert res["seconds_per_image_median"] > 0
