"""Logging the paper's experiment (`log_experiment`): the bench, the true and recovered
poses, every triplet through the four methods, and Table 1 as the summary."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..solvers._status import Status
from ._rerun_common import _TRUE, METHOD_LABELS, _np, _summary, _transform, _world_up
from ._rerun_layout import _frame_object
from ._rerun_scene import log_camera, log_observations, log_pose
from ._rerun_solution import _series, log_triplets

if TYPE_CHECKING:  # pragma: no cover
    import rerun as rr

    from ..apps._bench import Bench
    from ..apps._experiment import ExperimentResult
    from ..strategy import MixedResult

__all__ = ["log_experiment"]


def log_experiment(
    rec: rr.RecordingStream,
    bench: Bench,
    result: ExperimentResult,
    mixed: MixedResult | None = None,
    *,
    image=None,
    layout: bool = True,
) -> None:
    """Log the paper's experiment on `bench`: the camera, the observations, the true pose,
    the answer (the accepted mixed triplet of lowest error), the per-triplet Eq. 8 error
    and pose error of all four methods (`result`) and, with `mixed`, every triplet's
    hypothesis and status; Table 1 as the summary.

    **Arguments:**
    - `bench`: the `jaxpose.apps.Bench` the experiment ran on.
    - `result`: `jaxpose`'s `ExperimentResult` of `run_experiment(bench)`.
    - `mixed`: `jaxpose.mixed` on the same problem (same threshold), for the poses.
    - `image`: the camera's image (a file path, or an RGB array), e.g. a rendering.
    - `layout`: as for `log_solution`.
    """
    from ..apps._experiment import METHOD_NAMES, PAPER_TABLE1

    world_true = _transform(bench.R, bench.t, bench.model_points)
    distance = float(np.median(np.linalg.norm(world_true - (-bench.R_wc.T @ bench.t_wc), axis=1)))
    log_camera(
        rec,
        bench.camera,
        K=bench.K,
        R_wc=bench.R_wc,
        t_wc=bench.t_wc,
        image_size=bench.image_size,
        image=image,
        frustum=0.2 * distance,
    )
    if layout:
        centre = -bench.R_wc.T @ bench.t_wc
        up = _world_up(bench.R_wc, bench.t_wc)
        _frame_object(rec, centre, world_true, up, pose_error=True)
    log_pose(
        rec,
        "true",
        bench.camera,
        bench.model_points,
        (bench.R, bench.t),
        polyhedron=bench.model,
        color=_TRUE,
    )
    mixed_error = _np(result.error["mixed"])
    ok = np.array([Status(int(s)).succeeded for s in result.status["mixed"]])
    best = int(np.argmin(np.where(ok, mixed_error, np.inf))) if ok.any() else None
    if mixed is not None and best is not None:
        pose = (_np(mixed.pose.R)[best], _np(mixed.pose.t)[best])
        log_pose(
            rec,
            "recovered",
            bench.camera,
            bench.model_points,
            pose,
            polyhedron=bench.model,
            label=f"mixed, triplet {best}: {mixed_error[best]:.3g} px",
        )
        depth = _transform(*pose, bench.model_points)
    else:
        depth = world_true
    log_observations(rec, bench.camera, bench.image_points, depth_points=depth)
    if mixed is not None:
        log_triplets(
            rec,
            bench.camera,
            bench.model_points,
            bench.image_points,
            mixed,
            polyhedron=bench.model,
            errors=result.error,
            pose_errors=result.pose_error,
            statuses=result.status,
        )
    else:
        _series(rec, "error_px", result.error, result.used)
        _series(rec, "pose_error_mm", result.pose_error, result.used)
    stats = result.statistics()
    head = "| pose error (mm) | " + " | ".join(METHOD_LABELS[m] for m in METHOD_NAMES) + " |"
    rows = [head, "|---" * (len(METHOD_NAMES) + 1) + "|"]
    for label, key in (
        ("mean", "mean"),
        ("standard deviation", "std"),
        ("mean deviation", "mean_deviation"),
        ("minimum", "min"),
    ):
        rows.append(
            f"| {label} | "
            + " | ".join(
                f"{stats[m][key]:.3f} (paper {PAPER_TABLE1[m][key]:.3f})" for m in METHOD_NAMES
            )
            + " |"
        )
    rows.append(
        "| at the optimum | "
        + " | ".join(f"{100 * stats[m]['at_optimum']:.2f}%" for m in METHOD_NAMES)
        + " |"
    )
    c = result.counts
    lines = [
        f"# The paper's experiment (bench seed {bench.seed}, noise {bench.noise:g} px)",
        "",
        f"Triplets {c['triplets']}, aligned {c['aligned']}, collinear model points "
        f"{c['collinear_model']}, used {c['used']}; optimum pose error "
        f"{result.optimum:.3f} mm; threshold {result.threshold:.3f} px.",
        "",
        *rows,
    ]
    rec.log("summary", _summary(lines), static=True)
