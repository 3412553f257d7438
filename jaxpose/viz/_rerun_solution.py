"""Logging one solved problem (`log_solution`) and every triplet's hypothesis on the
`triplet` timeline (`log_triplets`)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from ..solvers._status import Status
from ..strategy._mixed import MixedResult
from ._rerun_common import (
    _GREY,
    _RECOVERED,
    _RED,
    _TRUE,
    METHOD_COLORS,
    METHOD_LABELS,
    _camera_parts,
    _edges,
    _f64,
    _hypothesis_ok,
    _np,
    _project,
    _rr,
    _status_color,
    _summary,
    _transform,
    _world_up,
)
from ._rerun_layout import _frame_object
from ._rerun_scene import _log_camera_near, log_observations, log_pose

if TYPE_CHECKING:  # pragma: no cover
    import rerun as rr

    from ..apps._polyhedron import Polyhedron
    from ..geometry._pose import Pose
    from ..strategy import Initial, Solution

__all__ = ["log_solution", "log_triplets"]


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
    - `result`: `jaxpose.mixed`'s `MixedResult`, or `jaxpose.strategy.initial_poses`'s `Initial`
      (the three-point method alone), for this problem (numpy or JAX arrays).
    - `polyhedron`: the model, for wireframes (else the matched points are drawn).
    - `errors`, `pose_errors`: `(T,)` arrays per method name; default: the Eq. 8 errors
      of the result (for a `MixedResult`: of its three-point, first linear and final
      steps).
    - `statuses`: `(T,)` status arrays per method, written into the log lines.
    """
    rr = _rr()
    staged = isinstance(result, MixedResult)
    initial = result.initial if isinstance(result, MixedResult) else result
    tri = np.asarray(initial.triplets)
    T = len(tri)
    status = np.asarray(result.status)
    error = _np(result.error)
    used = np.array([_hypothesis_ok(s) for s in np.asarray(initial.status)], dtype=bool)
    if errors is None:
        errors = {"three_point": _np(initial.error)}
        if isinstance(result, MixedResult):
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
    ghosts: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray, list[str] | None, float]]
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
            data3: dict[str, Any] = {"strips": world[:, edges].reshape(-1, 2, 3)}
            lengths3 = np.full(len(index), len(edges))
            data2: dict[str, Any] = {"strips": uv[:, edges][keep]}
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
        per_row: dict[str, Any] = {"colors": cols} | ({} if labs is None else {"labels": labs})
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
                    columns=rr.Clear.columns(is_recursive=[False] * len(cleared)),
                )


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
      `jaxpose.strategy.initial_poses`'s `Initial`), see `log_triplets`.
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
        f"- from the triplet of matches {np.asarray(solution.triplet).tolist()}",
    ]
    rec.log("summary", _summary(lines), static=True)
