"""The `jaxpose` command line: `reproduce` (the paper's experiment), `bench` and `solve`
(a pose problem read from files), with rerun recordings (`--rrd`, `--spawn`, `--serve`)."""

from __future__ import annotations

import argparse
import functools
import os
import sys
import time
from pathlib import Path

__all__ = ["main"]


class CliError(Exception):
    """An error to report as one line, without a traceback."""


class _Parser(argparse.ArgumentParser):
    """argparse, with a bad argument reported as one line (exit code 2)."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _console():
    from rich.console import Console

    # Table 1 needs about 100 columns; rich falls back to 80 when output is not a terminal.
    return Console(width=None if sys.stdout.isatty() else 110)


def _setup_jax(x64: bool = True) -> None:
    import jax

    # The command line owns its process: float64 (OpenCV-level accuracy) unless asked not
    # to, and JAX's persistent compilation cache so that a second run starts fast.
    jax.config.update("jax_enable_x64", x64)
    cache = Path.home() / ".cache" / "jaxpose" / "xla"
    try:
        cache.mkdir(parents=True, exist_ok=True)
        jax.config.update("jax_compilation_cache_dir", str(cache))
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    except OSError:  # pragma: no cover - read-only home
        pass


def _cmd_reproduce(args) -> int:
    from rich.table import Table

    console = _console()
    _setup_jax(not args.float32)
    from ..apps import _bench as _bench
    from ..apps import _experiment as _experiment

    if args.noise < 0:
        raise CliError(f"--noise must be >= 0, got {args.noise}")
    _check_recording_args(args)
    bench = _bench.default_bench(seed=args.seed, noise=args.noise)
    console.print(
        f"[bold]jaxpose reproduce[/]: cross prism, {len(bench.model_points)} matched vertices, "
        f"noise {bench.noise:g} px (seed {bench.seed}), camera f = {bench.K[0, 0]:g} px, "
        f"image {bench.image_size[0]}x{bench.image_size[1]}"
    )
    t0 = time.perf_counter()
    with console.status("compiling and solving all triplets with the four methods..."):
        result = _experiment.run_experiment(bench, threshold=args.threshold)
    t1 = time.perf_counter()
    with console.status("solving again (compiled)..."):
        result = _experiment.run_experiment(bench, threshold=args.threshold)
    t2 = time.perf_counter()
    c = result.counts
    pc = _experiment.PAPER_COUNTS
    console.print(
        f"triplets {c['triplets']} (paper {pc['triplets']}); aligned, area < 40 px^2: "
        f"{c['aligned']} (paper {pc['aligned']}); collinear model points: "
        f"{c['collinear_model']}; no three-point solution: {c['no_solution']}; "
        f"used {c['used']} (paper {pc['used']})"
    )
    stats = result.statistics()
    table = Table(title="Table 1: pose error (mm) per method: ours / paper")
    table.add_column("")
    labels = {
        "three_point": "3-segment",
        "nonlinear": "non-linear",
        "linear": "linear",
        "mixed": "mixed",
    }
    for m in _experiment.METHOD_NAMES:
        table.add_column(labels[m], justify="right")
    rows = [
        ("mean", "mean"),
        ("standard deviation", "std"),
        ("mean deviation", "mean_deviation"),
        ("minimum", "min"),
    ]
    for label, key in rows:
        table.add_row(
            label,
            *(
                f"{stats[m][key]:.3f} / {_experiment.PAPER_TABLE1[m][key]:.3f}"
                for m in _experiment.METHOD_NAMES
            ),
        )
    table.add_row(
        "at the optimum",
        *(f"{100 * stats[m]['at_optimum']:.2f}%" for m in _experiment.METHOD_NAMES),
    )
    console.print(table)
    console.print(
        f"optimum pose error {result.optimum:.3f} mm (paper 0.578); mixed at the optimum "
        f"{100 * stats['mixed']['at_optimum']:.2f}% of used triplets (paper "
        f"{100 * _experiment.PAPER_MIXED_AT_OPTIMUM:.2f}%); acceptance threshold "
        f"{result.threshold:.3f} px"
    )
    console.print(f"mixed statuses: {result.status_counts('mixed')}")
    console.print(
        f"time: first run (compile + solve) {t1 - t0:.1f} s, compiled run {1e3 * (t2 - t1):.1f} ms"
    )
    out = Path(args.out)
    try:
        json_path = _experiment.write_json(result, out / "results.json")
        figures = [] if args.no_figures else _experiment.write_figures(result, out)
    except OSError as exc:
        raise CliError(f"cannot write to --out {out}: {exc}") from exc
    console.print(f"wrote {json_path}" + "".join(f", {p}" for p in figures))
    if _wants_recording(args):
        from ..viz._rerun import log_experiment

        mix = result.mixed
        from ..viz._overlay import render_bench

        picture = render_bench(bench)[..., ::-1].copy()  # the bench seen by its camera (RGB)
        _record(
            args,
            console,
            "jaxpose reproduce",
            lambda rec: log_experiment(rec, bench, result, mix, image=picture),
        )
    return 0


def _cmd_bench(args) -> int:
    from rich.table import Table

    console = _console()
    _setup_jax(True)
    import cv2
    import jax
    import jax.numpy as jnp
    import numpy as np

    from ..api._solve import solve
    from ..apps import _bench as _bench

    bench = _bench.default_bench(seed=args.seed)
    C, M, I = (jnp.asarray(x) for x in (bench.camera, bench.model_points, bench.image_points))
    f = jax.jit(lambda C, M, I: solve(C, M, I, method="mixed"))
    with console.status("compiling the mixed algorithm..."):
        t0 = time.perf_counter()
        jax.block_until_ready(f(C, M, I))
        compile_s = time.perf_counter() - t0
    times = []
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        jax.block_until_ready(f(C, M, I))
        times.append(time.perf_counter() - t0)
    ours = float(np.median(times))

    # The equivalent OpenCV loop: P3P per triplet, best root over all matches, LM refine.
    from ..strategy._mixed import triplet_indices

    K = bench.K
    world = np.asarray(bench.model_points)
    img = np.asarray(bench.image_points)
    trip = triplet_indices(len(world))

    def opencv_loop():
        best = None
        for ijk in trip:
            try:
                n, rvecs, tvecs = cv2.solveP3P(
                    world[ijk], img[ijk], K, None, flags=cv2.SOLVEPNP_P3P
                )
            except cv2.error:
                continue
            for rv, tv in zip(rvecs[:n], tvecs[:n]):
                proj, _ = cv2.projectPoints(world, rv, tv, K, None)
                e = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - img) ** 2, 1))))
                if np.isfinite(e) and (best is None or e < best[0]):
                    best = (e, rv, tv)
            if best is not None:
                cv2.solvePnPRefineLM(world, img, K, None, best[1].copy(), best[2].copy())
        return best

    t0 = time.perf_counter()
    for _ in range(max(1, args.repeat // 10)):
        opencv_loop()
    cv = (time.perf_counter() - t0) / max(1, args.repeat // 10)
    table = Table(title=f"paper protocol: all {len(trip)} triplets of the bench")
    table.add_column("solver")
    table.add_column("time", justify="right")
    table.add_column("ratio", justify="right")
    table.add_row("jaxpose mixed (compiled)", f"{1e3 * ours:.2f} ms", "1.0x")
    table.add_row(
        "OpenCV loop (solveP3P, best root, RefineLM)",
        f"{1e3 * cv:.2f} ms",
        f"{cv / ours:.1f}x slower",
    )
    console.print(table)
    console.print(
        f"compile (first call): {compile_s:.1f} s. For the full benchmark suite: `make bench`."
    )
    return 0


# --------------------------------------------------------------------------- rerun recordings


def _add_recording_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("rerun recording (open a .rrd file with `rerun FILE`)")
    g.add_argument(
        "--rrd", metavar="PATH", help="write a rerun recording of the run to PATH (.rrd)"
    )
    g.add_argument(
        "--spawn",
        action="store_true",
        help="also stream the recording to a new native rerun viewer (needs a display)",
    )
    g.add_argument(
        "--serve",
        action="store_true",
        help="also serve the recording to the rerun web viewer, until Ctrl-C",
    )
    g.add_argument(
        "--port", type=int, default=9876, help="gRPC port for --spawn/--serve (default 9876)"
    )


def _wants_recording(args) -> bool:
    return bool(args.rrd or args.spawn or args.serve)


def _check_recording_args(args) -> None:
    """Fail fast (before any long computation) on recording options that cannot work."""
    if args.rrd:
        path = Path(args.rrd)
        if path.suffix != ".rrd":
            raise CliError(f"--rrd must name a .rrd file, got {path}")
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise CliError(f"cannot write --rrd {path}: {exc.strerror or exc}") from None
        if path.is_dir() or not os.access(path if path.exists() else path.parent, os.W_OK):
            raise CliError(f"cannot write --rrd {path}: not writable")
    if args.spawn and sys.platform.startswith("linux"):
        if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
            raise CliError(
                "--spawn needs a display (DISPLAY is not set): use --serve, or --rrd and "
                "open the file where there is one"
            )
    if not 0 < args.port < 65536:
        raise CliError(f"--port must be in 1..65535, got {args.port}")


@functools.cache
def _per_triplet_fn(n: int, method: str, threshold: float | None, nonlinear_budget: int | None):
    """Jitted per-triplet results for `n` matches: the three-point poses (`Initial`) for
    `method="three_point"`, else the mixed algorithm's `MixedResult` (cached per process)."""
    import jax

    from ..geometry._pose import observations
    from ..strategy._mixed import initial_poses, mixed, triplet_indices

    triplets = triplet_indices(n, 2000)

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

    from ..strategy._mixed import triplet_indices

    n = len(model)
    what = "three-point method" if method == "three_point" else "mixed algorithm"
    dtype = jnp.float64 if jax.config.read("jax_enable_x64") else jnp.float32
    with console.status(
        f"compiling and solving the {what} per triplet ({len(triplet_indices(n, 2000))} "
        "triplets) for the recording..."
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


def _record(args, console, name: str, log) -> None:
    """Make the recording asked for by --rrd / --spawn / --serve; `log(rec)` fills it."""
    from ..viz import _rerun as _rerun

    with console.status("writing the rerun recording..."):
        rec = _rerun.rerun_recording(
            args.rrd, name=name, spawn=args.spawn, serve=args.serve, port=args.port
        )
        log(rec)
        rec.flush()
    if args.rrd:
        console.print(f"wrote {args.rrd} (open it with: rerun {args.rrd})")
    if args.spawn:
        console.print("streamed the recording to the rerun viewer")
    if args.serve:
        url = _rerun.serve_web_viewer(args.port)
        console.print(
            f"serving the recording: web viewer at {url} ; native viewer: "
            f"rerun rerun+http://127.0.0.1:{args.port}/proxy ; Ctrl-C to stop"
        )
        try:
            while True:
                time.sleep(1.0)
        except KeyboardInterrupt:
            pass
    _rerun.close_recording(rec)


# --------------------------------------------------------------------------- solve


def _cmd_solve(args) -> int:
    from rich.table import Table

    console = _console()
    from ._problem import ProblemError, read_problem, write_problem

    if args.write_example:
        from ..apps._bench import default_bench
        from ._problem import bench_problem

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
    _check_recording_args(args)
    try:
        problem = read_problem(args.problem, model=args.model, image=args.image, camera=args.camera)
    except ProblemError as exc:
        raise CliError(str(exc)) from None

    _setup_jax(True)
    import jax
    import numpy as np

    from ..geometry._camera import decompose_camera
    from ..geometry._rotation import matrix_to_rotvec
    from ..solvers._status import Status
    from ..strategy._mixed import triplet_indices

    n = len(problem.model_points)
    triplets = triplet_indices(n, 2000)
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
    R, t = np.asarray(sol.pose.R), np.asarray(sol.pose.t)
    rvec = np.asarray(matrix_to_rotvec(R))
    if problem.R_wc is not None:
        R_wc, t_wc = problem.R_wc, problem.t_wc
    else:
        _, R_wc, t_wc, _ = (np.asarray(a) for a in decompose_camera(problem.camera))
    R_cam, t_cam = R_wc @ R, R_wc @ t + t_wc
    rvec_cam = np.asarray(matrix_to_rotvec(R_cam))
    ijk = [int(i) for i in triplets[int(sol.triplet)]]

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
    table.add_row("Eq. 8 error", f"{float(sol.error):.6g} px over {used} matches")
    table.add_row("pose error (paper)", f"{float(sol.pose_error):.6g} model units")
    table.add_row(
        "rotation vector (rad)",
        f"{vec(rvec)}  (angle {np.degrees(np.linalg.norm(rvec)):.4g} deg)",
    )
    for i in range(3):
        table.add_row("R (model to world)" if i == 0 else "", vec(R[i]))
    table.add_row("t (model to world)", vec(t))
    table.add_row("camera frame rvec, tvec", f"{vec(rvec_cam)}, {vec(t_cam)}")
    table.add_row("from triplet", f"{int(sol.triplet)} (matches {ijk[0]}, {ijk[1]}, {ijk[2]})")
    table.add_row("method", f"{args.method}, solved in {elapsed:.2f} s (compilation included)")
    console.print(table)
    if args.out:
        from ._problem import _dumps

        report = {
            "accepted": accepted,
            "status": code.name,
            "message": code.message,
            "method": args.method,
            "error_px": float(sol.error),
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
            out.write_text(_dumps(report) + "\n")
        except OSError as exc:
            raise CliError(f"cannot write --out {out}: {exc.strerror or exc}") from None
        console.print(f"wrote {out}")
    if _wants_recording(args):
        from ..viz._rerun import log_solution

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

        _record(args, console, f"jaxpose solve {' '.join(problem.sources)}", log)
    return 0 if accepted else 1


# --------------------------------------------------------------------------- point


@functools.cache
def _point_pipeline():
    """`jaxpose point`'s computation, compiled once per process: solve the bench, its pose
    covariance, the click's point (and the true one), the robot's joints."""
    import jax

    from ..api._solve import solve
    from ..apps._pointing import pick
    from ..apps._robot import forward_kinematics, inverse_kinematics
    from ..geometry._pose import Pose
    from ..strategy._covariance import pose_covariance

    def run(C, M, I, pixel, R_true, t_true, faces, click_cov, robot):
        sol = solve(C, M, I)
        cov = pose_covariance(C, M, I, sol.pose)
        hit = pick(C, faces, sol.pose, pixel, cov.covariance, click_cov)
        truth = pick(C, faces, Pose(R_true, t_true), pixel)
        cmd = inverse_kinematics(robot, hit.point, -hit.normal)
        return sol, cov, hit, truth, cmd, forward_kinematics(robot, cmd.joints)

    return jax.jit(run)


def _cmd_point(args) -> int:
    import math

    from rich.markup import escape
    from rich.table import Table

    console = _console()
    u, v = args.pixel
    if not (math.isfinite(u) and math.isfinite(v)):
        raise CliError(f"--pixel must be finite, got {u} {v}")
    if args.noise < 0 or not args.click_sigma >= 0:
        raise CliError(
            f"--noise and --click-sigma must be >= 0, got {args.noise}, {args.click_sigma}"
        )
    from ..apps._bench import default_bench

    bench = default_bench(seed=args.seed, noise=args.noise)
    width, height = bench.image_size
    if not (0 <= u <= width and 0 <= v <= height):
        raise CliError(f"--pixel {u:g} {v:g} is outside the {width}x{height} image")
    _check_recording_args(args)
    _setup_jax(True)
    import jax
    import jax.numpy as jnp
    import numpy as np

    from ..apps._pointing import polyhedron_faces
    from ..apps._robot import default_robot
    from ..solvers._status import Status

    faces = polyhedron_faces(bench.model)
    robot = default_robot()
    with console.status("compiling and solving the bench, then pointing..."):
        t0 = time.perf_counter()
        out = _point_pipeline()(
            *(jnp.asarray(x) for x in (bench.camera, bench.model_points, bench.image_points)),
            jnp.asarray([u, v], jnp.float64),
            jnp.asarray(bench.R),
            jnp.asarray(bench.t),
            faces,
            jnp.asarray(args.click_sigma**2 * np.eye(2)),
            robot,
        )
        sol, cov, hit, truth, cmd, state = jax.tree.map(np.asarray, out)
        elapsed = time.perf_counter() - t0

    def mm(x) -> str:
        return "(" + ", ".join(f"{c:.2f}" for c in np.ravel(x)) + ") mm"

    def record(lines: list[str], reached: bool) -> None:
        """The rerun recording (--rrd/--spawn/--serve) of this pointing command."""
        if not _wants_recording(args):
            return
        from ..viz._overlay import render_bench
        from ..viz._rerun import log_pointing

        picture = render_bench(bench)[..., ::-1].copy()  # the bench seen by its camera (RGB)
        found = int(hit.status) == Status.OK
        _record(
            args,
            console,
            f"jaxpose point {u:g} {v:g}",
            lambda rec: log_pointing(
                rec,
                bench.camera,
                (u, v),
                hit if found else None,
                (sol.pose.R, sol.pose.t),
                polyhedron=bench.model,
                model_points=bench.model_points,
                robot=robot if reached else None,
                joints=cmd.joints if reached else None,
                true_point=truth.point if found and int(truth.status) == Status.OK else None,
                image=picture,
                image_size=bench.image_size,
                K=bench.K,
                R_wc=bench.R_wc,
                t_wc=bench.t_wc,
                summary=lines,
            ),
        )

    if not bool(sol.accepted):
        code = Status(int(sol.status))
        print(f"jaxpose point: no pose accepted on the bench ({code.name}: {code.message})")
        return 1
    if int(hit.status) != Status.OK:
        code = Status(int(hit.status))
        line = f"no face at pixel ({u:g}, {v:g}): {code.message}"
        print(f"jaxpose point: {line}")
        record([f"# jaxpose point: {line}"], reached=False)
        return 1
    face = int(hit.face)
    name = {0: "top", 1: "bottom"}.get(face, f"side {face - 2}")
    if int(cmd.status) != Status.OK:
        code = Status(int(cmd.status))
        line = (
            f"the point {mm(hit.point)} on face {face} ({name}) is out of the "
            f"robot's reach ({code.name}): {code.message}"
        )
        print(f"jaxpose point: {line}")
        record([f"# jaxpose point: {line}"], reached=False)
        return 1

    S = hit.covariance
    o = bench.R_wc.T @ -bench.t_wc
    ray = (hit.point - o) / np.linalg.norm(hit.point - o)
    table = Table(
        title=f"pixel ({u:g}, {v:g}) on the bench (seed {bench.seed}, noise {bench.noise:g} px)",
        show_header=False,
    )
    table.add_column("", style="bold")
    table.add_column("")
    table.add_row(
        "pose",
        f"{Status(int(sol.status)).name}, Eq. 8 error {float(sol.error):.3f} px, estimated "
        f"pixel noise {float(cov.sigma):.3f} px",
    )
    table.add_row("face", f"{face} ({name}), outward normal {escape(str(hit.normal.round(3)))}")
    table.add_row("3D point (world)", mm(hit.point))
    table.add_row(
        "1-sigma",
        f"{mm(np.sqrt(np.diag(S)))} in x, y, z; {math.sqrt(ray @ S @ ray):.2f} mm along the ray"
        + (f" (click {args.click_sigma:g} px included)" if args.click_sigma > 0 else ""),
    )
    table.add_row("distance from the camera", f"{float(hit.distance):.1f} mm")
    if int(truth.status) == Status.OK:
        err = hit.point - truth.point
        table.add_row(
            "true surface point",
            f"{mm(truth.point)} on face {int(truth.face)}: error {np.linalg.norm(err):.2f} mm"
            f" ({abs(err @ ray) / max(math.sqrt(ray @ S @ ray), 1e-300):.1f} sigma along the ray)",
        )
    x, y, pan, tilt = cmd.joints
    table.add_row(
        "robot joints",
        f"x {x:.2f} mm, y {y:.2f} mm, pan {math.degrees(pan):.2f} deg, "
        f"tilt {math.degrees(tilt):.2f} deg",
    )
    table.add_row(
        "robot tip",
        f"{mm(state.tip)} (off by {float(cmd.error):.1e} mm); shank "
        f"{math.degrees(float(cmd.approach_angle)):.1f} deg from the face's inward normal",
    )
    table.add_row("time", f"{elapsed:.2f} s (compilation included)")
    console.print(table)
    along = math.sqrt(ray @ S @ ray)
    record(
        [
            f"# jaxpose point ({u:g}, {v:g}): face {face} ({name})",
            "",
            f"- pose: {Status(int(sol.status)).name}, Eq. 8 error {float(sol.error):.3f} px",
            f"- 3D point (world): {mm(hit.point)}, {float(hit.distance):.1f} mm from the camera",
            f"- 1-sigma: {mm(np.sqrt(np.diag(S)))} in x, y, z; {along:.2f} mm along the ray"
            " (ellipsoid drawn at 3 sigma)",
            f"- robot joints: x {x:.2f} mm, y {y:.2f} mm, pan {math.degrees(pan):.2f} deg, "
            f"tilt {math.degrees(tilt):.2f} deg; tip {mm(state.tip)}",
        ]
        + (
            [f"- true surface point: {mm(truth.point)} on face {int(truth.face)}"]
            if int(truth.status) == Status.OK
            else []
        ),
        reached=True,
    )
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="jaxpose",
        description="Pose recovery of a known 3D object from one calibrated image "
        "(Shaheen, Mallem & Chavand 2001), in JAX.",
        epilog="Run `jaxpose COMMAND --help` for the options of a command.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    p = sub.add_parser("reproduce", help="run the paper's experiment on the embedded bench")
    p.add_argument("--seed", type=int, default=0, help="image-noise seed (default 0)")
    p.add_argument(
        "--noise", type=float, default=None, help="pixel noise sigma (default: the bench's)"
    )
    p.add_argument(
        "--threshold",
        type=float,
        default=None,
        help="mixed acceptance threshold in px (default: adaptive)",
    )
    p.add_argument("--out", default="results", help="output folder (default ./results)")
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    p.add_argument("--float32", action="store_true", help="compute in float32")
    _add_recording_options(p)
    p.set_defaults(func=_cmd_reproduce)
    b = sub.add_parser("bench", help="time the paper protocol against OpenCV's loop")
    b.add_argument("--seed", type=int, default=0)
    b.add_argument("--repeat", type=int, default=20)
    b.set_defaults(func=_cmd_bench)
    s = sub.add_parser(
        "solve",
        help="recover a pose from a model, image points and a camera read from files",
        description="Recover the pose of a known object from files: a problem file (JSON "
        'or OpenCV YAML) and/or --model, --image and --camera files. JSON: {"camera": '
        '{"K": 3x3, "dist": [...], "R": 3x3, "t": [3]} or {"C": 3x4}, "model_points": '
        '[[x, y, z], ...], "image_points": [[u, v], ...], "mask": [...]}. OpenCV YAML '
        "(cv2.FileStorage): camera_matrix, distortion_coefficients, object_points, "
        "image_points. Points may also be .csv/.txt tables. The pose maps model to world "
        "(p = R m + t); exit code 0 when a pose is accepted, 1 when none is, 2 on bad input.",
    )
    s.add_argument("problem", nargs="?", help="problem file (.json, .yaml/.yml, .xml)")
    s.add_argument("--model", metavar="FILE", help="model points (or a polyhedron) file")
    s.add_argument("--image", metavar="FILE", help="image points file")
    s.add_argument("--camera", metavar="FILE", help="camera file (e.g. an OpenCV calibration)")
    s.add_argument(
        "--method",
        choices=("mixed", "three_point", "linear", "nonlinear"),
        default="mixed",
        help="pose-recovery method (default mixed)",
    )
    s.add_argument(
        "--threshold",
        type=float,
        default=None,
        help="acceptance threshold in px (default: adaptive)",
    )
    s.add_argument("--out", metavar="PATH", help="write the pose as JSON to PATH")
    s.add_argument("--photo", metavar="FILE", help="the camera image, shown in the recording")
    s.add_argument(
        "--write-example",
        metavar="PATH",
        help="write the embedded bench as an example problem file (.json or .yaml) and exit",
    )
    _add_recording_options(s)
    s.set_defaults(func=_cmd_solve)
    pt = sub.add_parser(
        "point",
        help="click a pixel of the bench: its 3D point, face, uncertainty and robot joints",
        description="Solve the default bench, intersect the visual ray of a clicked pixel "
        "with the recognised object's faces, and command the paper's 4-DOF robot to the "
        "point (world frame, mm); --rrd/--spawn/--serve record the scene, the ray, the "
        "point with its covariance and the robot for the rerun viewer. Exit code 0 when "
        "the robot can reach it, 1 when there is no face there or it is out of reach, 2 on "
        "bad input.",
    )
    pt.add_argument(
        "--pixel", type=float, nargs=2, required=True, metavar=("U", "V"), help="the click"
    )
    pt.add_argument("--seed", type=int, default=0, help="image-noise seed (default 0)")
    pt.add_argument(
        "--noise", type=float, default=None, help="pixel noise sigma (default: the bench's)"
    )
    pt.add_argument(
        "--click-sigma",
        type=float,
        default=0.0,
        help="uncertainty of the click itself in px, added to the pose's (default 0)",
    )
    _add_recording_options(pt)
    pt.set_defaults(func=_cmd_point)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help (0) or a bad argument (2, one line on stderr)
        return exc.code if isinstance(exc.code, int) else 2
    if args.command is None:
        parser.print_help()
        return 0
    if getattr(args, "noise", 0) is None:
        from ..apps._bench import DEFAULT_NOISE

        args.noise = DEFAULT_NOISE
    try:
        return args.func(args)
    except CliError as exc:
        print(f"jaxpose {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
