"""The speed benchmark (`benchmarks/speed.py`, printed by `benchmarks/run.py`): its cheap
sections run for real on tiny inputs, and the table prints every section with its
target and verdict (the expensive sections, which compile the whole solver, are given
stand-in figures here: `make bench` runs them)."""

import io
import math

from rich.console import Console

from benchmarks import run, speed


def test_cheap_sections_and_the_table():
    q = speed.p3p(256, 2)
    la = speed.linalg(64, 2)
    assert q["triplets"] == 256 and math.isfinite(q["ns_per_triplet"]) and q["ns_per_triplet"] > 0
    assert la["systems"] == 64 and la["lapack_us_per_system"] > 0 and la["ratio"] > 0
    res = {
        "paper": {
            "triplets": 560,
            "jaxpose_ms": 8.0,
            "compile_s": 20.0,
            "opencv_ms": 120.0,
            "poselib_ms": 70.0,
            "vs_opencv": 15.0,
            "vs_poselib": 8.75,
        },
        "paper_phases": {
            "triplets": 560,
            "three_point_ms": 1.7,
            "step1_ms": 3.3,
            "step2_linear_ms": 6.3,
            "mixed_ms": 9.4,
            "solve_ms": 8.5,
        },
        "latency": {"solve_pnp_ms": 11.0, "solve_pnp_budget8_ms": 2.0, "cv2_sqpnp_us": 56.0},
        "batch": [
            {
                "B": 10,
                "jaxpose_s": 0.005,
                "per_problem_us": 500.0,
                "opencv_s": 0.001,
                "vs_opencv": 0.2,
                "at_optimum": 1.0,
            }
        ],
        "p3p": q,
        "linalg": la,
        "targets": speed.TARGETS,
    }
    out = io.StringIO()
    run.print_speed(res, Console(file=out, width=200))
    text = out.getvalue()
    for expected in (
        "Paper protocol: all 560 triplets",
        "<= 3 ms: missed by 2.7x",
        ">= 30x: missed by 2.0x",
        "step 2 (linear from all 560) 6.30",
        "compile (cold, first call): 20.0 s",
        "P3P alone:",
        "6x6 normal equations",
    ):
        assert expected in text, (expected, text)
