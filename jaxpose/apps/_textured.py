"""Textured objects: the pose of an object from a photograph's keypoints matched to its
textured model.

`locate_textured` matches the photograph's keypoints to the model
(`jaxpose.features.match_keypoints`), then finds the pose that most matches agree with
by jaxpose's robust mode (`jaxpose.api.solve_pnp_ransac`: every sampled triplet's
three-point poses scored by consensus, the best refined on its inliers). OpenCV's
conventions throughout: `x_cam = Rodrigues(rvec) X + tvec`, pixels with the centre of the
top-left pixel at `(0, 0)`.
"""

from __future__ import annotations

import math
import os
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from ..api._pnp import solve_pnp_ransac
from ..features._keypoints import (
    Matches,
    TexturedModel,
    check_match_options,
    check_model,
    match_keypoints,
)
from ..geometry._validate import as_dist_coeffs, as_intrinsics, as_matching, no_type_check
from ..strategy._options import RobustOptions, resolve

__all__ = ["TexturedPose", "locate_matches", "locate_textured"]


class TexturedPose(NamedTuple):
    """The pose of a textured object in a photograph.

    **Fields:**
    - `ok`: whether a pose with at least `min_inliers` inlier matches was found.
    - `rvec`, `tvec`: `(3, 1)` float64, the pose (OpenCV's: `x_cam = Rodrigues(rvec) X +
      tvec`); zeros when `ok` is False.
    - `inliers`: `(N,)` bool, the matches consistent with the pose (all False when `ok`
      is False).
    - `matches`: the `Matches` the pose was found from.
    - `rms`: root mean square reprojection error of the inliers (px; with the
      distortion); 0 when `ok` is False.
    """

    ok: bool
    rvec: np.ndarray
    tvec: np.ndarray
    inliers: np.ndarray
    matches: Matches
    rms: float


def _failed(matches: Matches) -> TexturedPose:
    n = len(matches.distance)
    return TexturedPose(False, np.zeros((3, 1)), np.zeros((3, 1)), np.zeros(n, bool), matches, 0.0)


def _check_threshold(threshold: object) -> float:
    if isinstance(threshold, bool) or not (
        isinstance(threshold, int | float | np.floating | np.integer)
        and math.isfinite(threshold)
        and threshold > 0
    ):
        raise ValueError(f"threshold must be a positive number, got {threshold!r}")
    return float(threshold)


@no_type_check
def locate_matches(
    matches: Matches,
    camera_matrix: npt.ArrayLike,
    dist_coeffs: npt.ArrayLike | None = None,
    *,
    threshold: float = 8.0,
    options: RobustOptions | None = None,
    **changes: Any,
) -> TexturedPose:
    """The pose from 2D-3D matches of which some may be wrong (the second half of
    `locate_textured`).

    **Arguments:**
    - `matches`: `Matches` (from `jaxpose.features.match_keypoints`, or built by hand).
    - `camera_matrix`: `K` `(3, 3)`; `dist_coeffs`: OpenCV's distortion, or `None`.
    - `threshold`: the inlier test's radius (px, default 8: OpenCV's).
    - `options`, `**changes`: a `jaxpose.RobustOptions` and keyword shorthands for its
      fields (`min_inliers`, `max_triplets`, `refine`, ...), as
      `jaxpose.api.solve_pnp_ransac` takes them.

    **Returns:** a `TexturedPose` (`ok` False, with zeros, when fewer than
    `min_inliers` matches agree on a pose).

    **Raises:** `ValueError` naming the argument.
    """
    if not isinstance(matches, Matches):
        raise ValueError(f"matches must be a Matches, got {type(matches).__name__}")
    threshold = _check_threshold(threshold)
    options = resolve(options, changes, RobustOptions)
    K = np.asarray(as_intrinsics(camera_matrix, "camera_matrix"), np.float64)
    dist = as_dist_coeffs(dist_coeffs, "dist_coeffs")
    n = len(matches.distance)
    if n < max(3, int(options.min_inliers)):
        return _failed(matches)
    obj, img = as_matching(matches.object_points, matches.image_points, min_count=3)
    ok, rvec, tvec, index = solve_pnp_ransac(
        obj, img, K, dist, reprojection_error=threshold, options=options
    )
    if not ok or index is None:
        return _failed(matches)
    import cv2

    inliers = np.zeros(n, bool)
    inliers[index.ravel()] = True
    projected, _ = cv2.projectPoints(
        np.asarray(obj, np.float64)[inliers], rvec, tvec, K, None if dist is None else dist
    )
    residual = projected.reshape(-1, 2) - np.asarray(img, np.float64)[inliers]
    rms = float(np.sqrt(np.mean(np.sum(residual**2, axis=1))))
    return TexturedPose(True, rvec, tvec, inliers, matches, rms)


@no_type_check
def locate_textured(
    image: npt.ArrayLike | str | os.PathLike,
    model: TexturedModel,
    camera_matrix: npt.ArrayLike,
    dist_coeffs: npt.ArrayLike | None = None,
    *,
    threshold: float = 8.0,
    detector: str = "orb",
    features: int = 2000,
    ratio: float = 0.8,
    options: RobustOptions | None = None,
    **changes: Any,
) -> TexturedPose:
    """The pose of a textured object in a photograph: its keypoints matched to the
    model (`jaxpose.features.match_keypoints`), then jaxpose's robust pose on the
    matches (`jaxpose.api.solve_pnp_ransac`).

    **Arguments:**
    - `image`: the photograph: a uint8 array `(H, W)` or BGR `(H, W, 3)`, or a path.
    - `model`: a `jaxpose.features.TexturedModel` (`read_textured_model`).
    - `camera_matrix`: `K` `(3, 3)`; `dist_coeffs`: OpenCV's distortion, or `None`.
    - `threshold`: the inlier test's radius (px, default 8: OpenCV's).
    - `detector`, `features`, `ratio`: the matching's options (`match_keypoints`).
    - `options`, `**changes`: the robust mode's (`locate_matches`).

    **Returns:** a `TexturedPose` (`ok` False with finite placeholders when the
    photograph has too few matches or no pose agrees with enough of them).

    **Raises:** `ValueError` naming the argument.
    """
    check_match_options(detector, features, ratio)
    check_model(model, detector)
    _check_threshold(threshold)
    as_intrinsics(camera_matrix, "camera_matrix")
    as_dist_coeffs(dist_coeffs, "dist_coeffs")
    resolve(options, changes, RobustOptions)
    matches = match_keypoints(image, model, detector=detector, features=features, ratio=ratio)
    return locate_matches(
        matches, camera_matrix, dist_coeffs, threshold=threshold, options=options, **changes
    )
