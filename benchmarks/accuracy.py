"""Accuracy of jaxpose beside OpenCV and PoseLib: the standard synthetic PnP protocol and
OpenCV's chessboard images.

**Synthetic protocol** (the RPnP / OPnP / MLPnP toolboxes', in `benchmarks/_protocol.py`):
`jaxpose.apps.random_scene` with
`f = 800`, OpenCV's convention (world = camera frame, `C = K [I | 0]`) and camera-frame
points uniform in `[-2,2]x[-2,2]x[4,8]` ("ordinary"), `[1,2]x[1,2]x[4,8]`
("quasi_singular") or on a plane `[-2,2]^2` tilted by up to 30 degrees at depth 4-8
("planar"); Gaussian pixel noise `sigma`. Two sweeps per kind: `sigma` in
{0.5, 1, 2, 3, 4, 5} px at `n = 10`, and `n` in {4, 6, 10, 20, 50, 100, 200} at
`sigma = 2` px. Every method solves the same seeded instances. Errors, in the camera frame
(`x_cam = R X + t`): rotation error = the largest angle between matching axes (columns) of
`R_true` and `R_est` (degrees); translation error = `|t_est - t_true| / |t_true|` (%).
Medians and means over the trials of each cell.

Methods: jaxpose's four (`jaxpose.solve_pnp_batch`, float64, every trial of a cell in
fixed-size chunks, so one compilation per `(n, method)`; above `C(n, 3) = 2000` triplets
a fixed sample of 2000), OpenCV's `SOLVEPNP_EPNP`, `SOLVEPNP_SQPNP`, `SOLVEPNP_ITERATIVE`
and `SOLVEPNP_IPPE` (planar scenes only), and PoseLib's `estimate_absolute_pose` with a
10^4 px inlier threshold (every match an inlier) and a least-squares (`TRIVIAL` loss)
refinement.

**The ML optimum** of each trial, the minimum of Eq. 8 (RMS reprojection error): the best
of `cv2.solvePnPRefineLM` (float64, up to 200 iterations) started from SQPnP, from EPnP and
from the true pose. A method "is at the optimum" on a trial when its RMS reprojection
error is within `1e-6` px of the reference's (absolute; the stricter `1e-9` relative
criterion is counted too). Trials where jaxpose's mixed method misses it are kept in the
JSON as reproducers.

**Real images:** OpenCV's chessboard set (`jaxpose/data/chessboard/`): corners by
`cv2.findChessboardCorners` and `cv2.cornerSubPix`, intrinsics and distortion from
`left_intrinsics.yml`; per image, jaxpose's pose (`jaxpose.solve_pnp`, mixed) against
OpenCV's reference pose (the calibration's own extrinsics, in the same file) and against
`cv2.solvePnP`, with the reprojection errors side by side.

    python benchmarks/accuracy.py            # full: 500 trials per cell (see --help)
    python benchmarks/accuracy.py --quick    # ~50 trials per cell

Prints tables and writes `benchmarks/results/accuracy.json` (every figure, the machine,
the library versions) and one PNG per kind (`accuracy_<kind>.png`; tables and plots in
`benchmarks/_accuracy_report.py`). `run(quick, out_dir)` is the entry point for
`benchmarks/run.py`.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
from collections.abc import Sequence
from pathlib import Path

if __name__ == "__main__" and not __package__:  # run as `python benchmarks/accuracy.py`
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import cv2
import numpy as np

import jaxpose as jp
from benchmarks._accuracy_report import markdown as markdown
from benchmarks._accuracy_report import plot as plot
from benchmarks._accuracy_report import print_tables as print_tables
from benchmarks._harness import (
    RESULTS,
    ROOT,
    Stopwatch,
    compilation_cache,
    machine,
    rich_console,
    timeit,
    versions,
    write_json,
)
from benchmarks._protocol import (
    ABS_TOL,
    FOCAL,
    JAX_METHODS,
    KINDS,
    LOCAL_MINIMUM,
    ML,
    OPENCV_FLAGS,
    POSELIB_THRESHOLD,
    REFINE_CRITERIA,
    REL_TOL,
    Answers,
    Cell,
    chunk_size,
    jaxpose_name,
    make_cell,
    ml_optimum,
    rotation_angle_deg,
    solve_jaxpose,
    solve_opencv,
    solve_poselib,
    summarise,
)
from jaxpose.solvers import Status

CHESSBOARD = ROOT / "jaxpose" / "data" / "chessboard"

SIGMAS = (0.5, 1.0, 2.0, 3.0, 4.0, 5.0)
NS = (4, 6, 10, 20, 50, 100, 200)
SIGMA_SWEEP_N = 10
N_SWEEP_SIGMA = 2.0
MAX_REPRODUCERS = {"mixed": 25}  # per kind and jaxpose method (others: 3)


# --------------------------------------------------------------------------- schedule


@dataclasses.dataclass(frozen=True)
class Schedule:
    """How many trials each cell gets.

    `trials` per cell, capped at large `n` by `large_n` (`{n: cap}`): every method runs
    on the same instances of a cell. The three jaxpose ablations (the paper's
    three-point, linear and non-linear methods run from every triplet) run on the first
    `ablation[method][n]` of them (absent: all; `0`: not run), because at large `n` they
    cost seconds per problem (the non-linear one runs LM on all 2000 triplets)."""

    trials: int
    large_n: dict[int, int]
    ablation: dict[str, dict[int, int]]

    def cell_trials(self, n: int) -> int:
        return min(self.trials, self.large_n.get(n, self.trials))

    def method_trials(self, n: int, method: str) -> int:
        cell = self.cell_trials(n)
        return min(cell, self.ablation.get(method, {}).get(n, cell))


def default_schedule(quick: bool, trials: int | None = None) -> Schedule:
    """The schedule of `--quick` (about 50 trials per cell) or of the full run (500).

    Measured per-problem cost of `solve_pnp_batch` (float64, compiled, on the 2-core CPU
    this was developed on, shared with other work): mixed 0.006-0.01 s at n = 10,
    0.06-0.1 s at n = 20, 0.3-0.5 s at n = 50, 0.5-1.1 s at n = 100, 1-1.4 s at n = 200;
    non-linear 0.04-0.06 s at n = 10, 0.8 s at n = 20 and about 7 s at n = 50 (LM on every
    triplet). The caps keep the full run near 25 minutes of solving there; compiling the
    28 programs comes on top (minutes; JAX's persistent cache removes it on a rerun)."""
    if quick:
        base = 50 if trials is None else trials
        large_n = {20: 50, 50: 20, 100: 10, 200: 5}
        few = {50: 5, 100: 5, 200: 5}
        nonlinear = {n: 20 for n in (4, 6, 10)} | {20: 25, 50: 0, 100: 0, 200: 0}
    else:
        base = 500 if trials is None else trials
        large_n = {50: 160, 100: 60, 200: 30}
        few = {50: 60, 100: 20, 200: 10}
        nonlinear = {n: 150 for n in (4, 6, 10)} | {20: 100, 50: 0, 100: 0, 200: 0}
    return Schedule(
        trials=base,
        large_n=large_n,
        ablation={"three_point": few, "linear": few, "nonlinear": nonlinear},
    )


def reproducer(cell: Cell, i: int, name: str, ans: Answers, ml: Answers, ml_err, gap) -> dict:
    """A trial a method got wrong, with everything needed to run it again."""
    return {
        "method": name,
        "kind": cell.kind,
        "n": cell.n,
        "sigma": cell.sigma,
        "cell_seed": list(cell.seed),
        "trial": int(i),
        "ok": bool(ans.ok[i]),
        "rms_px": float(ml_err[i] + gap[i]) if np.isfinite(gap[i]) else None,
        "ml_rms_px": float(ml_err[i]),
        "gap_px": float(gap[i]) if np.isfinite(gap[i]) else None,
        "rotation_from_ml_deg": float(rotation_angle_deg(ans.R[i : i + 1], ml.R[i : i + 1])[0]),
        "K": cell.K.tolist(),
        "object_points": cell.obj[i].tolist(),
        "image_points": cell.img[i].tolist(),
        "R_true": cell.R[i].tolist(),
        "t_true": cell.t[i].tolist(),
        "R_ml": ml.R[i].tolist(),
        "t_ml": ml.t[i].tolist(),
        "R_method": ans.R[i].tolist(),
        "t_method": ans.t[i].tolist(),
    }


def diagnose(rep: dict, *, max_steps: int = 500) -> dict:
    """Why jaxpose's mixed method missed the ML optimum on a reproducer.

    Runs `jaxpose.solve` (mixed, float64): the status of its answer and its error. For
    `n <= 10` also `jaxpose.mixed` (the per-triplet outcome, with `solve`'s non-linear
    budget) and, from every three-point root of every triplet, Levenberg-Marquardt with a
    generous `max_steps`: which roots lead to the ML optimum (within 1e-6 px), and their
    rank by Eq. 8 error within their triplet (the mixed method refines rank 0 first)."""
    import jax
    import jax.numpy as jnp

    K = np.asarray(rep["K"])
    C = K @ np.hstack([np.eye(3), np.zeros((3, 1))])
    ml = rep["ml_rms_px"]
    with jax.enable_x64(True):
        args = tuple(
            jnp.asarray(a, jnp.float64) for a in (C, rep["object_points"], rep["image_points"])
        )
        sol = jax.jit(jp.solve)(*args)
        status = Status(int(sol.status))
        out = {
            "accepted": bool(sol.accepted),
            "status": status.name,
            "message": status.message,
            "error_px": float(sol.error),
            "error_minus_ml_px": float(sol.error) - ml,
            "triplet": [int(i) for i in np.asarray(sol.triplet)],
        }
        if rep["n"] > 10:
            return out

        def per_triplet(C, model, image):
            obs = jp.geometry.observations(C, model, image)
            res = jp.strategy.mixed(obs, nonlinear_budget=32)
            ini = res.initial
            R = jnp.concatenate([ini.pose.R[:, None], ini.alt_pose.R], axis=1)
            t = jnp.concatenate([ini.pose.t[:, None], ini.alt_pose.t], axis=1)

            def refine(R, t):
                return jp.solvers.nonlinear(obs, jp.geometry.Pose(R, t), max_steps=max_steps)

            refined = jax.vmap(jax.vmap(refine))(R, t)
            root_error = jnp.concatenate([ini.error[:, None], ini.alt_error], axis=1)
            return res, root_error, refined.error, refined.pose.R

        res, root_error, lm_error, lm_R = jax.jit(per_triplet)(*args)
        big = np.finfo(np.float64).max / 2
        roots = np.asarray(root_error) < big
        reach = roots & (np.asarray(lm_error) <= ml + ABS_TOL)
        ml_R = np.asarray(rep["R_ml"])
        triplets = []
        for k in range(len(res.error)):
            triplets.append(
                {
                    "initial_status": Status(int(res.initial.status[k])).name,
                    "status": Status(int(res.status[k])).name,
                    "error_px": float(res.error[k]),
                    "root": int(res.root[k]),
                    "root_p3p_error_px": [float(e) for e in np.asarray(root_error[k])[roots[k]]],
                    "root_lm_error_px": [float(e) for e in np.asarray(lm_error[k])[roots[k]]],
                    "root_lm_deg_from_ml": [
                        float(rotation_angle_deg(np.asarray(R)[None], ml_R[None])[0])
                        for R in np.asarray(lm_R[k])[roots[k]]
                    ],
                }
            )
        out |= {
            "lm_max_steps": max_steps,
            "roots": int(roots.sum()),
            "roots_reaching_ml": int(reach.sum()),
            "best_roots_reaching_ml": int(reach[:, 0].sum()),
            "triplets": triplets,
        }
        return out


def run_cell(
    cell: Cell,
    schedule: Schedule,
    jax_methods: Sequence[str],
    reproducers: list,
    progress=None,
    chunk: int | None = None,
) -> dict:
    """Every method on one cell: statistics per method, the ML optimum's own errors."""
    B = len(cell.obj)
    ml, ml_err, won = ml_optimum(cell, B)
    ml_stats, _, _ = summarise(cell, ml, ml_err)
    ml_stats["start_won"] = {k: won.count(k) for k in sorted(set(won))}
    rows: dict[str, dict] = {ML: ml_stats}
    for method in jax_methods:
        trials = schedule.method_trials(cell.n, method)
        name = jaxpose_name(method)
        if trials == 0:
            rows[name] = {"trials": 0, "skipped": "cost (see the schedule)"}
            continue
        if progress is not None:
            progress(f"{cell.kind} n={cell.n} sigma={cell.sigma:g}: {name} x {trials}")
        ans = solve_jaxpose(cell, method, trials, chunk)
        rows[name], missed, gap = summarise(cell, ans, ml_err)
        kept = [r for r in reproducers if r["method"] == name and r["kind"] == cell.kind]
        room = MAX_REPRODUCERS.get(method, 3) - len(kept)
        for i in np.flatnonzero(missed)[: max(0, room)]:
            reproducers.append(reproducer(cell, i, name, ans, ml, ml_err, gap))
    if progress is not None:
        progress(f"{cell.kind} n={cell.n} sigma={cell.sigma:g}: OpenCV, PoseLib x {B}")
    for key, flag in OPENCV_FLAGS.items():
        if key == "IPPE" and cell.kind != "planar":
            continue
        rows[f"cv2 {key}"], _, _ = summarise(cell, solve_opencv(cell, flag, B), ml_err)
    rows["PoseLib"], _, _ = summarise(cell, solve_poselib(cell, B), ml_err)
    return {
        "kind": cell.kind,
        "n": cell.n,
        "sigma": cell.sigma,
        "trials": B,
        "seed": list(cell.seed),
        "methods": rows,
    }


# --------------------------------------------------------------------------- chessboard


def chessboard(data: Path = CHESSBOARD, method: str = "mixed") -> dict:
    """jaxpose on OpenCV's chessboard images against OpenCV's reference poses and
    `cv2.solvePnP`.

    The reference pose of each image is the calibration's own extrinsics
    (`left_intrinsics.yml`, row `i` for the `i`-th image in name order; the file's own
    per-view errors confirm the order). Reprojection errors are RMS in image pixels
    (distortion applied by `cv2.projectPoints`), and on undistorted pixels
    (`undistorted_px`); both jaxpose and OpenCV minimise the error in the image."""
    fs = cv2.FileStorage(str(data / "left_intrinsics.yml"), cv2.FILE_STORAGE_READ)
    K = fs.getNode("camera_matrix").mat()
    dist = fs.getNode("distortion_coefficients").mat()
    extrinsics = fs.getNode("extrinsic_parameters").mat()
    per_view = fs.getNode("per_view_reprojection_errors").mat().ravel()
    cols, rows_ = int(fs.getNode("board_width").real()), int(fs.getNode("board_height").real())
    square = fs.getNode("square_size").real()
    fs.release()
    board = np.zeros((cols * rows_, 3))
    board[:, :2] = np.mgrid[0:cols, 0:rows_].T.reshape(-1, 2) * square
    paths = sorted(data.glob("left*.jpg"))
    if len(paths) != len(extrinsics):
        raise ValueError(f"{len(paths)} images but {len(extrinsics)} reference poses in {data}")

    def rms(corners, rv, tv, distortion):
        p, _ = cv2.projectPoints(board, rv, tv, K, distortion)
        return float(np.sqrt(np.mean(np.sum((p.reshape(-1, 2) - corners) ** 2, axis=1))))

    images = []
    for path, ext, view_err in zip(paths, extrinsics, per_view, strict=True):
        gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        found, corners = cv2.findChessboardCorners(gray, (cols, rows_))
        if not found:
            images.append({"image": path.name, "found": False})
            continue
        crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 1e-3)
        corners = cv2.cornerSubPix(gray, corners, (11, 11), (-1, -1), crit).reshape(-1, 2)
        rv_ref, tv_ref = ext[:3].reshape(3, 1), ext[3:].reshape(3, 1)
        # The detector may list the corners from the other end of the board.
        flipped = rms(corners[::-1], rv_ref, tv_ref, dist) < rms(corners, rv_ref, tv_ref, dist)
        if flipped:
            corners = np.ascontiguousarray(corners[::-1])
        call = timeit(
            lambda: jp.solve_pnp(board, corners, K, dist, method=method),
            warmup=0,
            repeat=1,
        )
        (ok, rv_jp, tv_jp), seconds = call.result, call.best
        _, rv_cv, tv_cv = cv2.solvePnP(board, corners, K, dist)
        undist = jp.geometry.undistort_pixels(corners, K, dist)
        poses = {"reference": (rv_ref, tv_ref), "cv2": (rv_cv, tv_cv), "jaxpose": (rv_jp, tv_jp)}
        Rs = {k: cv2.Rodrigues(np.asarray(v[0], np.float64))[0] for k, v in poses.items()}
        ts = {k: np.asarray(v[1], np.float64).ravel() for k, v in poses.items()}

        def diff(a, b):
            dt = np.linalg.norm(ts[a] - ts[b])
            return {
                "rotation_deg": float(rotation_angle_deg(Rs[a][None], Rs[b][None])[0]),
                "translation_mm": float(1000 * dt),
                "translation_pct": float(100 * dt / np.linalg.norm(ts[b])),
            }

        images.append(
            {
                "image": path.name,
                "found": True,
                "corners_reversed": bool(flipped),
                "jaxpose_ok": bool(ok),
                "jaxpose_seconds": seconds,
                "rms_px": {k: rms(corners, *v, dist) for k, v in poses.items()},
                "rms_undistorted_px": {k: rms(undist, *v, None) for k, v in poses.items()},
                "calibration_per_view_px": float(view_err),
                "jaxpose_vs_reference": diff("jaxpose", "reference"),
                "jaxpose_vs_cv2": diff("jaxpose", "cv2"),
                "cv2_vs_reference": diff("cv2", "reference"),
                "distance_m": float(np.linalg.norm(ts["reference"])),
                "rvec": {k: np.asarray(v[0], float).ravel().tolist() for k, v in poses.items()},
                "tvec": {k: ts[k].tolist() for k in poses},
            }
        )
    return {
        "data": str(data.relative_to(ROOT)) if data.is_relative_to(ROOT) else str(data),
        "board": {"inner_corners": [cols, rows_], "square_m": square},
        "K": K.tolist(),
        "dist_coeffs": dist.ravel().tolist(),
        "method": method,
        "images": images,
    }


# --------------------------------------------------------------------------- run


def run(
    quick: bool = False,
    out_dir: str | Path | None = None,
    *,
    trials: int | None = None,
    schedule: Schedule | None = None,
    kinds: Sequence[str] = KINDS,
    sigmas: Sequence[float] = SIGMAS,
    ns: Sequence[int] = NS,
    jax_methods: Sequence[str] = JAX_METHODS,
    real_images: bool = True,
    plots: bool = True,
    seed: int = 0,
    console=None,
    tag: str | None = None,
    chunk: int | None = None,
) -> dict:
    """Run the accuracy benchmark; print its tables, write its JSON and plots.

    **Arguments:**
    - `quick`: about 50 trials per cell instead of 500 (see `default_schedule`).
    - `out_dir`: where `accuracy.json` and `accuracy_<kind>.png` go (default
      `benchmarks/results/`).
    - `trials`, `schedule`: override the trials per cell / the whole schedule.
    - `kinds`, `sigmas`, `ns`, `jax_methods`: a smaller grid (tests use one).
    - `real_images`: also run the chessboard images; `plots`: write the PNGs.
    - `seed`: the instances' base seed; `console`: a `rich.console.Console` (default:
      a new one); `tag`: appended to the file names (`accuracy{tag}.json`,
      `accuracy{tag}_<kind>.png`; default `"_quick"` in quick mode, else none);
      `chunk`: problems per `solve_pnp_batch` call (default `chunk_size(n, method)`).

    **Returns:** the JSON-ready result (also written to `out_dir / f"accuracy{tag}.json"`).
    """
    console = console or rich_console(160)
    out = Path(out_dir) if out_dir is not None else RESULTS
    tag = ("_quick" if quick else "") if tag is None else tag
    out.mkdir(parents=True, exist_ok=True)
    schedule = schedule or default_schedule(quick, trials)
    watch = Stopwatch()
    load_start = list(os.getloadavg())
    cells: dict[tuple, dict] = {}
    reproducers: list[dict] = []
    synthetic: dict[str, dict] = {}

    def say(msg):
        console.log(msg)

    for kind in kinds:
        sweeps = {
            "sigma": [(SIGMA_SWEEP_N, float(s)) for s in sigmas],
            "n": [(int(n), N_SWEEP_SIGMA) for n in ns],
        }
        synthetic[kind] = {}
        for sweep, grid in sweeps.items():
            results = []
            for n, sigma in grid:
                key = (kind, n, sigma)
                if key not in cells:
                    cell = make_cell(kind, n, sigma, schedule.cell_trials(n), seed)
                    cells[key] = run_cell(cell, schedule, jax_methods, reproducers, say, chunk)
                results.append(cells[key])
            fixed = {"sigma": {"n": SIGMA_SWEEP_N}, "n": {"sigma": N_SWEEP_SIGMA}}[sweep]
            synthetic[kind][sweep] = fixed | {
                "values": [c[sweep] for c in results],
                "cells": results,
            }
    for rep in reproducers:
        if rep["method"] == jaxpose_name("mixed"):
            say(f"diagnosing a miss of jaxpose mixed ({rep['kind']}, n={rep['n']})")
            rep["jaxpose_solve"] = diagnose(rep)
    optimum = at_optimum(cells.values(), kinds)
    result = {
        "benchmark": "accuracy",
        "mode": "quick" if quick else "full",
        "protocol": {
            "focal_px": FOCAL,
            "kinds": list(kinds),
            "sigma_sweep": {"n": SIGMA_SWEEP_N, "sigma_px": list(map(float, sigmas))},
            "n_sweep": {"sigma_px": N_SWEEP_SIGMA, "n": list(map(int, ns))},
            "rotation_error": "largest angle between matching axes of R_true, R_est (deg)",
            "translation_error": "|t_est - t_true| / |t_true| (%)",
            "frame": "camera (cv2: x_cam = R X + t)",
            "ml_optimum": "best Eq. 8 RMS error of cv2.solvePnPRefineLM from SQPnP, EPnP and "
            f"the true pose (criteria {list(REFINE_CRITERIA)})",
            "at_optimum": f"RMS error within {ABS_TOL:g} px of the ML optimum's "
            f"(at_optimum_abs); within a relative {REL_TOL:g} (at_optimum_rel)",
            "local_minimum": f"more than {LOCAL_MINIMUM:g} px above the ML optimum",
            "poselib": f"estimate_absolute_pose, max_reproj_error {POSELIB_THRESHOLD:g} px, "
            "TRIVIAL loss (least squares)",
            "jaxpose": "solve_pnp_batch (float64), fixed chunks; C(n,3) > 2000 triplets: "
            "a fixed sample of 2000",
            "seed": seed,
        },
        "schedule": {
            "trials": schedule.trials,
            "large_n": {str(k): v for k, v in schedule.large_n.items()},
            "ablation": {
                m: {str(k): v for k, v in d.items()} for m, d in schedule.ablation.items()
            },
            "chunk": {
                str(n): {m: chunk or chunk_size(n, m) for m in jax_methods}
                for n in sorted({SIGMA_SWEEP_N, *ns})
            },
        },
        "synthetic": synthetic,
        "at_optimum": optimum,
        "reproducers": reproducers,
    }
    if real_images:
        say("chessboard images")
        result["chessboard"] = chessboard()
    result["machine"] = machine() | {"load_average_start": load_start}
    result["versions"] = versions()
    result["seconds"] = watch.seconds
    path = write_json(out / f"accuracy{tag}.json", result)
    if plots:
        result["plots"] = [str(p) for p in plot(result, out, tag)]
        write_json(path, result)
    print_tables(result, console)
    console.print(f"wrote {path} ({result['seconds']:.0f} s)")
    return result


def at_optimum(cells, kinds: Sequence[str]) -> dict:
    """Per kind and method: the trials at the ML optimum over every cell of the kind."""
    out: dict[str, dict] = {kind: {} for kind in kinds}
    for cell in cells:
        for name, row in cell["methods"].items():
            if name == ML or not row.get("trials"):
                continue
            acc = out[cell["kind"]].setdefault(
                name,
                {"trials": 0, "at_optimum_abs": 0, "at_optimum_rel": 0, "local_minima": 0}
                | {"failed": 0, "below_reference": 0},
            )
            for k in acc:
                acc[k] += row[k]
    for rows in out.values():
        for acc in rows.values():
            acc["share_abs"] = acc["at_optimum_abs"] / acc["trials"]
            acc["share_rel"] = acc["at_optimum_rel"] / acc["trials"]
    return out


# --------------------------------------------------------------------------- command line


def main(argv: Sequence[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="about 50 trials per cell")
    parser.add_argument("--trials", type=int, default=None, help="trials per cell (small n)")
    parser.add_argument("--out", default=None, help="output folder (default benchmarks/results)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--kinds", nargs="+", default=list(KINDS), choices=KINDS)
    parser.add_argument("--no-images", action="store_true", help="skip the chessboard images")
    parser.add_argument("--markdown", default=None, help="also write the tables as Markdown")
    parser.add_argument(
        "--from-json", default=None, help="no run: tables and plots from a saved result"
    )
    args = parser.parse_args(argv)
    if args.from_json:
        path = Path(args.from_json)
        result = json.loads(path.read_text())
        tag = path.stem.removeprefix("accuracy")
        plot(result, Path(args.out) if args.out else path.parent, tag)
        print_tables(result, rich_console(160))
        if args.markdown:
            Path(args.markdown).write_text(markdown(result))
        return result
    if args.trials is not None and args.trials < 1:
        parser.error(f"--trials must be >= 1, got {args.trials}")
    compilation_cache()  # a second run loads its 28 `(n, method)` programs
    result = run(
        args.quick,
        args.out,
        trials=args.trials,
        kinds=args.kinds,
        seed=args.seed,
        real_images=not args.no_images,
    )
    if args.markdown:
        Path(args.markdown).write_text(markdown(result))
    return result


if __name__ == "__main__":
    main()
