"""Recording pose problems and their solutions for the rerun viewer (`rerun-sdk`).

Every function takes the `rerun.RecordingStream` to write to (never the global one), so
recordings of several problems can be made side by side. `rerun` itself is imported
only when a recording is made: `import jaxpose` stays light.

Entity paths (world units are the model's, e.g. mm; pixels in the image space):

| path | what |
|---|---|
| `world` | the world frame (z up; the camera frame's axes when the world is the camera) |
| `world/camera` | the camera's pose in the world (`Transform3D`, camera to world) |
| `world/camera/image` | its pinhole (intrinsics, image size) and the image, if any |
| `world/camera/image/observed` | the observed image points (2D) |
| `world/camera/image/recovered`, `.../true` | reprojected points and wireframe (2D) |
| `world/model/recovered`, `world/model/true` | the model's wireframe at those poses (3D) |
| `world/points/...`, `world/rays` | matched vertices (3D) and the observed visual rays |
| `world/triplets/hypothesis`, `world/camera/image/triplets/...` | the current triplet's pose |
| `triplets/status` | one log line per triplet: its status and error |
| `metrics/error_px/<method>` | Eq. 8 error per triplet and method (px) |
| `metrics/pose_error_mm/<method>` | the paper's pose error per triplet and method |
| `summary` | the answer, as a Markdown text document |
| `world/pointing/...`, `world/robot/...` | a pointing command (`log_pointing`) |

Per-triplet data lie on the `triplet` sequence timeline (the triplet's index into
`jaxpose.triplet_indices`). `rerun_blueprint` lays them out: 3D view and image view
on top, the error series and the log below.
"""

from __future__ import annotations

import functools
import urllib.parse
import uuid
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..solvers._status import Status

if TYPE_CHECKING:  # pragma: no cover
    import rerun as rr
    import rerun.blueprint as rrb

    from ..api._solve import Solution
    from ..apps._bench import Bench, Polyhedron
    from ..apps._experiment import ExperimentResult
    from ..apps._pointing import Hit
    from ..apps._robot import Robot
    from ..geometry._pose import Pose
    from ..strategy._mixed import Initial, MixedResult

__all__ = [
    "STATUS_COLORS",
    "close_recording",
    "log_camera",
    "log_experiment",
    "log_observations",
    "log_pointing",
    "log_pose",
    "log_solution",
    "log_triplets",
    "pointing_blueprint",
    "rerun_blueprint",
    "rerun_recording",
    "serve_web_viewer",
]

APPLICATION_ID = "jaxpose"
METHOD_LABELS = {
    "three_point": "3-segment",
    "linear": "linear",
    "nonlinear": "non-linear",
    "mixed": "mixed",
}
METHOD_COLORS = {
    "three_point": (150, 150, 150),
    "linear": (66, 135, 245),
    "nonlinear": (230, 159, 0),
    "mixed": (0, 170, 90),
}
_GREEN, _ORANGE, _RED, _PURPLE, _GREY = (
    (40, 200, 90),
    (245, 160, 30),
    (230, 50, 50),
    (170, 90, 220),
    (130, 130, 130),
)
#: Colour of a hypothesis by its `Status`: accepted green, rejected orange, not converged
#: red, outside the non-linear budget purple, no pose (degenerate triplet) grey.
STATUS_COLORS = {
    Status.OK: _GREEN,
    Status.ACCEPTED_LINEAR: _GREEN,
    Status.ACCEPTED_AFTER_NONLINEAR: _GREEN,
    Status.REJECTED: _ORANGE,
    Status.NONLINEAR_NOT_CONVERGED: _RED,
    Status.LINEAR_NOT_CONVERGED: _RED,
    Status.NOT_ATTEMPTED: _PURPLE,
}
_NO_POSE = (
    Status.NO_SOLUTION,
    Status.BEHIND_CAMERA,
    Status.DEGENERATE_IMAGE,
    Status.DEGENERATE_MODEL,
    Status.TOO_FEW_POINTS,
    Status.NOT_FINITE,
)
_OBSERVED = (230, 50, 50)
_RECOVERED = (40, 200, 90)
_TRUE = (80, 140, 255)


def _rr():
    import rerun as rr

    return rr


# --------------------------------------------------------------------------- geometry (numpy)


def _np(x) -> np.ndarray:
    return np.asarray(x, dtype=np.float64)


@functools.cache
def _jitted(fn):
    import jax

    return jax.jit(fn)


def _f64(fn, *args):
    """`fn(*args)` for a jaxpose function, compiled once, in float64, as numpy."""
    import jax

    with jax.enable_x64(True):
        out = _jitted(fn)(*(np.asarray(a, np.float64) for a in args))
        return jax.tree.map(np.asarray, out)


def _transform(R, t, points) -> np.ndarray:
    return _np(points) @ _np(R).T + _np(t).reshape(1, 3)


def _project(camera, world) -> tuple[np.ndarray, np.ndarray]:
    """Pixels and a front-of-camera flag of world points (numpy, for drawing only)."""
    C = _np(camera)
    h = world @ C[:, :3].T + C[:, 3]
    sign = np.sign(np.linalg.det(C[:, :3])) or 1.0
    depth = sign * h[:, 2]
    front = depth > 1e-9 * np.maximum(np.abs(h[:, :2]).max(axis=1), 1.0)
    w = np.where(front, h[:, 2], 1.0)
    return h[:, :2] / w[:, None], front


def _camera_parts(camera, K=None, R_wc=None, t_wc=None):
    """`(K, R_wc, t_wc, centre)` of a camera: given, or decomposed from `C` (float64)."""
    if K is not None and R_wc is not None and t_wc is not None:
        K, R_wc, t_wc = _np(K), _np(R_wc), _np(t_wc).reshape(3)
        return K, R_wc, t_wc, -R_wc.T @ t_wc
    from ..geometry._camera import decompose_camera

    return _f64(decompose_camera, camera)


def _edges(polyhedron: Polyhedron | None, model_points) -> np.ndarray:
    """Edge list `(E, 2)` over the rows of `model_points`, or `(0, 2)`."""
    if polyhedron is None:
        return np.zeros((0, 2), dtype=np.int64)
    return np.asarray(polyhedron.edges, dtype=np.int64).reshape(-1, 2)


def _strips3d(world, edges) -> np.ndarray:
    """Segments `(E, 2, 3)` (one array: rerun's fast path)."""
    return world[edges]


def _strips2d(camera, world, edges) -> np.ndarray:
    """Projected segments `(E', 2, 2)`, those with both ends in front of the camera."""
    uv, front = _project(camera, world)
    return uv[edges[front[edges].all(axis=1)]]


def _hypothesis_ok(status: int) -> bool:
    return int(status) not in [int(s) for s in _NO_POSE]


def _status_color(status: int) -> tuple[int, int, int]:
    return STATUS_COLORS.get(Status(int(status)), _GREY)


# --------------------------------------------------------------------------- recording


def rerun_blueprint(
    *,
    pose_error: bool = True,
    eye: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> rrb.Blueprint:
    """The layout a recording opens on: the 3D scene and the camera image side by side,
    the per-triplet error series (px, and the pose error when `pose_error`) and the
    triplet log below, the time panel on the `triplet` timeline.

    `eye`: optionally the 3D view's initial `(position, look_target, up)` in the world
    (`log_solution` and `log_experiment` set one that frames the object)."""
    import rerun.blueprint as rrb

    series = [rrb.TimeSeriesView(origin="metrics/error_px", name="Eq. 8 error per triplet (px)")]
    if pose_error:
        series.append(
            rrb.TimeSeriesView(origin="metrics/pose_error_mm", name="pose error per triplet")
        )
    return rrb.Blueprint(
        rrb.Vertical(
            _scene_and_image(eye),
            rrb.Horizontal(
                *series,
                rrb.Tabs(
                    rrb.TextLogView(origin="triplets", name="triplets"),
                    rrb.TextDocumentView(origin="summary", name="summary"),
                ),
            ),
            row_shares=[3, 2],
        ),
        rrb.TimePanel(timeline="triplet"),
        collapse_panels=True,
    )


def _world_is_camera(R_wc, t_wc) -> bool:
    return bool(np.allclose(R_wc, np.eye(3)) and np.allclose(t_wc, 0))


def _world_up(R_wc, t_wc) -> np.ndarray:
    """The world's up direction as drawn: z, or -y (OpenCV's camera axes) when the world
    is the camera frame."""
    return np.array([0.0, -1.0, 0.0]) if _world_is_camera(R_wc, t_wc) else np.array([0.0, 0, 1])


def _frame_object(
    rec, centre, world_points, up, *, pose_error: bool = False, make_blueprint=None
) -> None:
    """Send the default layout (`make_blueprint(eye=...)`, default `rerun_blueprint`)
    with the 3D eye looking at the object from the side of the line of sight, above it,
    so that the object, the rays and the camera all show."""
    target = np.mean(world_points, axis=0)
    towards_camera = centre - target
    distance = float(np.linalg.norm(towards_camera))
    if not np.isfinite(distance) or distance == 0:
        return
    back = towards_camera / distance
    side = np.cross(up, back)
    side = side / np.linalg.norm(side) if np.linalg.norm(side) > 1e-9 else np.zeros(3)
    direction = 0.75 * back + 0.5 * side + 0.45 * up
    # About 2.5 object sizes away (the object fills a good part of the view), at most
    # 0.8 of the camera's distance.
    size = float(np.max(np.linalg.norm(world_points - target, axis=1)))
    reach = min(2.5 * 2 * size, 0.8 * distance) if size > 0 else 0.5 * distance
    position = target + reach * direction / np.linalg.norm(direction)
    eye = (position, target, up)
    if make_blueprint is None:
        blueprint = rerun_blueprint(pose_error=pose_error, eye=eye)
    else:
        blueprint = make_blueprint(eye=eye)
    rec.send_blueprint(blueprint, make_active=True, make_default=True)


def rerun_recording(
    path: str | Path | None = None,
    *,
    name: str | None = None,
    blueprint: rrb.Blueprint | None = None,
    spawn: bool = False,
    serve: bool = False,
    port: int = 9876,
) -> rr.RecordingStream:
    """A new, independent recording stream (not the global one) for `jaxpose`.

    Everything logged to it afterwards goes to the sinks chosen here; with none, it is
    buffered in memory (e.g. for `RecordingStream.notebook_show`). Finish it with
    `close_recording` so that files get their footer.

    **Arguments:**
    - `path`: stream to this `.rrd` file.
    - `name`: the recording's name shown in the viewer.
    - `blueprint`: the default layout (`rerun_blueprint()` when None).
    - `spawn`: start the native rerun viewer (it needs a display) and stream to it.
    - `serve`: host a gRPC server on `port` that viewers can connect to (see
      `serve_web_viewer`); it lives as long as the recording and the process.

    **Returns:** a `rerun.RecordingStream`.
    """
    rr = _rr()
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=uuid.uuid4())
    rec.set_log_time_enabled(False)  # the `triplet` timeline is the one that means something
    blueprint = rerun_blueprint() if blueprint is None else blueprint
    sinks = []
    if path is not None:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        sinks.append(rr.FileSink(path))
    if spawn:
        rec.spawn(port=port, connect=False)
        sinks.append(rr.GrpcSink(f"rerun+http://127.0.0.1:{port}/proxy"))
    if serve:
        sinks.append(rr.GrpcServerSink(port=port))
    if sinks:
        rec.set_sinks(*sinks, default_blueprint=blueprint)
    else:
        rec.send_blueprint(blueprint, make_active=True, make_default=True)
    if name:
        rec.send_recording_name(name)
    return rec


def close_recording(rec: rr.RecordingStream) -> None:
    """Flush `rec` and close its sinks (finishing `.rrd` files and stopping servers)."""
    rec.flush()
    rec.disconnect()


def serve_web_viewer(port: int = 9876, *, web_port: int = 9090) -> str:
    """Host the rerun web viewer on `web_port`, connected to the gRPC server of a
    recording made with `rerun_recording(serve=True, port=port)`. Returns its address."""
    rr = _rr()
    uri = f"rerun+http://127.0.0.1:{port}/proxy"
    rr.serve_web_viewer(web_port=web_port, open_browser=False, connect_to=uri)
    return f"http://127.0.0.1:{web_port}/?url={urllib.parse.quote(uri, safe='')}"


# --------------------------------------------------------------------------- scene


def log_camera(
    rec: rr.RecordingStream,
    camera,
    *,
    K=None,
    R_wc=None,
    t_wc=None,
    image_size: tuple[int, int] | None = None,
    image=None,
    frustum: float | None = None,
) -> None:
    """Log the camera: its pose in the world (`world/camera`), its pinhole with the image
    size (`world/camera/image`) and the image, when there is one.

    **Arguments:**
    - `camera`: `C` `(3, 4)`; decomposed into `K [R_wc | t_wc]` unless those are given.
    - `image_size`: `(width, height)` px; default: twice the principal point.
    - `image`: an image file path (logged compressed, as is) or an array `(H, W)` /
      `(H, W, 3)` RGB.
    - `frustum`: distance of the drawn image plane from the centre (world units).
    """
    rr = _rr()
    K, R_wc, t_wc, centre = _camera_parts(camera, K, R_wc, t_wc)
    if image_size is None:
        image_size = (int(round(2 * K[0, 2])), int(round(2 * K[1, 2])))
    coords = (
        rr.ViewCoordinates.RDF
        if _world_is_camera(R_wc, t_wc)
        else rr.ViewCoordinates.RIGHT_HAND_Z_UP
    )
    rec.log("world", coords, static=True)
    rec.log(
        "world/camera",
        rr.Transform3D(translation=centre, mat3x3=R_wc.T),
        static=True,
    )
    rec.log(
        "world/camera/image",
        rr.Pinhole(
            image_from_camera=K / K[2, 2],
            resolution=[int(image_size[0]), int(image_size[1])],
            image_plane_distance=frustum,
        ),
        static=True,
    )
    if image is None:
        return
    if isinstance(image, (str, Path)):
        rec.log("world/camera/image", rr.EncodedImage(path=Path(image)), static=True)
    else:
        rec.log("world/camera/image", rr.Image(np.asarray(image)), static=True)


def log_pose(
    rec: rr.RecordingStream,
    name: str,
    camera,
    model_points,
    pose: Pose | tuple,
    *,
    polyhedron: Polyhedron | None = None,
    color: tuple[int, int, int] = _RECOVERED,
    label: str | None = None,
) -> None:
    """Log one pose of the model (static): its wireframe in 3D (`world/model/<name>`) and
    projected into the image (`world/camera/image/<name>/wireframe`), and the matched
    vertices in 3D (`world/points/<name>`) and reprojected (`world/camera/image/<name>`).

    **Arguments:**
    - `name`: `"recovered"`, `"true"`, ...
    - `model_points`: `(n, 3)` matched model points.
    - `pose`: `(R, t)` mapping model to world.
    - `polyhedron`: the model with its edges (its vertices, not `model_points`, are drawn
      as the wireframe); without it only the points are drawn.
    """
    rr = _rr()
    R, t = _np(pose[0]), _np(pose[1])
    world = _transform(R, t, model_points)
    rec.log(
        f"world/points/{name}",
        rr.Points3D(world, colors=color, radii=rr.Radius.ui_points(4.0)),
        static=True,
    )
    uv, front = _project(camera, world)
    rec.log(
        f"world/camera/image/{name}",
        rr.Points2D(uv[front], colors=color, radii=rr.Radius.ui_points(4.0)),
        static=True,
    )
    if polyhedron is None:
        return
    vertices = _transform(R, t, polyhedron.vertices)
    edges = _edges(polyhedron, vertices)
    rec.log(
        f"world/model/{name}",
        rr.LineStrips3D(
            _strips3d(vertices, edges),
            colors=color,
            radii=rr.Radius.ui_points(1.5),
            labels=label,
            show_labels=label is not None,
        ),
        static=True,
    )
    rec.log(
        f"world/camera/image/{name}/wireframe",
        rr.LineStrips2D(_strips2d(camera, vertices, edges), colors=color),
        static=True,
    )


def log_observations(
    rec: rr.RecordingStream,
    camera,
    image_points,
    *,
    observed_points=None,
    mask=None,
    depth_points=None,
) -> None:
    """Log the observed image points (`world/camera/image/observed`) and, when
    `depth_points` (`(n, 3)` world points, e.g. the recovered vertices) are given, their
    visual rays in 3D (`world/rays`) up to just past those points.

    `observed_points` (with lens distortion, as measured) are drawn instead of the
    undistorted `image_points` when given; masked-out matches are drawn grey."""
    rr = _rr()
    pts = _np(image_points if observed_points is None else observed_points)
    mask = np.ones(len(pts), bool) if mask is None else np.asarray(mask, bool)
    colors = np.where(mask[:, None], np.array(_OBSERVED), np.array(_GREY)).astype(np.uint8)
    rec.log(
        "world/camera/image/observed",
        rr.Points2D(
            pts,
            colors=colors,
            radii=rr.Radius.ui_points(5.0),
            labels=[str(i) for i in range(len(pts))],
            show_labels=False,
        ),
        static=True,
    )
    if depth_points is None:
        return
    from ..geometry._camera import backproject

    centre, directions = _f64(backproject, camera, image_points)
    reach = 1.05 * np.linalg.norm(_np(depth_points) - centre, axis=1)
    ends = centre + directions * reach[:, None]
    colors = np.column_stack([colors, np.full(len(colors), 110, np.uint8)])  # translucent
    rec.log(
        "world/rays",
        rr.LineStrips3D(
            np.stack([np.broadcast_to(centre, ends.shape), ends], axis=1),
            colors=colors,
            radii=rr.Radius.ui_points(0.5),
        ),
        static=True,
    )


# --------------------------------------------------------------------------- triplets


def _series(rec, kind: str, values: Mapping[str, np.ndarray], used: np.ndarray) -> None:
    """Scalars per triplet and method on the `triplet` timeline (`metrics/<kind>/<m>`)."""
    rr = _rr()
    index = np.flatnonzero(used)
    for method, v in values.items():
        v = _np(v)[index]
        keep = np.isfinite(v) & (v < np.finfo(np.float64).max / 2)
        path = f"metrics/{kind}/{method}"
        rec.log(
            path,
            rr.SeriesPoints(
                colors=METHOD_COLORS.get(method, _GREY),
                names=METHOD_LABELS.get(method, method),
                markers="circle",
                marker_sizes=2.0,
            ),
            static=True,
        )
        rec.send_columns(
            path,
            indexes=[rr.TimeColumn("triplet", sequence=index[keep])],
            columns=rr.Scalars.columns(scalars=v[keep]),
        )


def log_triplets(
    rec: rr.RecordingStream,
    camera,
    model_points,
    image_points,
    result: MixedResult | Initial,
    *,
    polyhedron: Polyhedron | None = None,
    errors: Mapping[str, np.ndarray] | None = None,
    pose_errors: Mapping[str, np.ndarray] | None = None,
    statuses: Mapping[str, np.ndarray] | None = None,
) -> None:
    """Log every triplet's hypothesis on the `triplet` timeline.

    At time `k`: the pose of triplet `k` as a wireframe coloured by its status
    (`STATUS_COLORS`) with a label, in 3D (`world/triplets/hypothesis`) and in the image
    (`world/camera/image/triplets/hypothesis`); for a `MixedResult` also its three-point
    start (`.../three_point`, thin grey); its three image points
    (`world/camera/image/triplets/points`) and a log line (`triplets/status`). Scalars
    per method: `errors` (px) under `metrics/error_px`, `pose_errors` under
    `metrics/pose_error_mm`.

    **Arguments:**
    - `camera`, `model_points` `(n, 3)`, `image_points` `(n, 2)`: the problem.
    - `result`: `jaxpose.mixed`'s `MixedResult`, or `jaxpose.initial_poses`'s `Initial`
      (the three-point method alone), for this problem (numpy or JAX arrays).
    - `polyhedron`: the model, for wireframes (else the matched points are drawn).
    - `errors`, `pose_errors`: `(T,)` arrays per method name; default: the Eq. 8 errors
      of the result (for a `MixedResult`: of its three-point, first linear and final
      steps).
    - `statuses`: `(T,)` status arrays per method, written into the log lines.
    """
    rr = _rr()
    staged = hasattr(result, "initial")
    initial = result.initial if staged else result
    tri = np.asarray(initial.triplets)
    T = len(tri)
    status = np.asarray(result.status)
    error = _np(result.error)
    used = np.array([_hypothesis_ok(s) for s in np.asarray(initial.status)], dtype=bool)
    if errors is None:
        errors = {"three_point": _np(initial.error)}
        if staged:
            errors |= {"linear": _np(result.linear_error), "mixed": error}
    _series(rec, "error_px", errors, used)
    if pose_errors is not None:
        _series(rec, "pose_error_mm", pose_errors, used)

    def at(index) -> list:
        return [rr.TimeColumn("triplet", sequence=np.asarray(index, dtype=np.int64))]

    # The triplet's own three image points, and one log line per triplet.
    rec.log(
        "world/camera/image/triplets/points",
        rr.Points2D.from_fields(colors=(255, 220, 0), radii=rr.Radius.ui_points(7.0)),
        static=True,
    )
    rec.send_columns(
        "world/camera/image/triplets/points",
        indexes=at(np.arange(T)),
        columns=rr.Points2D.columns(positions=_np(image_points)[tri].reshape(-1, 2)).partition(
            np.full(T, 3)
        ),
    )
    codes = [Status(int(c)) for c in status]
    texts, levels = [], []
    for k in range(T):
        parts = [f"triplet {k} {tuple(int(i) for i in tri[k])}: {codes[k].name}"]
        parts[0] += f" ({codes[k].message})"
        if used[k]:
            parts.append(f"e = {error[k]:.4g} px")
        if statuses is not None:
            parts.append(
                "; ".join(
                    f"{METHOD_LABELS.get(m, m)} {Status(int(np.asarray(v)[k])).name}"
                    for m, v in statuses.items()
                )
            )
        texts.append(" | ".join(parts))
        if codes[k].succeeded:
            levels.append("INFO")
        elif used[k] and codes[k] != Status.NOT_ATTEMPTED:
            levels.append("WARN")
        else:
            levels.append("DEBUG")
    rec.send_columns(
        "triplets/status",
        indexes=at(np.arange(T)),
        columns=rr.TextLog.columns(text=texts, level=levels),
    )

    # The hypotheses: one wireframe (or point set) per usable triplet, cleared elsewhere.
    shape = _np(polyhedron.vertices) if polyhedron is not None else _np(model_points)
    edges = _edges(polyhedron, model_points)
    index = np.flatnonzero(used)
    R, t = _np(result.pose.R)[index], _np(result.pose.t)[index]
    colors = np.array([_status_color(codes[k]) for k in index], dtype=np.uint8).reshape(-1, 3)
    labels = [f"{k} {codes[k].name} {error[k]:.3g} px" for k in index]
    ghosts = {"hypothesis": (R, t, colors, labels, 1.5)}
    if staged:
        R0, t0 = _np(initial.pose.R)[index], _np(initial.pose.t)[index]
        grey = np.tile(np.array(_GREY, np.uint8), (len(index), 1))
        ghosts["three_point"] = (R0, t0, grey, None, 0.75)
    for entity, (Rs, ts, cols, labs, radius) in ghosts.items():
        path3, path2 = f"world/triplets/{entity}", f"world/camera/image/triplets/{entity}"
        world = np.einsum("kij,vj->kvi", Rs, shape) + ts[:, None, :]  # (U, V, 3)
        uv, front = _project(camera, world.reshape(-1, 3))
        uv, front = uv.reshape(*world.shape[:2], 2), front.reshape(world.shape[:2])
        if len(edges):
            keep = front[:, edges].all(axis=2)  # (U, E): segments in front of the camera
            archetype3, archetype2 = rr.LineStrips3D, rr.LineStrips2D
            data3 = {"strips": world[:, edges].reshape(-1, 2, 3)}
            lengths3 = np.full(len(index), len(edges))
            data2 = {"strips": uv[:, edges][keep]}
            lengths2 = keep.sum(axis=1)
            style = {"radii": rr.Radius.ui_points(radius), "show_labels": labs is not None}
            style2: dict = {}
        else:
            archetype3, archetype2 = rr.Points3D, rr.Points2D
            data3 = {"positions": world.reshape(-1, 3)}
            lengths3 = np.full(len(index), shape.shape[0])
            data2 = {"positions": uv[front]}
            lengths2 = front.sum(axis=1)
            style = {"radii": rr.Radius.ui_points(3.0 * radius), "show_labels": labs is not None}
            style2 = {"radii": rr.Radius.ui_points(3.0 * radius)}
        rec.log(path3, archetype3.from_fields(**style), static=True)
        if style2:
            rec.log(path2, archetype2.from_fields(**style2), static=True)
        per_row = {"colors": cols} | ({} if labs is None else {"labels": labs})
        if len(index):
            rec.send_columns(
                path3,
                indexes=at(index),
                columns=[
                    *archetype3.columns(**data3).partition(lengths3),
                    *archetype3.columns(**per_row),
                ],
            )
            rec.send_columns(
                path2,
                indexes=at(index),
                columns=[
                    *archetype2.columns(**data2).partition(lengths2),
                    *archetype2.columns(colors=cols),
                ],
            )
        cleared = np.flatnonzero(~used)
        if len(cleared):
            for path in (path3, path2):
                rec.send_columns(
                    path,
                    indexes=at(cleared),
                    columns=rr.Clear.columns(is_recursive=np.zeros(len(cleared), dtype=bool)),
                )


# --------------------------------------------------------------------------- whole runs


def _summary(lines: list[str]) -> Any:
    rr = _rr()
    return rr.TextDocument("\n".join(lines), media_type=rr.MediaType.MARKDOWN)


def _log_camera_near(rec, camera, parts, points, image_size, image) -> float:
    """`log_camera` with its frustum drawn at a fifth of the median distance from the
    camera centre (`parts[3]`) to `points` (world); returns that distance."""
    distance = float(np.median(np.linalg.norm(points - parts[3], axis=1)))
    log_camera(
        rec,
        camera,
        K=parts[0],
        R_wc=parts[1],
        t_wc=parts[2],
        image_size=image_size,
        image=image,
        frustum=0.2 * distance if np.isfinite(distance) and distance > 0 else None,
    )
    return distance


def log_solution(
    rec: rr.RecordingStream,
    camera,
    model_points,
    image_points,
    solution: Solution,
    *,
    triplets: MixedResult | Initial | None = None,
    polyhedron: Polyhedron | None = None,
    true_pose: Pose | tuple | None = None,
    image=None,
    image_size: tuple[int, int] | None = None,
    observed_points=None,
    mask=None,
    K=None,
    R_wc=None,
    t_wc=None,
    method: str = "mixed",
    layout: bool = True,
) -> None:
    """Log one solved problem: the camera and image, the observations and their rays, the
    recovered pose (and the true one when known) and, with `triplets`, every triplet's
    hypothesis (`log_triplets`); a Markdown summary at `summary`.

    **Arguments:**
    - `camera`, `model_points`, `image_points` (undistorted), `mask`: the problem as given
      to `jaxpose.solve`.
    - `solution`: its `Solution`.
    - `triplets`: optionally, the per-triplet results (`jaxpose.mixed`'s `MixedResult`, or
      `jaxpose.initial_poses`'s `Initial`), see `log_triplets`.
    - `polyhedron`: the model with edges, for wireframes.
    - `true_pose`: `(R, t)` ground truth.
    - `image`, `image_size`, `K`, `R_wc`, `t_wc`: see `log_camera`.
    - `observed_points`: the measured pixels (with distortion), drawn as observed.
    - `layout`: send the default layout (`rerun_blueprint`) with the 3D view framed on
      the object; False keeps the recording's own blueprint.
    """
    pose = (np.asarray(solution.pose.R), np.asarray(solution.pose.t))
    recovered = _transform(*pose, model_points)
    parts = _camera_parts(camera, K, R_wc, t_wc)
    _log_camera_near(rec, camera, parts, recovered, image_size, image)
    if layout:
        up = _world_up(parts[1], parts[2])
        _frame_object(rec, parts[3], recovered, up, pose_error=False)
    log_observations(
        rec,
        camera,
        image_points,
        observed_points=observed_points,
        mask=mask,
        depth_points=recovered,
    )
    code = Status(int(np.asarray(solution.status)))
    accepted = bool(np.asarray(solution.accepted))
    err = float(np.asarray(solution.error))
    if true_pose is not None:
        log_pose(rec, "true", camera, model_points, true_pose, polyhedron=polyhedron, color=_TRUE)
    log_pose(
        rec,
        "recovered",
        camera,
        model_points,
        pose,
        polyhedron=polyhedron,
        color=_RECOVERED if accepted else _RED,
        label=f"{method}: {err:.3g} px",
    )
    if triplets is not None:
        log_triplets(rec, camera, model_points, image_points, triplets, polyhedron=polyhedron)
    from ..geometry._rotation import matrix_to_rotvec

    rvec = _f64(matrix_to_rotvec, pose[0])
    lines = [
        f"# {method} solve: {'accepted' if accepted else 'no pose accepted'}",
        "",
        f"- status: `{code.name}` ({code.message})",
        f"- Eq. 8 error: {err:.6g} px over {len(recovered)} matches",
        f"- pose error (paper): {float(np.asarray(solution.pose_error)):.6g} model units",
        f"- rotation vector (model to world): {np.array2string(rvec, precision=6)}",
        f"- translation: {np.array2string(pose[1], precision=6)}",
        f"- from triplet {int(np.asarray(solution.triplet))}",
    ]
    rec.log("summary", _summary(lines), static=True)


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
    - `bench`: the `jaxpose.Bench` the experiment ran on.
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


# --------------------------------------------------------------------------- pointing


def _scene_and_image(eye):
    """The 3D scene (its eye from `_eye_controls`) beside the camera image."""
    import rerun.blueprint as rrb

    return rrb.Horizontal(
        rrb.Spatial3DView(origin="world", name="scene", eye_controls=_eye_controls(eye)),
        rrb.Spatial2DView(origin="world/camera/image", name="image"),
    )


def _eye_controls(eye):
    """rerun's 3D eye from `(position, look_target, up)`, or `None`."""
    import rerun.blueprint as rrb

    if eye is None:
        return None
    position, target, up = (np.asarray(v, dtype=np.float64) for v in eye)
    return rrb.EyeControls3D(position=position, look_target=target, eye_up=up)


def pointing_blueprint(
    *, eye: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
) -> rrb.Blueprint:
    """The layout of a pointing recording (`log_pointing`): the 3D scene (object, ray,
    point, robot) and the camera image side by side, the summary below."""
    import rerun.blueprint as rrb

    return rrb.Blueprint(
        rrb.Vertical(
            _scene_and_image(eye),
            rrb.TextDocumentView(origin="summary", name="summary"),
            row_shares=[4, 1],
        ),
        collapse_panels=True,
    )


def _robot_drawing(robot, joints) -> dict[str, np.ndarray]:
    """The robot at `joints`, world frame (numpy), from `forward_kinematics`: the carriage
    travel at wrist height, the links (bridge, pan axis, shank), wrist and tip, and the
    turret and tool frames."""
    import jax

    from ..apps._robot import forward_kinematics

    with jax.enable_x64(True):
        robot = type(robot)(*(np.asarray(a, np.float64) for a in robot))
        state = jax.tree.map(
            np.asarray, _jitted(forward_kinematics)(robot, np.asarray(joints, np.float64))
        )
    Rb, tb = _np(robot.base_R), _np(robot.base_t)
    lo, hi, h = _np(robot.lower), _np(robot.upper), float(robot.height)
    x = float(np.asarray(joints)[0])
    base = np.array(
        [
            [lo[0], lo[1], h],
            [hi[0], lo[1], h],
            [hi[0], hi[1], h],
            [lo[0], hi[1], h],
            [lo[0], lo[1], h],
        ]
    )
    bridge = np.array([[x, lo[1], h], [x, hi[1], h]])
    up = Rb[:, 2]
    return {
        "travel": _transform(Rb, tb, base),
        "bridge": _transform(Rb, tb, bridge),
        "pan_axis": np.stack([state.wrist + 0.2 * float(robot.shank) * up, state.wrist]),
        "shank": np.stack([state.wrist, state.tip]),
        "wrist": state.wrist,
        "tip": state.tip,
        "frames": state.frames,
    }


def _ellipsoid(covariance, n_sigma: float):
    """Half sizes `(3,)` and rotation quaternion `(x, y, z, w)` of the `n_sigma` ellipsoid
    of a `(3, 3)` covariance (its principal axes)."""
    from ..geometry._rotation import matrix_to_quaternion

    S = _np(covariance)
    values, vectors = np.linalg.eigh(0.5 * (S + S.T))
    if np.linalg.det(vectors) < 0:
        vectors[:, -1] *= -1
    q = _f64(matrix_to_quaternion, vectors)  # (w, x, y, z)
    return n_sigma * np.sqrt(np.clip(values, 0, None)), np.array([q[1], q[2], q[3], q[0]])


def log_pointing(
    rec: rr.RecordingStream,
    camera,
    pixel,
    hit: Hit | None,
    pose: Pose | tuple,
    *,
    polyhedron: Polyhedron | None = None,
    model_points=None,
    robot: Robot | None = None,
    joints=None,
    true_point=None,
    image=None,
    image_size: tuple[int, int] | None = None,
    K=None,
    R_wc=None,
    t_wc=None,
    n_sigma: float = 3.0,
    summary: list[str] | None = None,
    layout: bool = True,
) -> None:
    """Log a pointing command (`jaxpose.pick`, then the robot to the point): the camera and
    its image, the object's wireframe at `pose`, the clicked pixel and its visual ray, the
    3D point with its covariance ellipsoid, the face hit, and the robot at `joints`.

    Entities, besides `log_camera`'s and `log_pose`'s (`name = "recovered"`):

    | path | what |
    |---|---|
    | `world/camera/image/click` | the clicked pixel (2D) |
    | `world/pointing/ray` | its visual ray, from the camera centre to past the hit |
    | `world/pointing/point` | the 3D point, labelled with its sigma along the ray |
    | `world/pointing/covariance` | its `n_sigma` covariance ellipsoid |
    | `world/pointing/face`, `world/camera/image/face` | the face hit (outline, 3D, 2D) |
    | `world/pointing/normal` | the face's outward normal at the point |
    | `world/pointing/true_point` | the true surface point, when given |
    | `world/robot/travel` | the carriage's travel at wrist height |
    | `world/robot/links` | bridge, pan axis and shank at `joints` (forward kinematics) |
    | `world/robot/joints` | the wrist and the LED tip |
    | `world/robot/frames` | the turret's and the tool's axes (x red, y green, z blue) |
    | `summary` | the answer, as a Markdown text document |

    **Arguments:**
    - `camera`: `C` `(3, 4)`; `K`, `R_wc`, `t_wc`, `image`, `image_size`: see `log_camera`.
    - `pixel`: `(2,)` the clicked pixel `(u, v)`.
    - `hit`: `jaxpose.pick`'s `Hit` (numpy or JAX arrays); None or a status other than
      `OK`: no face there, only the ray is drawn.
    - `pose`: `(R, t)` of the object, model to world (the recovered pose).
    - `polyhedron`: the object, for its wireframe and the face outline.
    - `model_points`: `(n, 3)` matched model points (default: the polyhedron's vertices).
    - `robot`, `joints`: a `jaxpose.Robot` and its `(4,)` joint command (e.g.
      `jaxpose.inverse_kinematics(...).joints`); the robot is drawn when both are given.
    - `true_point`: `(3,)` the true surface point under the click, when known.
    - `n_sigma`: size of the drawn ellipsoid in standard deviations.
    - `summary`: Markdown lines for `summary` (default: a short description).
    - `layout`: send the pointing layout (`pointing_blueprint`) with the 3D view framed
      on the object and the robot; False keeps the recording's own blueprint.
    """
    rr = _rr()
    R, t = _np(pose[0]), _np(pose[1])
    parts = _camera_parts(camera, K, R_wc, t_wc)
    centre = parts[3]
    if model_points is None:
        if polyhedron is None:
            raise ValueError("log_pointing needs model_points or a polyhedron")
        model_points = polyhedron.vertices
    world = _transform(R, t, model_points)
    distance = _log_camera_near(rec, camera, parts, world, image_size, image)
    log_pose(rec, "recovered", camera, model_points, (R, t), polyhedron=polyhedron)
    pixel = _np(pixel).reshape(2)
    found = hit is not None and int(np.asarray(hit.status)) == Status.OK
    rec.log(
        "world/camera/image/click",
        rr.Points2D(
            pixel[None],
            colors=(255, 220, 0),
            radii=rr.Radius.ui_points(7.0),
            labels=f"click ({pixel[0]:.1f}, {pixel[1]:.1f})",
        ),
        static=True,
    )
    from ..geometry._camera import backproject

    _, direction = _f64(backproject, camera, pixel[None])
    direction = direction[0] / np.linalg.norm(direction[0])
    point = _np(hit.point) if found else None
    reach = 1.1 * (np.linalg.norm(point - centre) if found else distance)
    rec.log(
        "world/pointing/ray",
        rr.LineStrips3D(
            [np.stack([centre, centre + reach * direction])],
            colors=(255, 220, 0),
            radii=rr.Radius.ui_points(1.0),
        ),
        static=True,
    )
    lines = list(summary or [])
    if found:
        S = _np(hit.covariance)
        along = float(np.sqrt(max(direction @ S @ direction, 0.0)))
        face = int(np.asarray(hit.face))
        label = f"face {face}: sigma {along:.2f} mm along the ray"
        rec.log(
            "world/pointing/point",
            rr.Points3D(
                point[None],
                colors=_OBSERVED,
                radii=rr.Radius.ui_points(6.0),
                labels=label,
            ),
            static=True,
        )
        half, quaternion = _ellipsoid(S, n_sigma)
        if np.any(half > 0):
            rec.log(
                "world/pointing/covariance",
                rr.Ellipsoids3D(
                    centers=point[None],
                    half_sizes=half[None],
                    quaternions=[rr.Quaternion(xyzw=quaternion)],
                    colors=_OBSERVED,
                    # Wireframe: a flat (rank-deficient) covariance still shows, as lines.
                    fill_mode="majorwireframe",
                    line_radii=rr.Radius.ui_points(1.0),
                    labels=f"{n_sigma:g} sigma",
                ),
                static=True,
            )
        normal = _np(hit.normal)
        size = float(np.max(np.linalg.norm(world - world.mean(axis=0), axis=1)))
        rec.log(
            "world/pointing/normal",
            rr.Arrows3D(
                vectors=[0.4 * size * normal],
                origins=[point],
                colors=_PURPLE,
            ),
            static=True,
        )
        if polyhedron is not None and 0 <= face < len(polyhedron.faces):
            corners = _transform(R, t, _np(polyhedron.vertices)[list(polyhedron.faces[face])])
            loop = np.vstack([corners, corners[:1]])
            rec.log(
                "world/pointing/face",
                rr.LineStrips3D([loop], colors=_ORANGE, radii=rr.Radius.ui_points(3.0)),
                static=True,
            )
            uv, front = _project(camera, loop)
            if front.all():
                rec.log(
                    "world/camera/image/face",
                    rr.LineStrips2D([uv], colors=_ORANGE, radii=rr.Radius.ui_points(2.0)),
                    static=True,
                )
        if not lines:
            lines = [
                f"# Pointing at ({pixel[0]:.1f}, {pixel[1]:.1f}) px",
                "",
                f"- face {face}, point {np.array2string(point, precision=2)}",
                f"- 1-sigma: {np.array2string(np.sqrt(np.diag(S)), precision=2)} in x, y, z;"
                f" {along:.2f} along the ray (ellipsoid drawn at {n_sigma:g} sigma)",
            ]
    elif not lines:
        lines = [f"# Pointing at ({pixel[0]:.1f}, {pixel[1]:.1f}) px: no face there"]
    if true_point is not None:
        rec.log(
            "world/pointing/true_point",
            rr.Points3D(
                _np(true_point).reshape(1, 3),
                colors=_TRUE,
                radii=rr.Radius.ui_points(4.0),
                labels="true surface point",
            ),
            static=True,
        )
    targets = [world]
    if robot is not None and joints is not None:
        drawing = _robot_drawing(robot, joints)
        rec.log(
            "world/robot/travel",
            rr.LineStrips3D([drawing["travel"]], colors=_GREY, radii=rr.Radius.ui_points(0.75)),
            static=True,
        )
        rec.log(
            "world/robot/links",
            rr.LineStrips3D(
                [drawing["bridge"], drawing["pan_axis"], drawing["shank"]],
                colors=[(150, 150, 150), (66, 135, 245), (66, 135, 245)],
                radii=rr.Radius.ui_points(3.0),
                labels=["bridge (x)", "pan axis", "shank"],
            ),
            static=True,
        )
        rec.log(
            "world/robot/joints",
            rr.Points3D(
                np.stack([drawing["wrist"], drawing["tip"]]),
                colors=[(66, 135, 245), (0, 170, 90)],
                radii=rr.Radius.ui_points(6.0),
                labels=["wrist (pan, tilt)", "tip (LED)"],
            ),
            static=True,
        )
        frames = drawing["frames"][2:]  # turret and tool
        size = 0.15 * float(np.asarray(robot.shank))
        rec.log(
            "world/robot/frames",
            rr.Arrows3D(
                vectors=np.concatenate([size * F[:3, :3].T for F in frames]),
                origins=np.repeat(np.stack([F[:3, 3] for F in frames]), 3, axis=0),
                colors=np.tile(np.array([(230, 50, 50), (40, 200, 90), (66, 135, 245)]), (2, 1)),
            ),
            static=True,
        )
        targets.append(np.stack([drawing["wrist"], drawing["tip"]]))
    rec.log("summary", _summary(lines), static=True)
    if layout:
        up = _world_up(parts[1], parts[2])
        _frame_object(rec, centre, np.concatenate(targets), up, make_blueprint=pointing_blueprint)
