"""`jaxpose solve`: a pose problem read from files, solved, printed, written as JSON
(`--out`) and recorded for rerun with every triplet's hypothesis.

With lens distortion (a camera `K` with `dist`), the pose is found on the undistorted
pixels, then, for the optimising methods, refined to the least pixel error in the image
as observed (`jaxpose.geometry.refine_in_image`, what `cv2.solvePnP` and
`cv2.solvePnPRefineLM` minimise), in the camera frame `x_cam = R_wc (R m + t) + t_wc`
and mapped back to the world frame."""

from __future__ import annotations

import functools
import time
from pathlib import Path

from ._common import CliError, new_console, setup_jax
from ._recording import check_recording_args, make_recording, wants_recording

__all__ = ["cmd_solve"]


@functools.cache
def _per_triplet_fn(n: int, method: str, threshold: float | None, nonlinear_budget: int | None):
    """Jitted per-triplet results for `n` matches: the three-point poses (`Initial`) for
    `method="three_point"`, else the mixed algorithm's `MixedResult` (cached per process)."""
    import jax

    from ..geometry._pose import observations
    from ..strategy import Options, initial_poses, mixed, triplet_indices

    triplets = triplet_indices(n, Options().max_triplets)

    def run(C, M, I, mask):
        obs = observations(C, M, I, mask)
        if method == "three_point":
            return initial_poses(obs, triplets=triplets)
        return mixed(obs, threshold=threshold, nonlinear_budget=nonlinear_budget, triplets=triplets)

    return jax.jit(run)


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
        out = _per_triplet_fn(n, method, threshold, nonlinear_budget)(
            jnp.asarray(camera, dtype),
            jnp.asarray(model, dtype),
            jnp.asarray(image, dtype),
            None if mask is None else jnp.asarray(mask, bool),
        )
        return jax.tree.map(np.asarray, out)


@functools.cache
def _solve_fn(method: str, threshold: float | None):
    """`jaxpose.solve` jitted for one method and threshold (cached per process)."""
    import jax

    from ..api._solve import solve

    return jax.jit(functools.partial(solve, method=method, threshold=threshold))


@functools.cache
def _refine_fn():
    """`refine_in_image` jitted (cached per process)."""
    import jax

    from ..geometry._distortion import refine_in_image

    return jax.jit(refine_in_image, static_argnames=("iterations",))


def _in_image(problem, sol, R_wc, t_wc, refine: bool):
    """The solution with its pose refined in the distorted image when `refine` (camera
    frame, then back to the world frame; `error` and `pose_error` recomputed at the new
    pose), and the RMS pixel error in the image as observed: `(sol, image_rms)`."""
    import jax.numpy as jnp
    import numpy as np

    from ..api._pnp import REFINE_STEPS
    from ..geometry._distortion import project_points
    from ..geometry._errors import pose_error, reprojection_rms
    from ..geometry._pose import Pose
    from ..geometry._rotation import matrix_to_rotvec, rotvec_to_matrix

    n = len(problem.model_points)
    mask = np.ones(n, bool) if problem.mask is None else np.asarray(problem.mask, bool)
    R, t = np.asarray(sol.pose.R), np.asarray(sol.pose.t)
    rvec_cam = np.asarray(matrix_to_rotvec(R_wc @ R))
    t_cam = R_wc @ t + t_wc
    if refine:
        rv, tv, rms = _refine_fn()(
            jnp.asarray(problem.K, jnp.float64),
            jnp.asarray(problem.dist, jnp.float64),
            jnp.asarray(problem.model_points, jnp.float64),
            jnp.asarray(problem.observed_points, jnp.float64),
            jnp.asarray(mask),
            jnp.asarray(rvec_cam, jnp.float64),
            jnp.asarray(t_cam, jnp.float64),
            iterations=REFINE_STEPS,
        )
        R_cam, t_cam = np.asarray(rotvec_to_matrix(rv)), np.asarray(tv)
        R, t = R_wc.T @ R_cam, R_wc.T @ (t_cam - t_wc)
        where = (problem.camera, R, t, problem.model_points, problem.image_points, mask)
        sol = sol._replace(
            pose=Pose(R, t),
            error=np.asarray(reprojection_rms(*where)),
            pose_error=np.asarray(pose_error(*where)),
        )
        return sol, float(rms)
    seen = project_points(problem.model_points, rvec_cam, t_cam, problem.K, problem.dist)
    d2 = np.sum((np.asarray(seen) - problem.observed_points) ** 2, axis=1)
    return sol, float(np.sqrt(np.sum(d2 * mask) / max(int(mask.sum()), 1)))


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
    import jax
    import numpy as np

    from ..geometry._camera import decompose_camera
    from ..geometry._rotation import matrix_to_rotvec
    from ..solvers._status import Status
    from ..strategy import Options, triplet_indices

    n = len(problem.model_points)
    triplets = triplet_indices(n, Options().max_triplets)
    run = _solve_fn(args.method, args.threshold)
    with console.status(
        f"compiling and solving ({args.method}, {n} matches, {len(triplets)} triplets)..."
    ):
        t0 = time.perf_counter()
        sol = jax.tree.map(
            np.asarray,
            run(problem.camera, problem.model_points, problem.image_points, problem.mask),
        )
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
    rvec = np.asarray(matrix_to_rotvec(R))
    R_cam, t_cam = R_wc @ R, R_wc @ t + t_wc
    rvec_cam = np.asarray(matrix_to_rotvec(R_cam))
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
    table.add_row("method", f"{args.method}, solved in {elapsed:.2f} s (compilation included)")
    console.print(table)
    if args.out:
        from ._problem_write import dumps

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
        out = Path(args.out)
        try:
            out.parent.mkdir(parents=True, exist_ok=True)
            out.write_text(dumps(report) + "\n")
        except OSError as exc:
            raise CliError(f"cannot write --out {out}: {exc.strerror or exc}") from None
        console.print(f"wrote {out}")
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
