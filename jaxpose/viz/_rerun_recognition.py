"""Logging a recognition (`log_recognition`): the photograph, its primitives (segments,
vertices, the links between them), every detection's model edges at its pose, and the
winner's overlay with its matches."""

from __future__ import annotations

import re
from typing import TYPE_CHECKING

import numpy as np

from ..apps._polyhedron import Polyhedron
from ..apps._recognize import Recognition
from ..features._keypoints import TexturedModel
from ..geometry._validate import as_intrinsics
from ._rerun_common import (
    _GREY,
    _OBSERVED,
    _ORANGE,
    _PURPLE,
    _RECOVERED,
    _np,
    _project,
    _rr,
    _strips2d,
    _strips3d,
    _summary,
    _transform,
)
from ._rerun_layout import _frame_object, pointing_blueprint
from ._rerun_scene import log_camera

if TYPE_CHECKING:  # pragma: no cover
    import rerun as rr
    import rerun.blueprint as rrb

__all__ = ["log_recognition", "recognition_blueprint"]

_SEGMENT = (0, 200, 255)
_LINK = (255, 220, 0)
_WINNER = _RECOVERED


def recognition_blueprint(
    *, eye: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
) -> rrb.Blueprint:
    """The layout of a recognition recording (`log_recognition`): the same as a pointing
    recording's (`pointing_blueprint`): the 3D scene (camera and the detected models)
    beside the image with its primitives and overlays, the summary below."""
    return pointing_blueprint(eye=eye)


def _entity(rank: int, name: str) -> str:
    """An entity path part for the `rank`-th detection of model `name`."""
    return f"{rank}_" + (re.sub(r"[^A-Za-z0-9_-]", "_", name) or "model")


def _check(recognition, models, meshes, image):
    if not isinstance(recognition, Recognition):
        raise ValueError(f"recognition must be a Recognition, got {type(recognition).__name__}")
    if isinstance(models, Polyhedron | TexturedModel):
        models = [models]
    items = list(models.values()) if isinstance(models, dict) else list(models)
    if not all(isinstance(m, Polyhedron | TexturedModel) for m in items):
        raise ValueError("models must hold Polyhedron and TexturedModel objects only")
    polyhedra = {m.name: m for m in items if isinstance(m, Polyhedron)}
    for d in recognition.detections:
        if d.model not in polyhedra:
            raise ValueError(f"models has no Polyhedron named {d.model!r} (a detection's)")
    meshes = dict(meshes or {})
    if not all(isinstance(m, Polyhedron) for m in meshes.values()):
        raise ValueError("meshes must map textured model names to Polyhedron objects")
    picture = recognition.image if image is None else image
    picture = np.asarray(picture)
    if (
        picture.dtype != np.uint8
        or picture.ndim not in (2, 3)
        or (picture.ndim == 3 and picture.shape[2] not in (3, 4))
        or min(picture.shape[:2]) < 1
    ):
        raise ValueError(
            f"image must be a uint8 (H, W) or RGB(A) (H, W, 3|4) array, got {picture.dtype} "
            f"{picture.shape}"
        )
    return polyhedra, meshes, picture


def _posed(recognition, polyhedra, meshes):
    """`(rank key, model name, kind, R, t, polyhedron or None, what to say)` of every
    detection: polyhedral ones best first, then textured ones with a pose by inliers."""
    import cv2

    out = []
    for d in recognition.detections:
        out.append(
            (
                d.model,
                "vertex",
                _np(d.R),
                _np(d.t).reshape(3),
                polyhedra[d.model],
                f"score {float(d.score):.2f}, support {float(d.support):.2f}, "
                f"{len(d.vertices)} vertices matched, Eq. 8 error {float(d.error):.2f} px",
            )
        )
    textured = [(n, p) for n, p in recognition.textured.items() if p.ok]
    textured.sort(key=lambda item: -int(np.sum(item[1].inliers)))
    for name, pose in textured:
        R, _ = cv2.Rodrigues(_np(pose.rvec).reshape(3, 1))
        out.append(
            (
                name,
                "keypoint",
                R,
                _np(pose.tvec).reshape(3),
                meshes.get(name),
                f"{int(np.sum(pose.inliers))} of {len(pose.inliers)} keypoint matches, "
                f"rms {float(pose.rms):.2f} px",
            )
        )
    return [(_entity(i, row[0]), *row) for i, row in enumerate(out)]


def _log_primitives(rec, primitives) -> list[str]:
    rr = _rr()
    if primitives is None:
        return []
    ends = _np(primitives.segments.ends).reshape(-1, 2, 2)
    points = _np(primitives.vertices.points).reshape(-1, 2)
    links = np.asarray(primitives.links, bool)
    i, j = np.nonzero(np.triu(links | links.T, 1))
    base = "world/camera/image/primitives"
    rec.log(
        f"{base}/segments",
        rr.LineStrips2D(ends, colors=_SEGMENT, radii=rr.Radius.ui_points(1.0)),
        static=True,
    )
    rec.log(
        f"{base}/vertices",
        rr.Points2D(
            points,
            colors=_ORANGE,
            radii=rr.Radius.ui_points(4.0),
            labels=[str(k) for k in range(len(points))],
            show_labels=False,
        ),
        static=True,
    )
    rec.log(
        f"{base}/links",
        rr.LineStrips2D(
            np.stack([points[i], points[j]], axis=1).reshape(-1, 2, 2),
            colors=_LINK,
            radii=rr.Radius.ui_points(1.5),
        ),
        static=True,
    )
    return [f"- primitives: {len(ends)} segments, {len(points)} vertices, {len(i)} links"]


def log_recognition(
    rec: rr.RecordingStream,
    recognition: Recognition,
    models,
    camera_matrix,
    *,
    meshes: dict[str, Polyhedron] | None = None,
    image=None,
    summary: list[str] | None = None,
    layout: bool = True,
) -> None:
    """Log a recognition (`jaxpose.apps.recognize`): the image with its primitives, each
    detection's model edges at its pose (2D and 3D), and the winner's overlay. The world
    frame is the camera's (`K [I | 0]`); pixels are those of `recognition.image` (the
    undistorted photograph).

    Entities, besides `log_camera`'s:

    | path | what |
    |---|---|
    | `world/camera/image/primitives/segments` | the detected segments |
    | `world/camera/image/primitives/vertices` | the image vertices (labels: their index) |
    | `world/camera/image/primitives/links` | the links between vertices |
    | `world/camera/image/detections/<k>_<model>` | detection `k`'s projected model edges |
    | `world/model/<k>_<model>` | its model's wireframe at the pose (3D) |
    | `world/camera/image/keypoints/<model>` | a textured model's inlier keypoints |
    | `world/camera/image/winner` | the best detection's edges, drawn thick |
    | `world/camera/image/winner/matched` | its matched image vertices (or keypoints) |
    | `world/camera/image/winner/reprojected` | their model vertices at the pose |
    | `summary` | the detections, as a Markdown text document |

    Detections are ranked as `jaxpose recognize` lists them: polyhedral ones best first,
    then textured ones by their number of inliers; `k` is that rank, the winner is 0.

    **Arguments:**
    - `rec`: the `rerun.RecordingStream` to log to.
    - `recognition`: `jaxpose.apps.recognize`'s `Recognition`.
    - `models`: the models given to `recognize` (a sequence, or a dict name -> model).
    - `camera_matrix`: `K` `(3, 3)`.
    - `meshes`: textured model name -> `Polyhedron` whose edges are drawn at that
      model's pose (default: none; its inlier keypoints are drawn instead).
    - `image`: the picture shown (uint8 `(H, W)` or RGB `(H, W, 3)`, the size of
      `recognition.image`), e.g. the undistorted colour photograph; default
      `recognition.image`.
    - `summary`: Markdown lines for `summary` (default: one line per detection).
    - `layout`: send `recognition_blueprint` with the 3D view framed on the detections.

    **Raises:** `ValueError` naming the argument.
    """
    rr = _rr()
    polyhedra, meshes, picture = _check(recognition, models, meshes, image)
    K = _np(as_intrinsics(camera_matrix, "camera_matrix"))
    if picture.shape[:2] != np.asarray(recognition.image).shape[:2]:
        raise ValueError(
            f"image must have the size of recognition.image {recognition.image.shape[:2]}, "
            f"got {picture.shape[:2]}"
        )
    camera = K @ np.eye(3, 4)
    height, width = picture.shape[:2]
    log_camera(
        rec,
        camera,
        K=K,
        R_wc=np.eye(3),
        t_wc=np.zeros(3),
        image_size=(width, height),
        image=picture,
    )
    lines = ["# Recognition", ""] + _log_primitives(rec, recognition.primitives)
    posed = _posed(recognition, polyhedra, meshes)
    targets = []
    for rank, (key, name, kind, R, t, polyhedron, said) in enumerate(posed):
        color = _WINNER if rank == 0 else (_PURPLE if kind == "keypoint" else _GREY)
        lines.append(f"- {rank}: **{name}** ({kind} path): {said}")
        if kind == "keypoint":
            pose = recognition.textured[name]
            seen = _np(pose.matches.image_points)[np.asarray(pose.inliers, bool)]
            rec.log(
                f"world/camera/image/keypoints/{key}",
                rr.Points2D(seen, colors=_PURPLE, radii=rr.Radius.ui_points(2.5)),
                static=True,
            )
        if polyhedron is None:
            continue
        world = _transform(R, t, polyhedron.vertices)
        targets.append(world)
        edges = np.asarray(polyhedron.edges, np.int64).reshape(-1, 2)
        rec.log(
            f"world/model/{key}",
            rr.LineStrips3D(_strips3d(world, edges), colors=color, radii=rr.Radius.ui_points(1.5)),
            static=True,
        )
        rec.log(
            f"world/camera/image/detections/{key}",
            rr.LineStrips2D(
                _strips2d(camera, world, edges),
                colors=color,
                radii=rr.Radius.ui_points(1.5),
                labels=f"{rank}: {name}",
            ),
            static=True,
        )
    if posed:
        key, name, kind, R, t, polyhedron, said = posed[0]
        lines.insert(2, f"Winner: **{name}** ({kind} path), {said}.\n")
        if polyhedron is not None:
            world = _transform(R, t, polyhedron.vertices)
            edges = np.asarray(polyhedron.edges, np.int64).reshape(-1, 2)
            rec.log(
                "world/camera/image/winner",
                rr.LineStrips2D(
                    _strips2d(camera, world, edges),
                    colors=_WINNER,
                    radii=rr.Radius.ui_points(3.0),
                    labels=name,
                ),
                static=True,
            )
        if kind == "vertex":
            d = recognition.detections[0]
            matched = _np(d.pixels).reshape(-1, 2)
            model_points = _np(polyhedra[name].vertices)[np.asarray(d.vertices, np.int64)]
            labels = [str(int(v)) for v in d.vertices]
        else:
            pose = recognition.textured[name]
            inliers = np.asarray(pose.inliers, bool)
            matched = _np(pose.matches.image_points)[inliers]
            model_points = _np(pose.matches.object_points)[inliers]
            labels = None
        uv, front = _project(camera, _transform(R, t, model_points))
        rec.log(
            "world/camera/image/winner/matched",
            rr.Points2D(matched, colors=_OBSERVED, radii=rr.Radius.ui_points(5.0), labels=labels),
            static=True,
        )
        rec.log(
            "world/camera/image/winner/reprojected",
            rr.Points2D(uv[front], colors=_WINNER, radii=rr.Radius.ui_points(3.0)),
            static=True,
        )
    else:
        lines.append("- nothing recognised")
    rec.log("summary", _summary(summary if summary is not None else lines), static=True)
    if not layout:
        return
    if targets:
        _frame_object(
            rec,
            np.zeros(3),
            np.concatenate(targets),
            np.array([0.0, -1.0, 0.0]),
            make_blueprint=recognition_blueprint,
        )
    else:
        rec.send_blueprint(recognition_blueprint(), make_active=True, make_default=True)
