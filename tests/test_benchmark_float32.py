"""The float32 benchmark (`benchmarks/float32.py`): its per-cell figures on synthetic
answers, and a tiny end-to-end run (one cell, two trials, the quickest method to compile,
no P3P section): its JSON keys and finite numbers."""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from benchmarks import _protocol as protocol
from benchmarks import float32 as bench

STATS = {"median", "p99", "max"}


def _finite(x) -> bool:
    return isinstance(x, (int, float)) and math.isfinite(x)


def test_compare_figures():
    cell = protocol.make_cell("ordinary", 6, 0.0, 4)  # noise-free: the true pose is optimal
    R, t = cell.R.copy(), cell.t.copy()
    ok = np.ones(4, bool)
    a64 = protocol.Answers(R, t, ok, 1.0)
    # trial 0 identical, trial 1 rotated by 0.01 deg about z, trial 2 failed in float32,
    # trial 3 failed in float64 only
    c, s = np.cos(np.radians(0.01)), np.sin(np.radians(0.01))
    R32 = R.copy()
    R32[1] = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) @ R[1]
    ok32 = np.array([True, True, False, True])
    a32 = protocol.Answers(R32, t.copy(), ok32, 1.0)
    a64.ok = np.array([True, True, True, False])
    row = bench.compare(cell, a64, a32)
    assert row["rotation_diff_deg"]["max"] == pytest.approx(0.01, rel=1e-6)
    assert row["rotation_diff_deg"]["median"] == pytest.approx(0.005, rel=1e-6)
    assert row["translation_rel_diff"]["max"] == 0
    assert row["float32_failed_float64_ok"] == 0.25
    assert row["float64_failed_float32_ok"] == 0.25
    # trial 0 is at the optimum, trial 1 not: a 0.01 deg turn moves pixels by ~0.1 px
    assert row["rms_diff_px"]["max"] > 10 * bench.RMS_TOL
    assert row["at_float64_optimum"] == pytest.approx(1 / 3)
    assert 0 <= row["rounding_floor_px"]["max"] < 1e-3


def test_tiny_run(tmp_path):
    res = bench.run(
        True,
        tmp_path,
        kinds=["ordinary"],
        ns=[4],
        sigmas=[0.5],
        trials=2,
        method="three_point",
        p3p_n=0,
        verbose=False,
    )
    path = tmp_path / "float32_quick.json"
    assert Path(res["path"]) == path and path.exists()
    saved = json.loads(path.read_text())
    assert {"protocol", "cells", "summary", "p3p", "machine", "versions"} <= set(saved)
    assert saved["p3p"] is None
    (cell,) = saved["cells"]
    assert (cell["kind"], cell["n"], cell["sigma"], cell["trials"]) == ("ordinary", 4, 0.5, 2)
    for key in ("rotation_diff_deg", "translation_rel_diff", "rms_diff_px", "rounding_floor_px"):
        assert set(cell[key]) == STATS
        assert all(_finite(v) for v in cell[key].values()), (key, cell[key])
    for key in (
        "ok_float64",
        "ok_float32",
        "at_float64_optimum",
        "float32_failed_float64_ok",
        "float64_failed_float32_ok",
    ):
        assert _finite(cell[key]) and 0 <= cell[key] <= 1
    assert cell["ok_float64"] == 1.0  # noisy n = 4 problems with one accepted triplet
    # float32 moves the answer, but only a little (degrees, relative)
    assert 0 < cell["rotation_diff_deg"]["max"] < 0.5
    assert cell["translation_rel_diff"]["max"] < 1e-2
    assert all(_finite(v) for v in saved["summary"].values())
