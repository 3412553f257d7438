"""`benchmarks/distortion.py` on a few problems: its figures are what it says."""

from benchmarks import distortion


def test_a_few_problems_at_the_image_space_optimum():
    res = distortion.measure(4, seed=1)
    assert res["problems"] == 4
    assert res["at_optimum"] == 1.0 and res["verdict"] == "met"
    assert res["projection_max_diff_px"] < 1e-9
    assert res["worst_excess_px"] <= 1e-6 * res["median_rms_px"] + 1e-9
    assert res["solve_pnp_ms"] > 0
