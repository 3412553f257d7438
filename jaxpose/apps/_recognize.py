"""From a photograph to the objects it shows: the image front end, then recognition
without correspondences (polyhedral models, `detect`) and the keypoint path (textured
models, `locate_textured`), in OpenCV's camera conventions.

A lens's distortion is removed from the whole image first (`cv2.undistort`, same
intrinsics), so that straight model edges stay straight for the segment detector and
every pixel of the primitives is an ideal pinhole pixel; the poses are those of the
undistorted image, as the pixels of `cv2.undistortPoints(..., P=K)` give them.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from ..features._keypoints import TexturedModel, as_image
from ..features._vertices import Primitives, image_primitives
from ..geometry._validate import as_dist_coeffs, as_intrinsics, no_type_check
from ._detect import Detection, detect
from ._polyhedron import Polyhedron
from ._textured import TexturedPose, locate_textured

__all__ = ["Recognition", "recognize"]


class Recognition(NamedTuple):
    """What `recognize` found.

    **Fields:** `detections`: polyhedral models found (`Detection`, world frame = camera
    frame, best first); `textured`: one `TexturedPose` per textured model, by name;
    `primitives`: the image's segments, vertices and links (None without a polyhedral
    model); `image`: the undistorted image the primitives come from.
    """

    detections: list[Detection]
    textured: dict[str, TexturedPose]
    primitives: Primitives | None
    image: np.ndarray


@no_type_check
def recognize(
    image,
    models,
    camera_matrix,
    dist_coeffs=None,
    *,
    front_end: dict[str, Any] | None = None,
    **options: Any,
) -> Recognition:
    """Recognise polyhedral and textured models in one photograph.

    **Arguments:**
    - `image`: uint8 grey, BGR or BGRA array, or a path to an image file.
    - `models`: a sequence of `Polyhedron` (the vertex path) and `TexturedModel` (the
      keypoint path), or a dict name -> model.
    - `camera_matrix`: `K` `(3, 3)`; `dist_coeffs`: OpenCV's distortion coefficients
      (4, 5, 8, 12 or 14) or None.
    - `front_end`: options of `jaxpose.features.image_primitives`.
    - `options`: options of `detect` (`noise`, `min_support`, ...).

    **Returns:** a `Recognition`.
    """
    import cv2

    img = as_image(image, "image")
    K = as_intrinsics(camera_matrix, "camera_matrix")
    dist = as_dist_coeffs(dist_coeffs, "dist_coeffs")
    items = list(models.values()) if isinstance(models, dict) else list(models)
    if not items:
        raise ValueError("models must hold at least one Polyhedron or TexturedModel")
    for i, m in enumerate(items):
        if not isinstance(m, Polyhedron | TexturedModel):
            raise ValueError(
                f"models[{i}] must be a Polyhedron or a TexturedModel, got {type(m).__name__}"
            )
    if dist is not None and np.any(dist != 0):
        img = cv2.undistort(img, K, dist)
    polyhedra = {m.name: m for m in items if isinstance(m, Polyhedron)}
    textured = {
        m.name: locate_textured(img, m, K, None) for m in items if isinstance(m, TexturedModel)
    }
    primitives, detections = None, []
    if polyhedra:
        primitives = image_primitives(img, **(front_end or {}))
        camera = K @ np.eye(3, 4)
        detections = detect(camera, primitives, polyhedra, **options)
    return Recognition(detections, textured, primitives, img)
