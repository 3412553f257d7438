"""Logging the scene of one problem (static): the camera and its image, a pose of the
model (wireframe and matched points, in 3D and in the image), the observed image points
and their visual rays."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ._rerun_common import (
    _GREY,
    _OBSERVED,
    _RECOVERED,
    _camera_parts,
    _edges,
    _f64,
    _np,
    _project,
    _rr,
    _strips2d,
    _strips3d,
    _transform,
    _world_is_camera,
)

if TYPE_CHECKING:  # pragma: no cover
    import rerun as rr

    from ..apps._polyhedron import Polyhedron
    from ..geometry._pose import Pose

__all__ = ["log_camera", "log_observations", "log_pose"]


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
