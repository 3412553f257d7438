"""Finding the object afresh in a video frame, for the tracker's (re-)initialisation
(issue #32): recognition from the mesh alone (`recognize`'s vertex path: the image
front end, then `detect`) or, with a textured model, from its keypoints
(`locate_textured`), as one callable `reinit(frame, index) -> (R, t) or None` that
`jaxpose.apps.track` takes.

With a textured model both run: the keypoints tell a symmetric object from its
half-turned twins, which show the same edges, while the mesh's edges place it more
precisely (the textured model carries its own registration error). The answer is the
mesh's pose, or the twin of it, nearest the keypoints' pose, where it lies within
`AGREE` degrees of it; the keypoints' pose otherwise. On the photo-textured box rendered
by `benchmarks.track_rendered`, where it came back from a full occlusion (frames 13-16
of trajectory 3), the keypoints' pose was 4.3-25 degrees off and the mesh's twin nearest
it 0.23-0.36 degree; on three first frames (clutter, motion blur) 0.75-1.75 against
0.51-0.59 degree, and where the mesh found a wrong pose (82 degrees from the keypoints'),
the keypoints' stood.

A mesh with face colours (`Polyhedron.face_colours`, e.g. a PLY file's) tells its twins
apart by them (`by_colour`): the recognised pose, or its twin whose faces' colours agree
with the frame's grey levels.

Plain numpy around the recognition front end (whose compiled programs are stored, see
`jaxpose.api._programs`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from ..features._keypoints import TexturedModel
from ..features._vertices import MAX_VERTICES
from ..geometry._rotation import rotation_angle
from ..geometry._validate import as_dist_coeffs, as_intrinsics, no_type_check
from ._polyhedron import Polyhedron
from ._symmetry import by_colour, symmetries, turned
from ._visibility import MeshGeometry, mesh_geometry

__all__ = ["AGREE", "MORE_VERTICES", "recognition_reinit"]

#: The largest angle (degrees) between the keypoints' pose and the mesh's (or its twin's)
#: for which the mesh's is taken (see the module docstring).
AGREE = 30.0

#: Image vertices kept by the second try of `recognition_reinit` (the front end keeps 60):
#: on the first frames of the bench's prism rendered in clutter (`benchmarks.track_rendered`,
#: trajectories 2 and 3), recognition found nothing with 60 and the prism within 0.1
#: degree with 120 (1.7 and 4.5 s; 8 and 12 s with 200).
MORE_VERTICES = 120


@no_type_check
def recognition_reinit(
    model: Polyhedron | MeshGeometry,
    camera_matrix,
    dist_coeffs=None,
    *,
    textured: TexturedModel | None = None,
    more_vertices: int | None = MORE_VERTICES,
    **options: Any,
) -> Callable[[np.ndarray, int], tuple[np.ndarray, np.ndarray] | None]:
    """A `reinit` for `jaxpose.apps.track`: the pose of `model` in a frame by
    recognition (see the module docstring).

    **Arguments:**
    - `model`: the `Polyhedron` tracked (or its `MeshGeometry`); with `face_colours`,
      of the recognised pose and its half-turned twins the one whose faces' colours the
      frame shows (`by_colour`).
    - `camera_matrix` `(3, 3)`, `dist_coeffs`: the camera (OpenCV's conventions).
    - `textured`: a `TexturedModel` of the object: where its keypoints give a pose
      (enough inliers), the mesh's pose or its half-turned twin nearest it within
      `AGREE` degrees, else the keypoints' pose (module docstring); where they give
      none, the mesh's recognition alone.
    - `more_vertices`: where the mesh's recognition finds nothing among the front end's
      `max_vertices` best image vertices (60 by default), it is tried once more keeping
      this many (`MORE_VERTICES`); None: not. In clutter the junctions of background
      lines crowd the object's corners out of the best 60.
    - `options`: `recognize`'s (`front_end`, and `detect`'s: `noise`, `min_support`...).

    **Returns:** `reinit(frame, index)`: `(R (3, 3), t (3,))`, model to camera, or None
    when the object is not recognised in the frame; its `chooses_twin` is True where the
    mesh has half-turn symmetries and the face colours or the textured model choose
    among the twins (`track` then takes its pose as the twin, see there).

    **Raises:** `ValueError` naming the argument.
    """
    import cv2

    from ..features._moving_edges import _grey
    from ._recognize import recognize
    from ._textured import locate_textured

    mesh = model.model if isinstance(model, MeshGeometry) else model
    if not isinstance(mesh, Polyhedron):
        raise ValueError(f"model must be a Polyhedron or a MeshGeometry, got "
                         f"{type(model).__name__}")  # fmt: skip
    if textured is not None and not isinstance(textured, TexturedModel):
        raise ValueError(f"textured must be a TexturedModel or None, got "
                         f"{type(textured).__name__}")  # fmt: skip
    if more_vertices is not None and (
        isinstance(more_vertices, bool) or not isinstance(more_vertices, int) or more_vertices < 1
    ):
        raise ValueError(f"more_vertices must be a positive int or None, got {more_vertices!r}")
    front_end = dict(options.pop("front_end", None) or {})
    tries = [front_end]
    kept = front_end.get("max_vertices", MAX_VERTICES)
    if more_vertices is not None and more_vertices > kept:
        tries.append(front_end | {"max_vertices": more_vertices})
    K = as_intrinsics(camera_matrix, "camera_matrix")
    dist = as_dist_coeffs(dist_coeffs, "dist_coeffs")
    geo = mesh_geometry(model)
    coloured = mesh.face_colours is not None
    twin_turns = symmetries(geo) if textured is not None or coloured else []

    def mesh_pose(frame: np.ndarray, fronts: list[dict]) -> tuple[np.ndarray, np.ndarray] | None:
        """The mesh's first detection in `frame`, with the front ends of `fronts` tried
        in turn."""
        for front in fronts:
            found = recognize(frame, [mesh], K, dist, front_end=front, **options).detections
            if found:
                pose = np.asarray(found[0].R, np.float64), np.asarray(found[0].t, np.float64)
                if coloured and twin_turns:  # the twin the faces' colours show
                    twins = [pose] + [turned(*pose, S, c) for S, c in twin_turns]
                    pose = twins[by_colour(_grey(frame), geo, K, dist, twins)]
                return pose
        return None

    def reinit(frame: np.ndarray, index: int) -> tuple[np.ndarray, np.ndarray] | None:
        del index
        if textured is not None:
            pose = locate_textured(frame, textured, K, dist)
            if pose.ok:
                R_k = cv2.Rodrigues(pose.rvec)[0]
                found = mesh_pose(frame, tries[:1])
                if found is not None:
                    twins = [found] + [turned(*found, S, c) for S, c in twin_turns]
                    near = min(twins, key=lambda p: _angle(p[0], R_k))
                    if _angle(near[0], R_k) <= AGREE:
                        return near
                return R_k, pose.tvec.reshape(3)
        return mesh_pose(frame, tries)

    return _Reinit(reinit, bool(twin_turns))


class _Reinit:
    """`recognition_reinit`'s answer: `reinit(frame, index)`, and `chooses_twin`, whether
    its pose is the twin the frame's appearance shows (a symmetric mesh with face colours
    or a textured model): `track` then fits that pose alone, not its twins too."""

    def __init__(self, find: Callable[[np.ndarray, int], tuple | None], chooses_twin: bool):
        self._find = find
        self.chooses_twin = chooses_twin

    def __call__(self, frame: np.ndarray, index: int) -> tuple[np.ndarray, np.ndarray] | None:
        return self._find(frame, index)


def _angle(A: np.ndarray, B: np.ndarray) -> float:
    """The angle (degrees) between two rotations (`rotation_angle` of `A B^T`)."""
    return float(np.degrees(rotation_angle(A @ B.T)))
