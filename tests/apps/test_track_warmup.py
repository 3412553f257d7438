"""The tracker's programs built ahead of time (`jaxpose.apps._track_warmup`, `jaxpose
warmup --track`): after the plan's builds, the per-frame solve and the refinement of the
same buckets run without compiling; bad counts are named."""

import numpy as np
import pytest

from jaxpose.apps import _track_refine, _track_solve
from jaxpose.apps._track import TrackedFrame
from jaxpose.apps._track_solve import Measurements, solve_frame
from jaxpose.apps._track_warmup import track_warm_up_plan

K = np.array([[800.0, 0.0, 320.0], [0.0, 800.0, 240.0], [0.0, 0.0, 1.0]])


def _edges(R, t, n, rng):
    """`n` edge matches of points on a 20-unit cube seen at `(R, t)`, 0.2 px of noise."""
    model = rng.uniform(-10, 10, (n, 3))
    X = model @ R.T + t
    q = X[:, :2] / X[:, 2:] * 800.0 + [320.0, 240.0]
    angle = rng.uniform(0, np.pi, n)
    normal = np.column_stack([np.cos(angle), np.sin(angle)])
    q += normal * rng.normal(0, 0.2, (n, 1))
    lines = np.column_stack([normal, -(normal * q).sum(axis=1)])
    return Measurements(model, lines, np.zeros((0, 3)), np.zeros((0, 2)))


def test_built_programs_run_without_compiling():
    plan = track_warm_up_plan(solve=(7,), refine=((3, 7),))
    assert [what for what, _ in plan] == [
        "track: per-frame solve, 8 units",
        "track: refinement, 8 frames x 8 units",
    ]
    for _, build in plan:
        build()
    for _, build in plan:  # already in this process (or on disk): nothing compiled
        assert build() is False
    solved_before = _track_solve._PROGRAM.compiled
    refined_before = _track_refine._PROGRAM.compiled
    rng = np.random.default_rng(0)
    R, t = np.eye(3), np.array([0.0, 0.0, 100.0])
    frames = []
    for i in range(3):
        meas = _edges(R, t, 8, rng)
        s = solve_frame(R, t + [0.1, 0.0, 0.0], K, meas, iterations=3, min_rows=6,
                        min_scale=0.3)  # fmt: skip
        assert s.ok
        frames.append(TrackedFrame(i, s.R, s.t, True, 8, 0, s.rms, "tracked", rows=s.rows))
    refined = _track_refine.refine_track(frames)
    assert refined.iterations == 8 and np.isfinite(refined.cost_after)
    assert _track_solve._PROGRAM.compiled == solved_before
    assert _track_refine._PROGRAM.compiled == refined_before


@pytest.mark.parametrize(
    ("solve", "refine", "name"),
    [
        ((0,), (), "solve"),
        ((8,), ((0, 8),), "refine"),
        ((True,), (), "solve"),
        ((8,), ((8, 2.5),), "refine"),
        ((8,), ((8,),), "refine"),
    ],  # fmt: skip
)
def test_bad_counts_are_named(solve, refine, name):
    with pytest.raises(ValueError, match=name):
        track_warm_up_plan(solve=solve, refine=refine)
