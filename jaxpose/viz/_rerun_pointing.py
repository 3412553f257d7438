"""Logging a pointing command (`log_pointing`): the clicked pixel, its visual ray, the 3D
point with its covariance ellipsoid, the face hit, and the robot sent there."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..apps._pointing import PointingStatus
from ._rerun_common import (
    _GREY,
    _OBSERVED,
    _ORANGE,
    _PURPLE,
    _TRUE,
    _camera_parts,
    _f64,
    _jitted,
    _np,
    _project,
    _rr,
    _summary,
    _transform,
    _world_up,
)
from ._rerun_layout import _frame_object, pointing_blueprint
from ._rerun_scene import _log_camera_near, log_pose

if TYPE_CHECKING:  # pragma: no cover
    import rerun as rr

    from ..apps._pointing import Hit
    from ..apps._polyhedron import Polyhedron
    from ..apps._robot import Robot
    from ..geometry._pose import Pose

__all__ = ["log_pointing"]


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
    """Log a pointing command (`jaxpose.apps.pick`, then the robot to the point): the camera and
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
    - `hit`: `jaxpose.apps.pick`'s `Hit` (numpy or JAX arrays); None or a status other than
      `OK`: no face there, only the ray is drawn.
    - `pose`: `(R, t)` of the object, model to world (the recovered pose).
    - `polyhedron`: the object, for its wireframe and the face outline.
    - `model_points`: `(n, 3)` matched model points (default: the polyhedron's vertices).
    - `robot`, `joints`: a `jaxpose.apps.Robot` and its `(4,)` joint command (e.g.
      `jaxpose.apps.inverse_kinematics(...).joints`); the robot is drawn when both are given.
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
    found = hit if hit is not None and int(np.asarray(hit.status)) == PointingStatus.OK else None
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
    point = None if found is None else _np(found.point)
    reach = 1.1 * (distance if point is None else np.linalg.norm(point - centre))
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
    if found is not None and point is not None:
        S = _np(found.covariance)
        along = float(np.sqrt(max(direction @ S @ direction, 0.0)))
        face = int(np.asarray(found.face))
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
        normal = _np(found.normal)
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
