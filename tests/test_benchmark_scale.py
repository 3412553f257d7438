"""The scaling benchmark (`benchmarks/scale.py`) on a tiny configuration: its JSON, its
plot and the sanity of every figure (positive, finite), without worker processes."""

import json
import math

from benchmarks import scale


def _positive(x) -> bool:
    return isinstance(x, (int, float)) and math.isfinite(x) and x > 0


def test_strategies_and_switch():
    # Below 2000 triplets the sample is the exhaustive set; above, both are measured.
    assert [c["strategy"] for c in scale._strategies(16, 10**6)] == ["exhaustive", "budget8"]
    assert [c["strategy"] for c in scale._strategies(50, 10**6)] == [
        "exhaustive",
        "sampled",
        "budget8",
    ]
    assert [c["strategy"] for c in scale._strategies(200, 10**5)] == ["sampled", "budget8"]
    assert scale._batch_configs((10, 10_000), True, 1000, (1000, 100)) == [
        (10, None),
        (10_000, 1000),
        (10_000, 100),
    ]
    rows = [
        {"n": 50, "strategy": "exhaustive", "warm_s": 1.0, "error_px": 1.0},
        {"n": 50, "strategy": "sampled", "warm_s": 0.1, "error_px": 1.0},
    ]
    sw = scale._switch(rows)
    assert sw["library_switch_n"] == 24 and sw["exhaustive_stops_paying_n"] == 50


def test_tiny_run(tmp_path):
    # One compiled program per section (three_point compiles fastest): n = 4, and batches
    # of 2 (one call) and 4 (two chunks of 2, the same program).
    res = scale.main(
        [
            "--n", "4",
            "--batch", "2", "4",
            "--one-call-max", "2",
            "--chunks", "2",
            "--method", "three_point",
            "--repeat", "2",
            "--quick",
            "--in-process",
            "--no-cache",
            "--out", str(tmp_path),
        ]
    )  # fmt: skip
    data = json.loads((tmp_path / "scale_quick.json").read_text())
    assert (tmp_path / "scale_quick.png").stat().st_size > 0
    assert set(data) >= {"n", "batch", "cache", "targets", "machine", "load_average", "quick"}
    assert data["quick"] and data["cache"]["rows"] == []
    assert data["n"]["switch"]["library_switch_n"] == 24
    (row,) = data["n"]["rows"]
    assert row["n"] == 4 and row["strategy"] == "exhaustive" and row["triplets_solved"] == 4
    for key in ("warm_s", "compile_s", "first_call_s", "lower_s", "xla_compile_s", "error_px"):
        assert _positive(row[key]), key
    assert _positive(row["memory"]["peak_bytes"])
    assert math.isfinite(row["rss_growth_mb"]) and row["rss_growth_mb"] >= 0
    assert row["run_rss_growth_mb"] is None or row["run_rss_growth_mb"] >= 0
    rows = data["batch"]["rows"]
    # B = 2 in one call runs the smallest batch bucket (16 problems); B = 4 in chunks of 2
    assert [(r["B"], r["chunk"]) for r in rows] == [(2, 16), (4, 2)]
    for r in rows:
        for key in ("warm_s", "per_problem_us", "opencv_per_problem_us", "vs_opencv"):
            assert _positive(r[key]), key
        assert _positive(r["memory"]["peak_bytes"]) and r["ok"] == 1.0
    # A chunk of 16 problems needs more memory than a chunk of 2.
    assert rows[0]["memory"]["peak_bytes"] > rows[1]["memory"]["peak_bytes"]
    assert res["batch"]["rows"][1]["B"] == 4
