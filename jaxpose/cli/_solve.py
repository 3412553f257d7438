"""`jaxpose solve`: a pose problem read from files, solved, printed, written as JSON
(`--out`) and recorded for rerun with every triplet's hypothesis.

With lens distortion (a camera `K` with `dist`), the pose is found on the undistorted
pixels, then, for the optimising methods, refined to the least pixel error in the image
as observed (`jaxpose.geometry.refine_in_image`, what `cv2.solvePnP` and
`cv2.solvePnPRefineLM` minimise), in the camera frame `x_cam = R_wc (R m + t) + t_wc`
and mapped back to the world frame."""

from __future__ import annotations

import time
from pathlib import Path

from ._common import CliError, new_console, setup_jax, write_report
from ._recording import check_recording_args, make_recording, wants_recording

__all__ = ["cmd_solve"]


def _per_triplet_run(C, M, I, mask, method: str, threshold, nonlinear_budget):
    """Every triplet's results for recordings (a stored program per method and budget):
    the three-point poses (`Initial`) for `method="three_point"`, else the mixed
    algorithm's `MixedResult`."""
    from ..geometry._pose import observations
    from ..strategy import Options, initial_poses, mixed, triplet_indices

    triplets = triplet_indices(M.shape[0], Options().max_triplets)
    obs = observations(C, M, I, mask)
    if method == "three_point":
        return initial_poses(obs, triplets=triplets)
    return mixed(obs, threshold=threshold, nonlinear_budget=nonlinear_budget, triplets=triplets)


def _per_triplet_fn(method: str, threshold: float | None, nonlinear_budget: int | None):
    """The stored program of `_per_triplet_run` (one per method and budget)."""
    from ..api._programs import program

    return program(_per_triplet_run, method, threshold, nonlinear_budget)


def _per_triplet(console, camera, model, image, mask, threshold, *, method, nonlinear_budget):
    """Every triplet's hypothesis (numpy), for recordings: see `_per_triplet_fn`."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from ..strategy import Options, triplet_indices

    n = len(model)
    what = "three-point method" if method == "three_point" else "mixed algorithm"
    dtype = jnp.float64 if jax.config.read("jax_enable_x64") else jnp.float32
    count = len(triplet_indices(n, Options().max_triplets))
    with console.status(
        f"compiling and solving the {what} per triplet ({count} triplets) for the recording..."
    ):
        out = _per_triplet_fn(method, threshold, nonlinear_budget)(
            jnp.asarray(camera, dtype),
            jnp.asarray(model, dtype),
            jnp.asarray(image, dtype),
            None if mask is None else jnp.asarray(mask, bool),
        )
        return jax.tree.map(np.asarray, out)


def _image_pass(camera, K, dist, model, observed, image, mask, R, t, R_wc, t_wc, refine: bool):
    """The pose `(R, t)` (world frame) in the distorted image: refined there when
    `refine` (`refine_in_image`, in the camera frame `x_cam = R_wc (R m + t) + t_wc`,
    then back to the world frame; `error` and `pose_error` recomputed at the new pose),
    and the RMS pixel error in the image as observed. One stored program per `refine`
    (`jaxpose.api._programs`). Returns `(R, t, error, pose_error, image_rms)` (the
    errors `-1` when not refined: the solution's stand)."""
    import jax.numpy as jnp

    from ..api._pnp import REFINE_STEPS
    from ..geometry._distortion import project_points, refine_in_image
    from ..geometry._errors import pose_error, reprojection_rms
    from ..geometry._rotation import matrix_to_rotvec, rotvec_to_matrix

    rvec_cam, t_cam = matrix_to_rotvec(R_wc @ R), R_wc @ t + t_wc
    if refine:
        rv, tv, rms = refine_in_image(
            K, dist, model, observed, mask, rvec_cam, t_cam, iterations=REFINE_STEPS
        )
        R, t = R_wc.T @ rotvec_to_matrix(rv), R_wc.T @ (tv - t_wc)
        where = (camera, R, t, model, image, mask)
        return R, t, reprojection_rms(*where), pose_error(*where), rms
    seen = project_points(model, rvec_cam, t_cam, K, dist)
    d2 = jnp.sum((seen - observed) ** 2, axis=1)
    rms = jnp.sqrt(jnp.sum(d2 * mask) / jnp.maximum(jnp.sum(mask), 1))
    return R, t, -jnp.ones_like(rms), -jnp.ones_like(rms), rms


def _in_image(problem, sol, R_wc, t_wc, refine: bool):
    """The solution with its pose refined in the distorted image when `refine`, and the
    RMS pixel error in the image as observed: `(sol, image_rms)` (`_image_pass`)."""
    from typing import Any, cast

    import numpy as np

    from ..api._programs import program
    from ..geometry._pose import Pose

    n = len(problem.model_points)
    mask = np.ones(n, bool) if problem.mask is None else np.asarray(problem.mask, bool)
    f64 = (
        problem.camera,
        problem.K,
        problem.dist,
        problem.model_points,
        problem.observed_points,
        problem.image_points,
    )
    pose = (sol.pose.R, sol.pose.t, R_wc, t_wc)
    args = [np.asarray(a, np.float64) for a in f64] + [mask]
    args += [np.asarray(a, np.float64) for a in pose]
    R, t, error, perr, rms = (np.asarray(a) for a in program(_image_pass, refine)(*args))
    if refine:
        pose = Pose(cast(Any, R), cast(Any, t))  # numpy, as the rest of `sol`
        sol = sol._replace(pose=pose, error=error, pose_error=perr)
    return sol, float(rms)


def cmd_solve(args) -> int:
    """Run `jaxpose solve` with the parsed `args`; returns the exit code (0: a pose is
    accepted, 1: none is)."""
    from rich.table import Table

    console = new_console()
    from ._problem import ProblemError
    from ._problem_read import read_problem

    if args.write_example:
        from ..apps._bench import default_bench
        from ._problem_write import bench_problem, write_problem

        try:
            path = write_problem(args.write_example, bench_problem(default_bench()))
        except (OSError, ValueError) as exc:
            raise CliError(f"cannot write --write-example {args.write_example}: {exc}") from None
        console.print(f"wrote {path} (the embedded bench); try: jaxpose solve {path}")
        return 0
    if args.problem is None and not (args.model or args.image or args.camera):
        raise CliError(
            "give a problem file, or --model, --image and --camera (jaxpose solve --help)"
        )
    if args.threshold is not None and not args.threshold > 0:
        raise CliError(f"--threshold must be > 0, got {args.threshold}")
    if args.photo is not None and not Path(args.photo).is_file():
        raise CliError(f"--photo {args.photo}: no such file")
    check_recording_args(args)
    try:
        problem = read_problem(args.problem, model=args.model, image=args.image, camera=args.camera)
    except ProblemError as exc:
        raise CliError(str(exc)) from None

    setup_jax(True)
    import cv2
    import jax
    import numpy as np

    from ..geometry._camera import decompose_camera
    from ..solvers._status import Status
    from ..strategy import Options, triplet_indices

    n = len(problem.model_points)
    triplets = triplet_indices(n, Options().max_triplets)
    from ..api._solve import solve

    with console.status(f"solving ({args.method}, {n} matches, {len(triplets)} triplets)..."):
        t0 = time.perf_counter()
        # a stored program (compiled once per bucket of matches, loaded by later runs)
        sol = solve(
            problem.camera,
            problem.model_points,
            problem.image_points,
            problem.mask,
            method=args.method,
            threshold=args.threshold,
        )
        sol = jax.tree.map(np.asarray, sol)
        elapsed = time.perf_counter() - t0
    code = Status(int(sol.status))
    accepted = bool(sol.accepted)
    if problem.R_wc is not None:
        R_wc, t_wc = problem.R_wc, problem.t_wc
    else:
        _, R_wc, t_wc, _ = (np.asarray(a) for a in decompose_camera(problem.camera))
    distorted = problem.dist is not None and problem.K is not None
    image_rms = float(sol.error)  # without distortion, the image error is Eq. 8's
    if distorted:
        refine = accepted and args.method != "three_point"
        with console.status("refining the pose in the distorted image..."):
            sol, image_rms = _in_image(problem, sol, R_wc, t_wc, refine)
    R, t = np.asarray(sol.pose.R), np.asarray(sol.pose.t)
    rvec = cv2.Rodrigues(R)[0].ravel()
    R_cam, t_cam = R_wc @ R, R_wc @ t + t_wc
    rvec_cam = cv2.Rodrigues(R_cam)[0].ravel()
    ijk = [int(i) for i in np.asarray(sol.triplet)]

    def vec(v) -> str:
        return "[" + ", ".join(f"{x: .6g}" for x in np.ravel(v)) + "]"

    table = Table(
        title=f"pose of the model ({'accepted' if accepted else 'NO POSE ACCEPTED'})",
        show_header=False,
    )
    table.add_column("", style="bold")
    table.add_column("")
    table.add_row("status", f"{code.name}: {code.message}")
    used = n if problem.mask is None else int(problem.mask.sum())
    undistorted = " (on the undistorted pixels)" if distorted else ""
    table.add_row("Eq. 8 error", f"{float(sol.error):.6g} px over {used} matches{undistorted}")
    table.add_row("image error (RMS)", f"{image_rms:.6g} px in the image as observed")
    table.add_row("pose error (paper)", f"{float(sol.pose_error):.6g} model units")
    table.add_row(
        "rotation vector (rad)",
        f"{vec(rvec)}  (angle {np.degrees(np.linalg.norm(rvec)):.4g} deg)",
    )
    for i in range(3):
        table.add_row("R (model to world)" if i == 0 else "", vec(R[i]))
    table.add_row("t (model to world)", vec(t))
    table.add_row("camera frame rvec, tvec", f"{vec(rvec_cam)}, {vec(t_cam)}")
    table.add_row("from triplet", f"matches {ijk[0]}, {ijk[1]}, {ijk[2]}")
    table.add_row("method", f"{args.method}, solved in {elapsed:.2f} s")
    console.print(table)
    if args.out:
        report = {
            "accepted": accepted,
            "status": code.name,
            "message": code.message,
            "method": args.method,
            "error_px": float(sol.error),
            "image_rms_px": image_rms,
            "refined_in_image": distorted and accepted and args.method != "three_point",
            "pose_error": float(sol.pose_error),
            "rvec": rvec.tolist(),
            "R": R.tolist(),
            "t": t.tolist(),
            "camera_frame": {"rvec": rvec_cam.tolist(), "tvec": t_cam.tolist()},
            "triplet": ijk,
            "matches": n,
            "sources": list(problem.sources),
        }
        write_report(args.out, report, "--out", console)
    if wants_recording(args):
        from ..viz._rerun_solution import log_solution

        mix = _per_triplet(
            console,
            problem.camera,
            problem.model_points,
            problem.image_points,
            problem.mask,
            args.threshold,
            method=args.method,
            nonlinear_budget=32,
        )

        def log(rec):
            log_solution(
                rec,
                problem.camera,
                problem.model_points,
                problem.image_points,
                sol,
                triplets=mix,
                polyhedron=problem.polyhedron,
                true_pose=problem.true_pose,
                image=args.photo,
                image_size=problem.image_size,
                observed_points=problem.observed_points,
                mask=problem.mask,
                K=problem.K,
                R_wc=problem.R_wc,
                t_wc=problem.t_wc,
                method=args.method,
            )

        make_recording(args, console, f"jaxpose solve {' '.join(problem.sources)}", log)
    return 0 if accepted else 1
