"""Pictures of a tracked video (issue #32): the model's visible edges at each frame's pose
drawn over the frame (`draw_tracked`, for an overlay video) and a rerun recording of
the track (`track_blueprint`, `log_track_camera`, `log_tracked_frame`): the video
frames with the model's edges over them, the object's trajectory and wireframe in 3D,
and per-frame scalars.

The edges drawn are those the tracker measures (`jaxpose.apps.edge_samples`: faces
turned away and hidden parts removed, distortion applied), joined into polylines.

Entity paths (the world is the camera frame, OpenCV's: x right, y down, z forward):

| path | what |
|---|---|
| `world/camera/image` | the pinhole, and each frame (JPEG) on the `frame` timeline |
| `world/camera/image/edges` | the model's visible edges at the frame's pose (2D) |
| `world/model` | the model's wireframe at the frame's pose (3D) |
| `world/trajectory` | the model centre's path over the frames with a pose so far (3D) |
| `metrics/error_px`, `metrics/inliers`, `metrics/ms` | per-frame scalars |
| `metrics/rotation_std_deg`, `metrics/translation_std` | the pose's spread (below) |
| `world/target`, `world/camera/image/target` | a followed click (`jaxpose track --point`) |
| `status` | one log line per frame: its status |

The pose's spread: the square roots of the traces of the rotation and translation
blocks of `jaxpose.apps.frame_covariance` (degrees, model units), on frames with a pose.

Plain numpy and OpenCV; `rerun` is imported only when a recording is made.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..apps._track import TrackedFrame
from ..apps._track_solve import frame_covariance
from ..apps._visibility import MeshGeometry, edge_samples
from ._rerun_common import _rr, _strips3d

if TYPE_CHECKING:  # pragma: no cover
    import rerun as rr
    import rerun.blueprint as rrb

__all__ = [
    "draw_target",
    "draw_tracked",
    "log_track_camera",
    "log_tracked_frame",
    "track_blueprint",
]

#: The colour of the model's edges by the frame's status (RGB).
STATUS_RGB = {
    "initialised": (0, 160, 255),
    "tracked": (40, 200, 90),
    "reinitialised": (0, 160, 255),
    "lost": (230, 50, 50),
}


def visible_edges(geo: MeshGeometry, K, dist, R, t, image_size, spacing: float = 3.0):
    """The model's edges seen at pose `(R, t)` as polylines: a list of `(k, 2)` pixel
    arrays, one per visible stretch of an edge (`edge_samples` every `spacing` px)."""
    s = edge_samples(geo, K, dist, R, t, spacing=spacing, image_size=image_size)
    if not s.visible.any():
        return []
    # A new stretch wherever the edge changes or a sample is hidden.
    breaks = np.flatnonzero((np.diff(s.edge) != 0) | (np.diff(s.visible.astype(np.int8)) != 0))
    out = []
    for run in np.split(np.arange(len(s.edge)), breaks + 1):
        if len(run) >= 2 and s.visible[run[0]]:
            out.append(s.pixels[run])
    return out


def draw_tracked(image: np.ndarray, geo: MeshGeometry, K, dist, result: TrackedFrame,
                 *, thickness: int = 2) -> np.ndarray:  # fmt: skip
    """A copy of `image` (BGR or grey, uint8) with the model's visible edges drawn at
    `result`'s pose, in the colour of its status (green tracked, blue (re)initialised,
    red lost: the last pose held), and the frame's number and status written."""
    import cv2

    picture = np.asarray(image)
    if picture.ndim == 2:
        picture = cv2.cvtColor(picture, cv2.COLOR_GRAY2BGR)
    else:
        picture = picture.copy()
    h, w = picture.shape[:2]
    r, g, b = STATUS_RGB.get(result.status, (200, 200, 200))
    if result.R is not None and np.all(np.isfinite(result.t)) and result.t[2] > 0:
        lines = visible_edges(geo, K, dist, result.R, result.t, (w, h))
        polys = [np.round(p * 16).astype(np.int32) for p in lines]
        cv2.polylines(picture, polys, False, (b, g, r), thickness, cv2.LINE_AA, 4)
    label = f"{result.frame} {result.status}"
    cv2.putText(picture, label, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (b, g, r), 2,
                cv2.LINE_AA)  # fmt: skip
    return picture


def draw_target(picture: np.ndarray, target) -> None:
    """Mark a followed point (`jaxpose.apps.Target`) on a BGR `picture` in place: a
    yellow cross where it is in sight, a grey one where the object hides it."""
    import cv2

    if not np.all(np.isfinite(target.pixel)):
        return
    u, v = (int(round(float(x))) for x in target.pixel)
    colour = (0, 220, 255) if target.visible else (150, 150, 150)
    cv2.drawMarker(picture, (u, v), colour, cv2.MARKER_CROSS, 18, 2, cv2.LINE_AA)


def track_blueprint() -> rrb.Blueprint:
    """The layout of a tracking recording: the frames with the model's edges beside the
    3D scene (camera, trajectory, wireframe), the per-frame scalars and the status log
    below, the time panel on the `frame` timeline."""
    import rerun.blueprint as rrb

    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(
                rrb.Spatial2DView(origin="world/camera/image", name="video"),
                rrb.Spatial3DView(origin="world", name="trajectory"),
            ),
            rrb.Horizontal(
                rrb.TimeSeriesView(origin="metrics/error_px", name="RMS residual (px)"),
                rrb.TimeSeriesView(origin="metrics/inliers", name="measurements used"),
                rrb.TimeSeriesView(origin="metrics/ms", name="time per frame (ms)"),
                rrb.TimeSeriesView(
                    origin="metrics/rotation_std_deg", name="rotation std (deg, noise only)"
                ),
                rrb.TextLogView(origin="status", name="status"),
            ),
            row_shares=[3, 2],
        ),
        rrb.TimePanel(timeline="frame"),
        collapse_panels=True,
    )


def log_track_camera(rec: rr.RecordingStream, K, image_size: tuple[int, int]) -> None:
    """The camera (static): the world is its frame; its pinhole and image size."""
    rr = _rr()
    K = np.asarray(K, np.float64)
    rec.log("world", rr.ViewCoordinates.RDF, static=True)
    rec.log(
        "world/camera/image",
        rr.Pinhole(image_from_camera=K, resolution=[int(image_size[0]), int(image_size[1])]),
        static=True,
    )


def log_tracked_frame(
    rec: rr.RecordingStream,
    frame: np.ndarray,
    result: TrackedFrame,
    geo: MeshGeometry,
    K,
    dist,
    trajectory: list[np.ndarray],
    *,
    jpeg_quality: int = 75,
    clicked: bool = False,
    target=None,
) -> None:
    """One frame on the `frame` timeline: the image (JPEG), the model's edges over it
    and its wireframe in 3D at the frame's pose, the trajectory so far (`trajectory`:
    the model centre's positions of the frames with a pose, this one appended when it
    has one), the scalars and the status line; when `clicked` (a click is followed), the
    pixel and 3D point of `target` (a `jaxpose.apps.Target`, or None on a frame without
    one: cleared)."""
    import cv2

    rr = _rr()
    rec.set_time("frame", sequence=int(result.frame))
    picture = np.asarray(frame)
    rgb = picture if picture.ndim == 2 else cv2.cvtColor(picture, cv2.COLOR_BGR2RGB)
    rec.log("world/camera/image", rr.Image(rgb).compress(jpeg_quality=jpeg_quality))
    colour = STATUS_RGB.get(result.status, (200, 200, 200))
    h, w = picture.shape[:2]
    lines = visible_edges(geo, K, dist, result.R, result.t, (w, h))
    rec.log("world/camera/image/edges", rr.LineStrips2D(lines, colors=colour))
    vertices = np.asarray(geo.model.vertices, np.float64)
    world = vertices @ result.R.T + result.t
    edges = np.asarray(geo.model.edges, np.int64).reshape(-1, 2)
    rec.log("world/model", rr.LineStrips3D(_strips3d(world, edges), colors=colour))
    if result.ok:
        trajectory.append(vertices.mean(axis=0) @ result.R.T + result.t)
    if len(trajectory) >= 2:
        rec.log("world/trajectory", rr.LineStrips3D([np.array(trajectory)], colors=(255, 200, 0)))
    if target is not None:
        colour = (255, 220, 0) if target.visible else (150, 150, 150)
        rec.log("world/camera/image/target", rr.Points2D([target.pixel], colors=colour, radii=4))
        rec.log("world/target", rr.Points3D([target.point], colors=colour, radii=1.0))
    elif clicked:
        rec.log("world/camera/image/target", rr.Clear(recursive=False))
        rec.log("world/target", rr.Clear(recursive=False))
    rec.log("metrics/error_px", rr.Scalars(float(result.rms)))
    rec.log("metrics/inliers", rr.Scalars(float(result.edges + result.points)))
    rec.log("metrics/ms", rr.Scalars(float(result.ms)))
    spread = frame_covariance(result)
    if spread is not None:
        cov = np.asarray(spread.covariance)
        blocks = (cov[:3, :3], cov[3:, 3:])
        rotation, translation = (max(float(np.trace(b)), 0.0) ** 0.5 for b in blocks)
        rec.log("metrics/rotation_std_deg", rr.Scalars(np.degrees(rotation)))
        rec.log("metrics/translation_std", rr.Scalars(translation))
    level = "WARN" if result.status == "lost" else "INFO"
    text = (f"frame {result.frame}: {result.status}, {result.edges} edges, "
            f"{result.points} points, {result.rms:.2f} px, {result.ms:.1f} ms")  # fmt: skip
    rec.log("status", rr.TextLog(text, level=level))
