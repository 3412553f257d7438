"""The `jaxpose` command line: its parser (every subcommand's options) and its entry
point. Each subcommand runs in its own module: `_reproduce` (the paper's experiment),
`_bench`, `_solve` (a pose problem read from files), `_point` (a click to a 3D point
and the robot), `_recognize` (the known objects a photograph shows), `_track` (an
object followed through a video) and `_warmup`; the
rerun recording options (`--rrd`, `--spawn`, `--serve`) are in `_recording`, problem
files in `_problem`, `_problem_read` and `_problem_write`."""

from __future__ import annotations

import argparse
import os
import sys

from ..api import _programs
from ._bench import cmd_bench
from ._common import CliError
from ._point import cmd_point
from ._recognize import cmd_recognize
from ._recording import add_recording_options
from ._reproduce import cmd_reproduce
from ._solve import cmd_solve
from ._track import cmd_track
from ._warmup import cmd_warmup

__all__ = ["build_parser", "main", "run"]

#: The commands whose stored programs a new process starts loading at once, in the
#: background (`jaxpose.api._programs.prefetch`: those the command's last run used).
PREFETCHED = ("solve", "point", "recognize", "track")


class _Parser(argparse.ArgumentParser):
    """argparse, with a bad argument reported as one line (exit code 2)."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _add_noise_options(parser: argparse.ArgumentParser) -> None:
    """`--seed` and `--noise`: the image noise of the embedded bench (`--noise` left
    `None` here stands for the bench's own sigma, filled in by `main`)."""
    parser.add_argument("--seed", type=int, default=0, help="image-noise seed (default 0)")
    parser.add_argument(
        "--noise", type=float, default=None, help="pixel noise sigma (default: the bench's)"
    )


def _add_threshold_option(parser: argparse.ArgumentParser, help_text: str) -> None:
    """`--threshold`: an acceptance threshold in px, `None` (adaptive) by default."""
    parser.add_argument("--threshold", type=float, default=None, help=help_text)


def build_parser() -> argparse.ArgumentParser:
    """The `jaxpose` argument parser, with its subcommands."""
    parser = _Parser(
        prog="jaxpose",
        description="Pose recovery of a known 3D object from one calibrated image "
        "(Shaheen, Mallem & Chavand 2001), in JAX.",
        epilog="Run `jaxpose COMMAND --help` for the options of a command.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    p = sub.add_parser("reproduce", help="run the paper's experiment on the embedded bench")
    _add_noise_options(p)
    _add_threshold_option(p, "mixed acceptance threshold in px (default: adaptive)")
    p.add_argument("--out", default="results", help="output folder (default ./results)")
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    p.add_argument("--float32", action="store_true", help="compute in float32")
    add_recording_options(p)
    p.set_defaults(func=cmd_reproduce)
    b = sub.add_parser("bench", help="time the paper protocol against OpenCV's loop")
    b.add_argument("--seed", type=int, default=0)
    b.add_argument("--repeat", type=int, default=20)
    b.set_defaults(func=cmd_bench)
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
    _add_threshold_option(s, "acceptance threshold in px (default: adaptive)")
    s.add_argument("--out", metavar="PATH", help="write the pose as JSON to PATH")
    s.add_argument("--photo", metavar="FILE", help="the camera image, shown in the recording")
    s.add_argument(
        "--write-example",
        metavar="PATH",
        help="write the embedded bench as an example problem file (.json or .yaml) and exit",
    )
    add_recording_options(s)
    s.set_defaults(func=cmd_solve)
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
    _add_noise_options(pt)
    pt.add_argument(
        "--click-sigma",
        type=float,
        default=0.0,
        help="uncertainty of the click itself in px, added to the pose's (default 0)",
    )
    add_recording_options(pt)
    pt.set_defaults(func=cmd_point)
    r = sub.add_parser(
        "recognize",
        help="recognise known objects in a photograph: mesh and textured models, their poses",
        description="Find which of the --model objects a photograph shows and where: a "
        ".ply mesh is searched for by its vertices and edges (no correspondence given), a "
        "textured model (OpenCV's .yml/.yaml/.xml/.json, .gz too) by its keypoints. Prints "
        "each detection (polyhedral ones best first, then textured ones by inliers) with "
        "OpenCV's pose (x_cam = Rodrigues(rvec) X + tvec); --json writes them with the "
        "pixels of the model's vertices at the pose. A camera with distortion: the image is "
        "undistorted first, the pose is that camera's, the pixels those of the image as "
        "given. Several images: one table each, --json holds {'images': [{'image', "
        "'detections'}, ...]} and the recording one step of its 'image' timeline each. Exit "
        "code 0 when something is recognised in every image, 1 when not, 2 on bad input.",
    )
    r.add_argument(
        "image",
        nargs="+",
        help="photographs (any format OpenCV reads), or folders of them (sorted by name), "
        "recognised one after the other in one process",
    )
    r.add_argument(
        "--model",
        metavar="FILE",
        action="append",
        required=True,
        help="a .ply mesh or a textured model file (repeat for several models)",
    )
    r.add_argument(
        "--camera",
        metavar="FILE",
        required=True,
        help="OpenCV calibration file with camera_matrix and distortion_coefficients",
    )
    r.add_argument("--json", metavar="PATH", help="write the detections as JSON to PATH")
    r.add_argument(
        "--noise",
        type=float,
        default=None,
        metavar="PX",
        help="image vertex noise sigma for the verification (default: detect's, 1 px)",
    )
    r.add_argument(
        "--min-support",
        type=float,
        default=None,
        metavar="F",
        help="least fraction of a pose's predicted edges and vertices the image must hold "
        "(default: detect's, 0.6)",
    )
    add_recording_options(r)
    r.set_defaults(func=cmd_recognize)
    tr = sub.add_parser(
        "track",
        help="track a known object through a video, a folder of images or a camera",
        description="Follow a known object from frame to frame (moving edges along the "
        "model's visible edges and KLT points, the paper's small-movement linear method), "
        "with a status per frame (initialised, tracked, lost, reinitialised): a frame whose "
        "measurements do not support the pose is lost, and the object is then recognised "
        "again from the mesh (and --textured's keypoints). The first frame's pose is "
        '--init-pose ({"rvec": [..], "tvec": [..]}, OpenCV\'s conventions) or recognised. '
        '--json writes {"frames": [{"index", "ok", "status", "rvec", "tvec", "error_px", '
        '"inliers", "ms"}, ...]} (rvec and tvec null where lost), --csv the same columns. '
        "A progress bar goes to stderr. --point follows a clicked pixel's point of the object. "
        "--smooth refines the trajectory jointly after the "
        "pass. `jaxpose warmup --track` builds the tracker's compiled programs ahead of "
        "time. Exit code 0 when every frame has a pose, 1 when some frame is lost, 2 on "
        "bad input.",
    )
    tr.add_argument("input", help="a video file, a folder of images (sorted by name), or a "
                    "camera index (0, 1, ...)")  # fmt: skip
    tr.add_argument("--model", metavar="MESH", required=True, help="the object's mesh "
                    "(.ply, .obj or ViSP's .cao)")  # fmt: skip
    tr.add_argument("--textured", metavar="MODEL.yml", help="its textured model (OpenCV's "
                    "keypoints YAML), tried first when recognising")  # fmt: skip
    tr.add_argument("--camera", metavar="CAMERA.yml", required=True, help="OpenCV "
                    "calibration file with camera_matrix and distortion_coefficients")  # fmt: skip
    tr.add_argument("--init-pose", metavar="POSE.json", help='the first frame\'s pose, '
                    '{"rvec": [..], "tvec": [..]} (default: recognised)')  # fmt: skip
    tr.add_argument("--json", metavar="OUT.json", help="write the per-frame poses as JSON")
    tr.add_argument("--csv", metavar="OUT.csv", help="write the per-frame poses as CSV")
    tr.add_argument("--overlay", metavar="OUT.mp4", help="write the frames with the model's "
                    "edges drawn at each pose (green tracked, blue found, red lost)")  # fmt: skip
    tr.add_argument("--frames", type=int, metavar="N", help="the first N frames only")
    tr.add_argument("--point", type=float, nargs=2, metavar=("U", "V"), help="a pixel "
                    "clicked on the object on frame --point-frame: the point of the object "
                    "under it is followed on every later frame with a pose (--json and --csv "
                    "gain target, its camera-frame position, target_px and target_visible; "
                    "--overlay marks it)")  # fmt: skip
    tr.add_argument("--point-frame", type=int, default=0, metavar="N", help="the frame "
                    "--point was clicked on (default 0; the first frame from it with a pose "
                    "anchors it)")  # fmt: skip
    tr.add_argument("--no-reinit", action="store_true", help="no recognition after a lost "
                    "frame (the last pose is tried again; needs --init-pose)")  # fmt: skip
    tr.add_argument("--reinit-every", type=int, default=1, metavar="K", help="after a lost "
                    "frame, recognise on one frame in K at most (default 1)")  # fmt: skip
    tr.add_argument("--reinit-wait", type=float, metavar="SECONDS", help="and only SECONDS "
                    "after the last try ended (default 1 for a camera, else 0)")  # fmt: skip
    tr.add_argument("--smooth", action="store_true", help="after the pass, refine the whole "
                    "trajectory jointly (every frame's measurements plus a constant-velocity "
                    "prior: jaxpose.apps.refine_track) and write the refined poses to --json "
                    "and --csv; prints the jitter before and after (--overlay and --rrd show "
                    "the tracked poses)")  # fmt: skip
    tr.add_argument("--smooth-rotation", type=float, default=None, metavar="DEG",
                    help="--smooth's prior: the change of the frame-to-frame rotation "
                    "expected per frame, degrees (default: the spread of the track's own "
                    "second differences, jaxpose.apps.motion_sigmas; larger smooths "
                    "less)")  # fmt: skip
    tr.add_argument("--smooth-translation", type=float, default=None, metavar="F",
                    help="--smooth's prior: the change of the frame-to-frame movement of the "
                    "object's centre expected per frame, as a fraction of its distance "
                    "(default: from the track, as --smooth-rotation's)")  # fmt: skip
    add_recording_options(tr)
    tr.set_defaults(func=cmd_track)
    w = sub.add_parser(
        "warmup",
        help="compile solve_pnp's and solve's programs ahead of time, into the program cache",
        description="Build the compiled programs of solve_pnp, of a plain solve and of a "
        "plain jax.grad of it (and of "
        "solve_pnp_batch for the --batch chunk sizes) for the point buckets holding "
        "--points, and keep them in "
        "the program cache ($JAXPOSE_CACHE_DIR, else ~/.cache/jaxpose), so that a new "
        "process loads them instead of compiling. Programs already there are only loaded. "
        "--track builds the tracker's programs too (jaxpose track's per-frame solve and "
        "its --smooth refinement), so that `jaxpose track` reaches its first tracked frame "
        "without compiling.",
    )
    w.add_argument(
        "--points",
        type=int,
        nargs="+",
        default=[8, 16, 32, 64],
        metavar="N",
        help="point counts whose buckets are built (default 8 16 32 64: every n up to 64)",
    )
    w.add_argument(
        "--batch",
        type=int,
        nargs="*",
        default=[],
        metavar="B",
        help="solve_pnp_batch chunk sizes to build too (default none)",
    )
    w.add_argument(
        "--track",
        action="store_true",
        help="build jaxpose track's programs too: the per-frame solve for 64-512 "
        "measurements (a 640 x 480 video) and the --smooth refinement of up to 512 frames "
        "(10-20 s more the first time on 2 cores; off by default)",
    )
    w.set_defaults(func=cmd_warmup)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the command line on `argv` (default: `sys.argv[1:]`); returns the exit code
    (2 on bad input, reported as one line)."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help (0) or a bad argument (2, one line on stderr)
        return exc.code if isinstance(exc.code, int) else 2
    if args.command is None:
        parser.print_help()
        return 0
    if args.command in ("reproduce", "point") and args.noise is None:
        from ..apps._bench import DEFAULT_NOISE

        args.noise = DEFAULT_NOISE
    stored = args.command in PREFETCHED
    if stored:  # its programs loaded ahead, beside the command's own first steps
        _programs.prefetch(args.command)
    try:
        code = args.func(args)
    except CliError as exc:
        print(f"jaxpose {args.command}: error: {exc}", file=sys.stderr)
        return 2
    if stored:
        _programs.remember(args.command)
    return code


def run() -> None:
    """The `jaxpose` command: `main()` on `sys.argv`, then the process ends at once with
    its exit code, every output flushed and closed (a recording is closed by its
    command), without the interpreter's teardown of JAX's runtime and modules, which
    takes about 0.3 s (AMD EPYC, 2 cores) and shows nothing. An uncaught exception is
    left to Python, as usual."""
    code = main()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
