"""The speed benchmark (`benchmarks/speed.py`, printed by `benchmarks/run.py`): its cheap
sections run for real on tiny inputs, and the targets table has every target of
`TARGETS` with its figure, bound, verdict, peer and compile time (the expensive sections,
which compile the whole solver, are given stand-in figures here: `make bench` and `make
bench-quick` run them). Structure only: no timing is asserted."""

import io
import math

import numpy as np
from rich.console import Console

from benchmarks import run, speed
from benchmarks._harness import peak_memory_mb


def _stand_ins() -> dict:
    """Section results shaped like a run's, for the sections too slow to run here."""
    latency = {
        k: {
            "n": n,
            "ms": ms,
            "compile_s": 20.0,
            "sqpnp_lm_us": 150.0,
            "rms_px": 1.0,
            "sqpnp_lm_rms_px": 1.0,
        }
        for k, n, ms in (("bench", 16, 1.2), ("n54", 54, 2.5), ("n200", 200, 4.0))
    }
    return {
        "peers": {
            "triplets": 560,
            "opencv_loop_ms": 60.0,
            "poselib_loop_ms": 40.0,
            "sqpnp_lm_us": 150.0,
        },
        "paper": {"triplets": 560, "jaxpose_ms": 8.1, "compile_s": 20.0},
        "paper_phases": {
            "triplets": 560,
            "three_point_ms": 1.7,
            "step1_ms": 3.3,
            "step2_linear_ms": 6.3,
            "mixed_ms": 8.1,
            "solve_ms": 8.5,
        },
        "latency": latency,
        "batch": [
            {
                "B": 1000,
                "jaxpose_s": 0.2,
                "compile_s": 30.0,
                "per_problem_us": 200.0,
                "opencv_s": 0.1,
                "vs_opencv": 0.5,
                "at_optimum": 0.9995,
            }
        ],
        "classes": {
            "sizes": [200, 1000],
            "classes": {
                kind: {
                    "opencv_us": 100.0,
                    "growth": 1.1 + 0.1 * k,
                    **{
                        str(B): {
                            "jaxpose_s": B * 2e-5,
                            "compile_s": 20.0,
                            "per_problem_us": 20.0,
                            "vs_opencv": 5.0 + k,
                            "at_optimum": 1.0 - 0.0005 * k,
                            "ok": 1.0,
                        }
                        for B in (200, 1000)
                    },
                }
                for k, kind in enumerate(speed.CLASSES)
            },
        },
        "batch_memory": {
            "B": 1000,
            "peak_mb": 700.0,
            "vm_hwm_mb": 700.0,
            "rss_before_call_mb": 400.0,
            "first_call_s": 31.0,
            "warm_s": 0.2,
            "compile_s": 30.0,
        },
    }


def test_cheap_sections_and_the_targets_table():
    res = _stand_ins()
    res["p3p"] = speed.p3p(512, 2, peer_count=20)
    res["linear_step"] = speed.linear_step(64, 2, reference=False)
    q, ls = res["p3p"], res["linear_step"]
    assert q["triplets"] == 512 and math.isfinite(q["ns_per_triplet"]) and q["ns_per_triplet"] > 0
    assert q["opencv_ns_per_triplet"] > 0 and q["poselib_ns_per_triplet"] > 0
    assert 0.9 <= q["solved"] <= 1.0  # random triplets: nearly all have a root in front
    assert ls["problems"] == 64 and ls["n"] == 16 and ls["ns"] > 0

    T = speed.targets(res)
    assert list(T) == list(speed.TARGETS)
    for key, row in T.items():
        assert row["figure"] is not None and math.isfinite(row["figure"]), key
        assert row["met"] in (True, False), key
        assert row["verdict"] == "met" or row["verdict"].startswith("missed by"), key
        assert row["target"] == speed.TARGETS[key].bound
        assert row["compile_s"] is not None, key
    assert T["latency_vs_lean_opencv"]["figure"] == 60.0 / 1.2
    assert T["latency_vs_lean_opencv"]["verdict"] == "missed by 1.2x"
    assert T["batch_vs_loop"]["verdict"] == "missed by 16.0x"
    assert T["batch_at_optimum"]["met"] and T["batch_peak_mb"]["met"]
    assert T["latency_n54_ms"]["verdict"] == "missed by 1.2x"
    assert T["paper_ms"]["peer_figure"] == 60.0 and T["batch_vs_loop"]["peer_figure"] == 0.1
    assert T["linear_step_ns"]["peer"] is None
    # the least ratio and share over the classes, the largest growth
    assert T["classes_vs_loop"]["figure"] == 5.0 and not T["classes_vs_loop"]["met"]
    assert T["classes_vs_loop"]["peer"] == "SQPnP + RefineLM loop on ordinary"
    assert T["classes_at_optimum"]["figure"] == 1.0 - 0.0015
    assert T["classes_growth"]["figure"] == 1.1 + 0.3 and not T["classes_growth"]["met"]

    res["targets"], res["machine"] = T, {"cpu": "test cpu", "cores": 2}
    out = io.StringIO()
    run.print_speed(res, Console(file=out, width=250))
    text = out.getvalue()
    for expected in (
        "Speed targets (test cpu, 2 cores)",
        "step 2 (linear from all 560) 6.30",
        "three-point kernel:",
        "linear step kernel",
        "Batches: n = 16",
        "Problem classes",
        "bench_model",
        "<= 1.5 ms",
        ">= 60x",
        ">= 99.9%",
        "<= 1024 MB",
        *speed.TARGETS,
    ):
        assert expected in text, (expected, text)


def test_missing_sections_are_not_measured():
    T = speed.targets({"p3p": {}, "batch": []})
    assert list(T) == list(speed.TARGETS)
    for row in T.values():
        assert row["figure"] is None and row["met"] is None
        assert row["verdict"] == "not measured"
    out = io.StringIO()
    run.print_targets(T, Console(file=out, width=250))
    assert out.getvalue().count("not measured") == len(speed.TARGETS)


def test_at_optimum_is_the_ml_optimum_or_lower():
    ref = np.array([1.0, 1.0, 1.0, 0.0, 0.0])
    err = np.array([1.0 + 0.5e-6, 1.0 + 2e-6, 0.5, 0.5e-9, 2e-9])
    assert speed.at_optimum(err, ref).tolist() == [True, False, True, True, False]


def test_chessboard_problem_and_peak_memory():
    obj, img = speed.chessboard_problem(seed=3)
    assert obj.shape == (54, 3) and img.shape == (54, 2)
    assert np.all(obj[:, 2] == 0)  # planar
    assert np.all((img > 0) & (img < [640, 480]))
    peak = peak_memory_mb()
    assert peak["ru_maxrss"] > 0 and (peak["vm_hwm"] is None or peak["vm_hwm"] > 0)


def test_device_benchmark_writes_what_its_table_reads(tmp_path):
    """`benchmarks/device.py` runs (its kernel section, small) and saves the device, the
    host's CPU and the figures; the documentation's table renders from a saved run."""
    import json
    import sys
    from pathlib import Path

    from benchmarks import device

    out = tmp_path / "device.json"
    res = device.main(["--quick", "--sections", "p3p", "--out", str(out)])
    saved = json.loads(out.read_text())
    assert saved["device"]["platform"] == res["device"]["platform"]
    assert saved["machine"]["cpu"] and saved["machine"]["devices"]
    assert saved["p3p"]["ns_per_triplet"] > 0 and saved["p3p"]["solved"] > 0.9
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "docs" / "scripts"))
    from tables_speed import device as device_table

    text = device_table(Path(__file__).resolve().parents[1] / "benchmarks" / "results")
    assert "three-point kernel" in text and "Machine:" in text
