"""A clicked point followed through a tracked sequence: the paper's pointing (Section 6)
on a video.

The operator clicks a pixel on one frame. Its visual ray meets the object at that frame's
tracked pose (`jaxpose.apps.pick`, the nearest face under the pixel), which fixes the
point on the object, in the model frame: the `Anchor`. On every later frame with a pose
the pose carries it, `p = R m + t`: its position in the camera frame (the position order
for a robot whose base is calibrated to the camera), its pixel (the camera's distortion
applied), and whether it is in sight there (the visual ray of that pixel meets the object
at the point itself, not at a face in front of it, nor on a face turned away). A frame
without a pose (`TrackedFrame.ok` False) gives no target: the point is not guessed.

`follow_click` runs this beside `jaxpose.apps.track`; `jaxpose track --point U V
[--point-frame N]` writes the targets to its JSON and CSV and draws them on its overlay.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from ..api._programs import program
from ..geometry._validate import no_type_check
from ._polyhedron import Polyhedron
from ._track import _undistort
from ._track_solve import _float, frame_covariance
from ._visibility import _check_pose, project

if TYPE_CHECKING:
    from ._track import TrackedFrame

__all__ = ["Anchor", "Target", "anchor_click", "follow_anchor", "follow_click"]


class Anchor(NamedTuple):
    """A clicked point fixed on the object.

    **Fields:**
    - `frame`: the frame the click was made on.
    - `pixel`: `(2,)` the clicked pixel `(u, v)`.
    - `point`: `(3,)` the point of the object under it, model frame.
    - `face`: the index of its face (into `Polyhedron.faces`).
    """

    frame: int
    pixel: np.ndarray
    point: np.ndarray
    face: int


class Target(NamedTuple):
    """The anchored point on one frame.

    **Fields:**
    - `frame`: the frame's number.
    - `point`: `(3,)` the point in the camera frame, `R m + t` (model units).
    - `pixel`: `(2,)` where it projects (the camera's distortion applied).
    - `visible`: whether it is in sight: in front of the camera, on a face turned to
      it, and nothing of the object in front of it.
    - `covariance`: `(3, 3)` the covariance of `point` from the frame's pose covariance
      (the anchored model point held fixed), or None when none was given.
    """

    frame: int
    point: np.ndarray
    pixel: np.ndarray
    visible: bool
    covariance: np.ndarray | None = None


def _pick_run(K, vertices, mask, R, t, pixel):
    """`pick` with the camera `K [I | 0]` (the camera frame as the world frame): the
    point, its face and the status. One stored program (`jaxpose.api._programs`)."""
    import jax.numpy as jnp

    from ..geometry._pose import Pose
    from ._pointing import Faces, pick

    camera = jnp.concatenate([K, jnp.zeros((3, 1), K.dtype)], axis=1)
    hit = pick(camera, Faces(vertices, mask), Pose(R, t), pixel)
    return hit.point, hit.face, hit.status


def _faces(model):
    from ._pointing import polyhedron_faces

    if not isinstance(model, Polyhedron):
        raise ValueError(f"model must be a Polyhedron, got {type(model).__name__}")
    return polyhedron_faces(model)


_PICK = program(_pick_run)


def _hit(faces, K, R, t, pixel) -> tuple[np.ndarray, int, bool]:
    from ._pointing import PointingStatus

    f = _float()
    args = (K, faces.vertices, R, t, pixel)
    K, vertices, R, t, pixel = (np.asarray(a, f) for a in args)
    point, face, status = _PICK(K, vertices, faces.mask, R, t, pixel)
    return np.asarray(point, np.float64), int(face), int(status) == PointingStatus.OK


def _anchor(faces, K, dist, R, t, pixel: np.ndarray, frame: int) -> Anchor | None:
    point, face, ok = _hit(faces, K, R, t, _undistort(pixel[None], K, dist)[0])
    return Anchor(int(frame), pixel, R.T @ (point - t), face) if ok else None


def _follow(anchor: Anchor, faces, K, dist, R, t, frame: int, pose_cov=None) -> Target:
    p = R @ anchor.point + t
    cov = None
    if pose_cov is not None:
        # p = exp(hat(w)) R m + t + dt: dp / d(w, dt) = [-hat(R m), I]
        J = np.hstack([-np.cross(np.eye(3), R @ anchor.point), np.eye(3)])  # (rows e_i x a)
        cov = J @ pose_cov @ J.T
        cov = 0.5 * (cov + cov.T)
    depth = float(p[2])
    if depth <= 0:  # behind the camera: out of sight, no pixel
        return Target(int(frame), p, np.zeros(2), False, cov)
    ideal = (K @ p)[:2] / depth
    pixel = ideal if dist is None else project(p[None], K, dist)[0]
    seen, _, ok = _hit(faces, K, R, t, ideal)
    # in sight: the pixel's ray meets the object first at the point itself
    visible = ok and float(np.linalg.norm(seen - p)) <= 1e-6 * float(np.linalg.norm(p))
    return Target(int(frame), p, np.asarray(pixel, np.float64), bool(visible), cov)


def _pixel(pixel) -> np.ndarray:
    pixel = np.asarray(pixel, np.float64).ravel()
    if pixel.shape != (2,) or not np.all(np.isfinite(pixel)):
        raise ValueError(f"pixel must be two finite numbers (u, v), got {pixel.tolist()}")
    return pixel


@no_type_check
def anchor_click(model: Polyhedron, K, dist, R, t, pixel, *, frame: int = 0) -> Anchor | None:
    """The point of the object under a clicked pixel, fixed on the object.

    **Arguments:**
    - `model`: the tracked `Polyhedron` (e.g. `jaxpose.apps.read_mesh`).
    - `K` `(3, 3)`, `dist` (OpenCV's coefficients or None): the camera.
    - `R`, `t`: the object's pose on the clicked frame, model to camera.
    - `pixel`: `(2,)` the clicked pixel `(u, v)` (as the frame shows it: distorted).
    - `frame`: the frame's number (kept in the `Anchor`).

    **Returns:** an `Anchor`, or None when the pixel's ray meets no face of the object.

    **Raises:** `ValueError` naming the argument.
    """
    faces = _faces(model)
    K, dist, R, t = _check_pose(K, dist, R, t)
    return _anchor(faces, K, dist, R, t, _pixel(pixel), frame)


@no_type_check
def follow_anchor(
    anchor: Anchor, model: Polyhedron, K, dist, R, t, *, frame: int, pose_covariance=None
) -> Target:
    """The anchored point at the pose `(R, t)` of frame `frame` (see the module
    docstring). Arguments as `anchor_click`; `pose_covariance`: optional `(6, 6)`
    covariance of the pose in `jaxpose.pose_covariance`'s order `(w, dt)` (e.g.
    `jaxpose.apps.frame_covariance(result).covariance`), carried to the point's.

    **Raises:** `ValueError` naming the argument.
    """
    if not isinstance(anchor, Anchor):
        raise ValueError(f"anchor must be an Anchor, got {type(anchor).__name__}")
    faces = _faces(model)
    K, dist, R, t = _check_pose(K, dist, R, t)
    cov = None
    if pose_covariance is not None:
        cov = np.asarray(pose_covariance, np.float64)
        if cov.shape != (6, 6) or not np.all(np.isfinite(cov)):
            raise ValueError(f"pose_covariance must be a finite (6, 6) matrix, got {cov.shape}")
    return _follow(anchor, faces, K, dist, R, t, frame, cov)


@no_type_check
def follow_click(
    results: Iterable[TrackedFrame], model: Polyhedron, K, dist, click: tuple[int, float, float]
) -> Iterator[tuple[TrackedFrame, Anchor | None, Target | None]]:
    """Follow a click through `jaxpose.apps.track`'s results as they come.

    **Arguments:**
    - `results`: `TrackedFrame`s (e.g. the generator `jaxpose.apps.track` returns).
    - `model`, `K`, `dist`: as `anchor_click`.
    - `click`: `(frame, u, v)`: the pixel `(u, v)` clicked on frame `frame`. It is
      anchored on the first frame from `frame` on that has a pose.

    **Returns:** a generator of `(result, anchor, target)`, one per result: `anchor`
    None until the click is anchored, and for good when its ray met no face of the
    object there (it is not tried again); `target` None on the frames before and on
    frames without a pose; its `covariance` from the frame's (`frame_covariance`, where
    the result keeps its measurements).

    **Raises:** `ValueError` naming the argument.
    """
    faces = _faces(model)
    K, dist, _, _ = _check_pose(K, dist, np.eye(3), np.zeros(3))
    if not isinstance(click, tuple | list) or len(click) != 3:
        raise ValueError("click must be (frame, u, v)")
    start = int(click[0])
    if start < 0:
        raise ValueError(f"click's frame must be >= 0, got {start}")
    pixel = _pixel(click[1:])
    return _follow_click(results, faces, K, dist, start, pixel)


def _follow_click(
    results: Iterable[TrackedFrame], faces, K, dist, start: int, pixel: np.ndarray
) -> Iterator[tuple[TrackedFrame, Anchor | None, Target | None]]:
    found: Anchor | None = None
    tried = False
    for r in results:
        target = None
        if r.ok and r.frame >= start:
            R, t = np.asarray(r.R, np.float64), np.asarray(r.t, np.float64)
            if not tried:
                tried = True
                found = _anchor(faces, K, dist, R, t, pixel, r.frame)
            if found is not None:
                covariance = frame_covariance(r)
                pose_cov = None if covariance is None else np.asarray(covariance.covariance)
                target = _follow(found, faces, K, dist, R, t, r.frame, pose_cov)
        yield r, found, target
