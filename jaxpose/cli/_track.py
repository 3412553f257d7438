"""`jaxpose track`: a known object followed through a video, a folder of images or a live
camera (`jaxpose.apps.track`: moving edges and KLT points, the paper's small-movement
linear method), with an honest status per frame and re-initialisation by recognition
(`jaxpose.apps.recognition_reinit`) after a lost frame.

The first frame's pose is given (`--init-pose POSE.json`, `{"rvec": [..], "tvec":
[..]}`, OpenCV's conventions: `x_cam = Rodrigues(rvec) X + tvec`) or recognised from the
mesh (the keypoints of `--textured` first). Outputs: `--json` (`{"frames": [{"index",
"ok", "status", "rvec", "tvec", "error_px", "inliers", "ms"}, ...]}`, one entry per
input frame; `rvec` and `tvec` null on a lost frame), `--csv` (the same columns),
`--rrd` (the rerun recording: `jaxpose.viz._tracking`) and `--overlay` (an mp4 of the
frames with the model's visible edges drawn at each pose). A progress bar goes to
stderr. `--point U V [--point-frame N]`: a clicked pixel's point of the object followed
(`jaxpose.apps.follow_click`): `--json` and `--csv` gain its camera-frame position, its
pixel, whether it is in sight and its standard deviation; `--overlay` and `--rrd` show
it.

`--smooth`: after the pass, the whole trajectory is refined jointly
(`jaxpose.apps.refine_track`: every frame's stored measurements, the planes of the
paper's small-movement method (Section 2.2, Eqs. 5-7) with their robust weights, plus a
constant-velocity prior) and the refined poses are what `--json` and `--csv` hold
(`error_px` then the frame's RMS residual at its refined pose); the jitter before and
after is printed. `--overlay` and `--rrd` are written during the pass: they show the
tracked poses.

The command computes in float64 (as `jaxpose recognize` and the benchmarks do), so that
its compiled programs are those `jaxpose warmup --track` builds; the console (rich) is
set up only after the pass, so that nothing but the tracker stands before the first
frame.
"""

from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ._common import CliError, camera_option, new_console, setup_jax
from ._recording import (
    check_recording_args,
    finish_recording,
    open_recording,
    wants_recording,
)

if TYPE_CHECKING:  # pragma: no cover
    import numpy as np

__all__ = ["cmd_track", "jitter", "read_init_pose"]

#: The columns of `--csv` (the keys of each `--json` frame; rvec and tvec as 3 each).
CSV_COLUMNS = ("index", "ok", "status", "rvec_x", "rvec_y", "rvec_z", "tvec_x", "tvec_y",
               "tvec_z", "error_px", "inliers", "ms")  # fmt: skip
#: `--point`'s columns, after those.
TARGET_COLUMNS = ("target_x", "target_y", "target_z", "target_u", "target_v", "target_visible",
                  "target_std_x", "target_std_y", "target_std_z")  # fmt: skip


def read_init_pose(path: str) -> tuple[np.ndarray, np.ndarray]:
    """`(rvec (3,), tvec (3,))` of a POSE.json file; `CliError` naming `--init-pose`."""
    import numpy as np

    where = f"--init-pose {path}"
    try:
        data = json.loads(Path(path).read_text())
    except OSError as exc:
        raise CliError(f"{where}: cannot read: {exc.strerror or exc}") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise CliError(f"{where}: not JSON ({exc})") from None
    if not isinstance(data, dict) or "rvec" not in data or "tvec" not in data:
        raise CliError(f'{where}: expected {{"rvec": [3 numbers], "tvec": [3 numbers]}}')
    out = []
    for key in ("rvec", "tvec"):
        try:
            value = np.asarray(data[key], dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            value = np.zeros(0)
        if value.shape != (3,) or not np.all(np.isfinite(value)):
            raise CliError(f"{where}: {key} must be 3 finite numbers, got {data[key]!r}")
        out.append(value)
    if not out[1][2] > 0:
        raise CliError(f"{where}: tvec must put the object in front of the camera (z > 0)")
    return out[0], out[1]


def _source(text: str):
    """A camera index for a string of digits that names no file, else the path."""
    return int(text) if text.isdigit() and not Path(text).exists() else text


def _check_args(args) -> None:
    if not Path(args.model).is_file():
        raise CliError(f"--model {args.model}: no such file")
    if Path(args.model).suffix.lower() not in (".ply", ".obj", ".cao"):
        raise CliError(f"--model {args.model}: a mesh must be .ply, .obj or .cao")
    if not Path(args.camera).is_file():
        raise CliError(f"--camera {args.camera}: no such file")
    for option, value in (("--textured", args.textured), ("--init-pose", args.init_pose)):
        if value is not None and not Path(value).is_file():
            raise CliError(f"{option} {value}: no such file")
    for option, value in (("--json", args.json), ("--csv", args.csv),
                          ("--overlay", args.overlay)):  # fmt: skip
        if value is not None and Path(value).is_dir():
            raise CliError(f"cannot write {option} {value}: a directory")
    if args.overlay is not None and Path(args.overlay).suffix.lower() != ".mp4":
        raise CliError(f"--overlay must name a .mp4 file, got {args.overlay}")
    if args.frames is not None and args.frames < 1:
        raise CliError(f"--frames must be >= 1, got {args.frames}")
    if args.reinit_every < 1:
        raise CliError(f"--reinit-every must be >= 1, got {args.reinit_every}")
    if args.reinit_wait is not None and not 0 <= args.reinit_wait < math.inf:
        raise CliError(f"--reinit-wait must be a finite number >= 0, got {args.reinit_wait}")
    for option, value in (("--smooth-rotation", args.smooth_rotation),
                          ("--smooth-translation", args.smooth_translation)):  # fmt: skip
        if value is not None and not 0 < value < math.inf:
            raise CliError(f"{option} must be a finite number > 0, got {value}")
    if args.point is not None and not all(math.isfinite(x) for x in args.point):
        raise CliError(f"--point must be two finite numbers, got {args.point}")
    if args.point_frame < 0:
        raise CliError(f"--point-frame must be >= 0, got {args.point_frame}")
    if args.point_frame != 0 and args.point is None:
        raise CliError("--point-frame needs --point")
    if args.no_reinit and args.init_pose is None:
        raise CliError("--no-reinit needs --init-pose (the first frame is recognised otherwise)")
    check_recording_args(args)


class _Progress:
    """A plain-text progress bar on stderr: redrawn in place on a terminal, a line every
    tenth of the frames (or every 100 frames when their number is unknown) otherwise."""

    def __init__(self, total: int | None, stream=None) -> None:
        self.total, self.stream = total, stream or sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.began, self.last = time.perf_counter(), -1

    def update(self, done: int, lost: int) -> None:
        total = self.total
        step = max(total // 10, 1) if total else 100
        finished = total is not None and done >= total
        if not self.tty and not finished and done // step == self.last // step:
            return
        self.last = done
        rate = done / max(time.perf_counter() - self.began, 1e-9)
        if total:
            filled = int(30 * min(done / total, 1.0))
            bar = f"[{'#' * filled}{'.' * (30 - filled)}] {done}/{total}"
        else:
            bar = f"{done} frames"
        line = f"tracking {bar}, {rate:.1f} frames/s, {lost} lost"
        self.stream.write(("\r" + line) if self.tty else (line + "\n"))
        self.stream.flush()

    def close(self) -> None:
        if self.tty:
            self.stream.write("\n")
            self.stream.flush()


def _row(r) -> dict[str, Any]:
    """One frame of `--json`: OpenCV's pose (null when lost) and the tracker's figures."""
    import cv2

    rvec = tvec = None
    if r.ok:
        rvec = [float(x) for x in cv2.Rodrigues(r.R)[0].ravel()]
        tvec = [float(x) for x in r.t]
    return {"index": int(r.frame), "ok": bool(r.ok), "status": r.status, "rvec": rvec,
            "tvec": tvec, "error_px": float(r.rms), "inliers": int(r.edges + r.points),
            "ms": round(float(r.ms), 3)}  # fmt: skip


def _with_target(row: dict[str, Any], target) -> dict[str, Any]:
    """`row` with `--point`'s fields: the target's camera-frame position, its pixel,
    whether it is in sight and the standard deviations of its position along the
    camera's axes from the frame's pose covariance (null where the frame has none)."""
    import numpy as np

    row.update(target=None, target_px=None, target_visible=None, target_std=None)
    if target is not None:
        row.update(target=[float(x) for x in target.point],
                   target_px=[float(x) for x in target.pixel],
                   target_visible=bool(target.visible))  # fmt: skip
        if target.covariance is not None:
            std = np.sqrt(np.maximum(np.diagonal(target.covariance), 0))
            row["target_std"] = [float(x) for x in std]
    return row


def _anchored_line(anchor, args) -> str:
    u, v = args.point
    if anchor is None:
        return f"--point ({u:g}, {v:g}): no frame from {args.point_frame} on had a pose"
    if anchor is False:
        return (
            f"--point ({u:g}, {v:g}): on frame {args.point_frame} or the first after it with a "
            "pose, the pixel's ray meets no face of the model: nothing followed"
        )
    m = ", ".join(f"{x:.4g}" for x in anchor.point)
    return (
        f"--point ({u:g}, {v:g}) on frame {anchor.frame}: face {anchor.face} of the model, at "
        f"({m}) in the model's frame; followed on every later frame with a pose"
    )


def _write_json(path: str, rows: list[dict[str, Any]], console) -> None:
    """`{"frames": [...]}`, one frame a line."""
    out = Path(path)
    text = '{"frames": [\n' + ",\n".join(json.dumps(row) for row in rows) + "\n]}\n"
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(text)
    except OSError as exc:
        raise CliError(f"cannot write --json {out}: {exc.strerror or exc}") from None
    console.print(f"wrote {out}")


def _write_csv(path: str, rows: list[dict[str, Any]], console) -> None:
    import csv

    out = Path(path)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        with out.open("w", newline="") as f:
            writer = csv.writer(f)
            targets = bool(rows) and "target" in rows[0]
            writer.writerow(CSV_COLUMNS + (TARGET_COLUMNS if targets else ()))
            for row in rows:
                pose = (row["rvec"] or [""] * 3) + (row["tvec"] or [""] * 3)
                extra = []
                if targets:
                    seen = row["target_visible"]
                    extra = [*(row["target"] or [""] * 3), *(row["target_px"] or [""] * 2),
                             "" if seen is None else int(seen),
                             *(row["target_std"] or [""] * 3)]  # fmt: skip
                writer.writerow([row["index"], int(row["ok"]), row["status"], *pose,
                                 row["error_px"], row["inliers"], row["ms"], *extra])  # fmt: skip
    except OSError as exc:
        raise CliError(f"cannot write --csv {out}: {exc.strerror or exc}") from None
    console.print(f"wrote {out}")


def _reinit(args, mesh, K, dist):
    """The re-initialisation: recognition (its compiled programs loaded on first use)."""
    from ..apps._reinit import recognition_reinit
    from ..features._keypoints import read_textured_model

    textured = None
    if args.textured is not None:
        try:
            textured = read_textured_model(args.textured)
        except ValueError as exc:
            raise CliError(f"--textured {args.textured}: {exc}") from None
    return recognition_reinit(mesh, K, dist, textured=textured)


def jitter(poses, centre) -> dict[str, float]:
    """The frame-to-frame jitter of a trajectory: between consecutive frames with a pose
    (`None` where lost), the median rotation (degrees) and movement of the model point
    `centre` (model units); over three consecutive frames with a pose, the median of
    the second differences of the rotation vectors (degrees) and of `centre`'s path.
    NaN where there are too few frames (printed as such, never written)."""
    import cv2
    import numpy as np

    rot, move, rot2, move2 = [], [], [], []
    steps: list = [None]  # the motion into each frame from the previous one
    for a, b in zip(poses, poses[1:]):
        if a is None or b is None:
            steps.append(None)
            continue
        w = cv2.Rodrigues(b[0] @ a[0].T)[0].ravel()
        p = (b[0] @ centre + b[1]) - (a[0] @ centre + a[1])
        rot.append(np.degrees(np.linalg.norm(w)))
        move.append(float(np.linalg.norm(p)))
        steps.append((w, p))
    for s, u in zip(steps, steps[1:]):
        if s is not None and u is not None:
            rot2.append(np.degrees(np.linalg.norm(u[0] - s[0])))
            move2.append(float(np.linalg.norm(u[1] - s[1])))

    def median(v):
        return float(np.median(v)) if v else math.nan

    return {"rotation_deg": median(rot), "translation": median(move),
            "rotation_2nd_deg": median(rot2), "translation_2nd": median(move2)}  # fmt: skip


def _smooth(results, centre, rotation_sigma: float | None, translation_sigma: float | None):
    """`refine_track` on the pass's results with the prior's sigmas (None: from the
    track): the refined frames, a line saying the sigmas and the jitter before and after,
    and the seconds it took."""
    from ..apps._track_refine import refine_track

    began = time.perf_counter()
    try:
        refined = refine_track(
            results, rotation_sigma=rotation_sigma, translation_sigma=translation_sigma
        )
    except ValueError as exc:  # (not expected: the tracker's own frames)
        raise CliError(f"--smooth: {exc}") from None
    seconds = time.perf_counter() - began

    def poses(frames):
        return [(f.R, f.t) if f.ok else None for f in frames]

    a, b = jitter(poses(results), centre), jitter(poses(refined.frames), centre)
    line = (
        f"smoothed (refine_track, {refined.iterations} steps, {seconds:.1f} s; prior "
        f"{refined.rotation_sigma:.3g} deg, {refined.translation_sigma:.3g} of the distance "
        f"per frame^2): jitter "
        f"{a['rotation_deg']:.3f} -> {b['rotation_deg']:.3f} deg, {a['translation']:.3f} -> "
        f"{b['translation']:.3f} (model units) frame to frame; second difference "
        f"{a['rotation_2nd_deg']:.3f} -> {b['rotation_2nd_deg']:.3f} deg, "
        f"{a['translation_2nd']:.3f} -> {b['translation_2nd']:.3f} (medians)"
    )
    return refined.frames, line, seconds


def cmd_track(args) -> int:
    """Run `jaxpose track` with the parsed `args`; returns the exit code (0: a pose on
    every frame, 1: some frame lost, 2: bad input)."""
    import cv2
    import numpy as np

    from ..apps._mesh_formats import read_mesh
    from ..apps._track import track
    from ..apps._track_options import TrackOptions
    from ..apps._visibility import mesh_geometry
    from ..features._video import open_frames

    _check_args(args)
    setup_jax(True)
    K, dist = camera_option(args.camera)
    dist = None if not np.any(dist) else dist
    try:
        mesh = read_mesh(args.model)
    except ValueError as exc:
        raise CliError(f"--model {args.model}: {exc}") from None
    if len(mesh.faces) == 0:
        raise CliError(f"--model {args.model}: the mesh has no faces")
    geo = mesh_geometry(mesh)
    initial = None
    if args.init_pose is not None:
        rvec, tvec = read_init_pose(args.init_pose)
        initial = (cv2.Rodrigues(rvec.reshape(3, 1))[0], tvec)
    try:
        frames = open_frames(_source(args.input), stop=args.frames)
    except ValueError as exc:
        raise CliError(f"INPUT {args.input}: {str(exc).removeprefix('source: ')}") from None
    try:
        total: int | None = len(frames)
    except TypeError:
        total = None
    reinit = None if args.no_reinit else _reinit(args, mesh, K, dist)
    # On a live camera a try at recognition (about a second) holds the stream: one try
    # a second at most unless told otherwise.
    wait = args.reinit_wait
    if wait is None:
        wait = 1.0 if isinstance(_source(args.input), int) else 0.0
    options = TrackOptions(reinit_every=args.reinit_every, reinit_wait=wait)

    current: dict[str, np.ndarray] = {}

    def feed():
        for frame in frames:
            current["frame"] = frame
            yield frame

    rec = writer = None
    if wants_recording(args):
        from ..viz._tracking import track_blueprint

        rec = open_recording(args, f"jaxpose track {args.input}", track_blueprint())
    results = []  # the frames' results, kept for --smooth
    stream = track(feed(), geo, K, dist, initial, options=options, reinit=reinit)
    follow = None
    if args.point is not None:
        from ..apps._track_target import follow_click

        follow = follow_click(stream, mesh, K, dist, (args.point_frame, *args.point))
    anchored = None  # --point's anchor (False: its ray met no face)
    rows: list[dict[str, Any]] = []
    trajectory: list[np.ndarray] = []
    progress = _Progress(total)
    lost = 0
    interrupted = False
    try:
        for r, anchor, target in _targets(stream, follow):
            frame = current["frame"]
            if follow is not None and anchored is None and r.ok and r.frame >= args.point_frame:
                anchored = False if anchor is None else anchor  # (the first posed frame's)
            rows.append(_row(r) if follow is None else _with_target(_row(r), target))
            if args.smooth:
                results.append(r)
            lost += not r.ok
            if args.overlay is not None:
                from ..viz._tracking import draw_tracked

                picture = draw_tracked(frame, geo, K, dist, r)
                if follow is not None and target is not None:
                    from ..viz._tracking import draw_target

                    draw_target(picture, target)
                if writer is None:
                    writer = _video_writer(args.overlay, frames, picture.shape[1::-1])
                writer.write(picture)
            if rec is not None:
                from ..viz._tracking import log_track_camera, log_tracked_frame

                if r.frame == 0:
                    log_track_camera(rec, K, frame.shape[1::-1])
                log_tracked_frame(rec, frame, r, geo, K, dist, trajectory,
                                  clicked=follow is not None, target=target)  # fmt: skip
            progress.update(len(rows), lost)
    except ValueError as exc:
        raise CliError(f"INPUT {args.input}: {str(exc).removeprefix('source: ')}") from None
    except KeyboardInterrupt:  # Ctrl-C (a live camera): the frames so far are written
        interrupted = True
    finally:
        progress.close()
        if writer is not None:
            writer.release()
        frames.close()
    console = new_console()
    if interrupted:
        console.print(f"interrupted after {len(rows)} frames")
    if not rows:
        raise CliError(f"INPUT {args.input}: no frame could be read")
    counts = {s: sum(row["status"] == s for row in rows)
              for s in ("initialised", "tracked", "reinitialised", "lost")}  # fmt: skip
    summary = f"{len(rows)} frames: " + ", ".join(f"{n} {s}" for s, n in counts.items() if n)
    tracked = [row["ms"] for row in rows if row["status"] == "tracked"]
    if tracked:
        summary += (f"; tracker {np.median(tracked):.1f} ms per tracked frame (median), "
                    f"{1e3 / max(float(np.mean(tracked)), 1e-9):.0f} frames/s (decoding "
                    "excluded)")  # fmt: skip
    console.print(summary)
    if follow is not None:
        console.print(_anchored_line(anchored, args))
    if args.smooth:
        centre = np.asarray(mesh.vertices, np.float64).mean(axis=0)
        refined, line, _ = _smooth(results, centre, args.smooth_rotation, args.smooth_translation)
        rows = [_row(r) for r in refined]
        if follow is not None:  # the anchored point at the refined poses
            from ..apps._track_target import follow_anchor

            for row, r in zip(rows, refined, strict=True):
                target = None
                if anchored and r.ok and r.frame >= anchored.frame:
                    target = follow_anchor(anchored, mesh, K, dist, r.R, r.t, frame=r.frame)
                _with_target(row, target)
        console.print(line)
    if args.json:
        _write_json(args.json, rows, console)
    if args.csv:
        _write_csv(args.csv, rows, console)
    if args.overlay is not None:
        console.print(f"wrote {args.overlay}")
    if rec is not None:
        finish_recording(args, console, rec)
    return 0 if lost == 0 else 1


def _targets(stream, follow):
    """`(result, anchor, target)` for each frame of the tracker's `stream` (`follow`:
    `follow_click` over it; None without `--point`: no anchor, no target)."""
    if follow is None:
        return ((r, None, None) for r in stream)
    return follow


def _video_writer(path: str, frames, size: tuple[int, int]):
    import cv2

    fps = frames.fps if math.isfinite(frames.fps) and frames.fps > 0 else 30.0
    out = Path(path)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CliError(f"cannot write --overlay {out}: {exc.strerror or exc}") from None
    writer = cv2.VideoWriter(str(out), cv2.VideoWriter.fourcc(*"mp4v"), fps,
                             (int(size[0]), int(size[1])))  # fmt: skip
    if not writer.isOpened():
        raise CliError(f"cannot write --overlay {out}: OpenCV could not open a video writer")
    return writer
