"""`jaxpose point`: a clicked pixel of the bench to its 3D point, face and uncertainty,
and the robot's joints to reach it."""

from __future__ import annotations

import time

from ._common import CliError, new_console, setup_jax
from ._recording import check_recording_args, make_recording, wants_recording

__all__ = ["cmd_point"]


def _point_run(C, M, image, R, t, pixel, R_true, t_true, faces, click_cov, robot):
    """`jaxpose point`'s computation after the solve, one stored program
    (`jaxpose.api._programs`: compiled once, loaded by later processes): the pose
    covariance of the answer `Pose(R, t)`, the click's point (and the true one), the
    robot's joints."""
    from ..apps._pointing import pick
    from ..apps._robot import forward_kinematics, inverse_kinematics
    from ..geometry._pose import Pose
    from ..strategy._covariance import pose_covariance

    pose = Pose(R, t)
    cov = pose_covariance(C, M, image, pose)
    hit = pick(C, faces, pose, pixel, cov.covariance, click_cov)
    truth = pick(C, faces, Pose(R_true, t_true), pixel)
    cmd = inverse_kinematics(robot, hit.point, -hit.normal)
    return cov, hit, truth, cmd, forward_kinematics(robot, cmd.joints)


def cmd_point(args) -> int:
    """Run `jaxpose point` with the parsed `args`; returns the exit code (0: the robot
    reaches the point, 1: no face there or out of reach)."""
    import math

    from rich.markup import escape
    from rich.table import Table

    console = new_console()
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
    check_recording_args(args)
    setup_jax(True)
    import jax
    import numpy as np

    from ..api._programs import program
    from ..api._solve import solve
    from ..apps._pointing import PointingStatus, polyhedron_faces
    from ..apps._robot import RobotStatus, default_robot
    from ..solvers._status import Status

    faces = polyhedron_faces(bench.model)
    robot = default_robot()
    with console.status("compiling and solving the bench, then pointing..."):
        t0 = time.perf_counter()
        f64 = (bench.camera, bench.model_points, bench.image_points, [u, v], bench.R, bench.t)
        cov = np.asarray(args.click_sigma**2 * np.eye(2))
        C, M, image, pixel, R_true, t_true = (np.asarray(x, np.float64) for x in f64)
        # jaxpose.solve's own stored program (the one `jaxpose solve` and a plain
        # `jp.solve` of the bench load), then this command's
        sol = jax.tree.map(np.asarray, solve(C, M, image))
        rest = (sol.pose.R, sol.pose.t, pixel, R_true, t_true, faces, cov, robot)
        out = program(_point_run)(C, M, image, *rest)
        cov, hit, truth, cmd, state = jax.tree.map(np.asarray, out)
        elapsed = time.perf_counter() - t0

    def mm(x) -> str:
        return "(" + ", ".join(f"{c:.2f}" for c in np.ravel(x)) + ") mm"

    def record(lines: list[str], reached: bool) -> None:
        """The rerun recording (--rrd/--spawn/--serve) of this pointing command."""
        if not wants_recording(args):
            return
        from ..viz._overlay import render_bench
        from ..viz._rerun_pointing import log_pointing

        picture = render_bench(bench)[..., ::-1].copy()  # the bench seen by its camera (RGB)
        found = int(hit.status) == PointingStatus.OK
        make_recording(
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
                true_point=(
                    truth.point if found and int(truth.status) == PointingStatus.OK else None
                ),
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
    if int(hit.status) != PointingStatus.OK:
        code = PointingStatus(int(hit.status))
        line = f"no face at pixel ({u:g}, {v:g}): {code.message}"
        print(f"jaxpose point: {line}")
        record([f"# jaxpose point: {line}"], reached=False)
        return 1
    face = int(hit.face)
    name = {0: "top", 1: "bottom"}.get(face, f"side {face - 2}")
    if int(cmd.status) != RobotStatus.OK:
        code = RobotStatus(int(cmd.status))
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
    if int(truth.status) == PointingStatus.OK:
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
    table.add_row("time", f"{elapsed:.2f} s")
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
            if int(truth.status) == PointingStatus.OK
            else []
        ),
        reached=True,
    )
    return 0
