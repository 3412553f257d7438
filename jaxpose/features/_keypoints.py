r"""Keypoints matched against a textured model: the 2D-3D pairs a pose method takes for a
textured object.

A textured model is a set of 3D points on the object, each with the descriptor of the
keypoint it was seen as when the model was registered (OpenCV's real-time pose
estimation tutorial writes such models as YAML: `points_3d`, `descriptors`, ...). The
photograph's keypoints are detected (ORB, or SIFT for a SIFT model), each matched to its
two nearest model descriptors (brute force; Hamming distance for ORB's binary
descriptors, L2 for SIFT's) and kept when it passes Lowe's ratio test,
$d_1 < \rho \, d_2$: the nearest is clearly nearer than the second.

Plain numpy and OpenCV (imported inside the functions, not with the module).
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from ..geometry._validate import no_type_check
from ._files import open_storage

__all__ = [
    "DETECTORS",
    "Matches",
    "TexturedModel",
    "as_image",
    "match_keypoints",
    "read_textured_model",
]

#: The keypoint detectors `match_keypoints` knows, with the descriptor each writes:
#: `(dtype, length)`.
DETECTORS = {"orb": (np.uint8, 32), "sift": (np.float32, 128)}


class TexturedModel(NamedTuple):
    """A textured model: 3D points with the descriptors of their keypoints.

    **Fields:**
    - `points`: `(M, 3)` float64, the points in the model frame (the model's units).
    - `descriptors`: `(M, 32)` uint8 (ORB) or `(M, 128)` float32 (SIFT), row `i` that of
      point `i`.
    - `name`: the model's name (by default its file's name without extensions).
    """

    points: np.ndarray
    descriptors: np.ndarray
    name: str


class Matches(NamedTuple):
    """Keypoints of a photograph matched to a textured model's points.

    **Fields:**
    - `object_points`: `(N, 3)` float64, the model points matched.
    - `image_points`: `(N, 2)` float64, the keypoints' pixels (OpenCV's: the centre of
      the top-left pixel is `(0, 0)`).
    - `distance`: `(N,)` float64, the descriptor distance of each match.
    - `model_index`: `(N,)` int64, the row of each matched point in the model.
    """

    object_points: np.ndarray
    image_points: np.ndarray
    distance: np.ndarray
    model_index: np.ndarray


def no_matches() -> Matches:
    """Zero matches, with the shapes and dtypes of any others."""
    return Matches(np.zeros((0, 3)), np.zeros((0, 2)), np.zeros(0), np.zeros(0, np.int64))


def _model_name(path: Path) -> str:
    name = path.name
    for suffix in (".gz", ".yml", ".yaml", ".xml", ".json"):
        name = name.removesuffix(suffix)
    return name


@no_type_check
def read_textured_model(path: str | os.PathLike, name: str | None = None) -> TexturedModel:
    """Read a textured model in OpenCV's format (YAML, XML or JSON, `.gz` too).

    **Arguments:**
    - `path`: a file with `points_3d` (an `M x 1` matrix of 3-vectors, or `M x 3`) and
      `descriptors` (`M x 32` uint8 for ORB, `M x 128` float32 for SIFT). Its other
      fields (`points_2d`, `keypoints`: the registration photograph's) are not read.
    - `name`: the model's name (`None`: the file's name without extensions).

    **Returns:** a `TexturedModel`.

    **Raises:** `ValueError` naming the path or the field that is missing or malformed.
    """
    if not isinstance(path, str | os.PathLike):
        raise ValueError(f"path must be a str or a path, got {type(path).__name__}")
    if name is not None and not isinstance(name, str):
        raise ValueError(f"name must be a str or None, got {type(name).__name__}")
    path = Path(path)
    fs = open_storage(path)
    try:
        fields = {}
        for field in ("points_3d", "descriptors"):
            node = fs.getNode(field)
            mat = None if node.empty() or node.isNone() else node.mat()
            if mat is None:
                raise ValueError(f"{field} is missing from {str(path)!r} (or not a matrix)")
            fields[field] = np.asarray(mat)
    finally:
        fs.release()
    points = fields["points_3d"]
    if points.size % 3 or points.ndim < 2 or points.shape[-1] not in (1, 3):
        raise ValueError(f"points_3d in {str(path)!r} must hold 3-vectors, got {points.shape}")
    points = points.reshape(-1, 3).astype(np.float64)
    descriptors = fields["descriptors"]
    if descriptors.ndim != 2 or descriptors.shape[0] != len(points):
        raise ValueError(
            f"descriptors in {str(path)!r} must have one row per point ({len(points)}), "
            f"got shape {descriptors.shape}"
        )
    if not np.all(np.isfinite(points)):
        raise ValueError(f"points_3d in {str(path)!r} contains NaN or infinite values")
    return TexturedModel(
        points=points,
        descriptors=np.ascontiguousarray(descriptors),
        name=_model_name(path) if name is None else name,
    )


def as_image(image: object, name: str = "image") -> np.ndarray:
    """A photograph as an 8-bit grayscale array `(H, W)`: from a path (read by
    `cv2.imread`) or an array `(H, W)`, `(H, W, 1)`, `(H, W, 3)` (BGR) or `(H, W, 4)`
    (BGRA) of uint8. `ValueError` naming `name` otherwise."""
    import cv2

    if isinstance(image, str | os.PathLike):
        # (read in colour, then converted: the same pixels as a caller's cv2.imread)
        read = cv2.imread(str(image), cv2.IMREAD_COLOR)
        if read is None:
            raise ValueError(f"{name}: {str(image)!r} could not be read as an image")
        image = read
    if not isinstance(image, np.ndarray):
        raise ValueError(f"{name} must be a numpy array or a path, got {type(image).__name__}")
    if image.dtype != np.uint8:
        raise ValueError(f"{name} must be 8-bit (uint8), got dtype {image.dtype}")
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim == 2:
        gray = image
    elif image.ndim == 3 and image.shape[2] in (3, 4):
        code = cv2.COLOR_BGR2GRAY if image.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
        gray = cv2.cvtColor(np.ascontiguousarray(image), code)
    else:
        raise ValueError(
            f"{name} must have shape (H, W), (H, W, 1), (H, W, 3) or (H, W, 4), got {image.shape}"
        )
    if min(gray.shape) < 1:
        raise ValueError(f"{name} is empty, shape {image.shape}")
    return np.ascontiguousarray(gray)


def check_model(model: object, detector: str, name: str = "model") -> TexturedModel:
    """`model` when it is a `TexturedModel` whose descriptors `detector` writes."""
    if not isinstance(model, TexturedModel):
        raise ValueError(f"{name} must be a TexturedModel, got {type(model).__name__}")
    dtype, length = DETECTORS[detector]
    d = np.asarray(model.descriptors)
    if d.ndim != 2 or d.dtype != dtype or d.shape[1] != length:
        raise ValueError(
            f"{name}'s descriptors must be ({length} per point, {np.dtype(dtype).name}) "
            f"for detector {detector!r}, got shape {d.shape}, dtype {d.dtype}"
        )
    p = np.asarray(model.points)
    if p.shape != (d.shape[0], 3):
        raise ValueError(
            f"{name}'s points must have shape ({d.shape[0]}, 3) (one per descriptor), got {p.shape}"
        )
    return model


def check_match_options(detector: object, features: object, ratio: object) -> None:
    """`ValueError` naming the first bad one of `match_keypoints`' options."""
    if not isinstance(detector, str) or detector not in DETECTORS:
        raise ValueError(f"detector must be one of {sorted(DETECTORS)}, got {detector!r}")
    if isinstance(features, bool) or not isinstance(features, int | np.integer) or features < 1:
        raise ValueError(f"features must be a positive int, got {features!r}")
    if isinstance(ratio, bool) or not (
        isinstance(ratio, int | float | np.floating | np.integer)
        and math.isfinite(ratio)
        and 0 < ratio <= 1
    ):
        raise ValueError(f"ratio must be a number in (0, 1], got {ratio!r}")


@no_type_check
def match_keypoints(
    image: npt.ArrayLike | str | os.PathLike,
    model: TexturedModel,
    *,
    detector: str = "orb",
    features: int = 2000,
    ratio: float = 0.8,
) -> Matches:
    r"""Match a photograph's keypoints to a textured model's points.

    Detects up to `features` keypoints (`cv2.ORB.create` or `cv2.SIFT.create`), finds
    each one's two nearest model descriptors (`cv2.BFMatcher.knnMatch`, `k=2`; Hamming
    distance for ORB, L2 for SIFT) and keeps the match when $d_1 < \rho\, d_2$
    (`ratio` $\rho$, Lowe's test; `ratio=1` keeps every nearest match).

    **Arguments:**
    - `image`: the photograph: a uint8 array `(H, W)` or BGR `(H, W, 3)`, or a path.
    - `model`: a `TexturedModel` whose descriptors the detector writes (32 bytes for
      ORB, 128 float32 for SIFT).
    - `detector`: `"orb"` (default) or `"sift"`.
    - `features`: the most keypoints detected (default 2000).
    - `ratio`: Lowe's ratio $\rho$ in `(0, 1]` (default 0.8).

    **Returns:** `Matches` (zero of them for an image without keypoints).

    **Raises:** `ValueError` naming the argument.
    """
    import cv2

    check_match_options(detector, features, ratio)
    model = check_model(model, detector)
    gray = as_image(image)
    if detector == "orb":
        finder, norm = cv2.ORB.create(nfeatures=int(features)), cv2.NORM_HAMMING
    else:
        finder, norm = cv2.SIFT.create(nfeatures=int(features)), cv2.NORM_L2
    keypoints, descriptors = finder.detectAndCompute(gray, None)
    if descriptors is None or len(keypoints) == 0 or len(model.descriptors) == 0:
        return no_matches()
    train = np.ascontiguousarray(model.descriptors)
    k = 2 if len(train) >= 2 else 1
    pairs = cv2.BFMatcher(norm).knnMatch(descriptors, train, k=k)
    query, index, distance = [], [], []
    for pair in pairs:
        if not pair:
            continue
        best = pair[0]
        if len(pair) == 2 and ratio < 1 and not best.distance < ratio * pair[1].distance:
            continue
        query.append(best.queryIdx)
        index.append(best.trainIdx)
        distance.append(best.distance)
    if not query:
        return no_matches()
    pixels = np.array([keypoints[q].pt for q in query], dtype=np.float64).reshape(-1, 2)
    index = np.asarray(index, dtype=np.int64)
    return Matches(
        object_points=np.asarray(model.points, np.float64)[index],
        image_points=pixels,
        distance=np.asarray(distance, dtype=np.float64),
        model_index=index,
    )
