"""Camera files: the intrinsics `K` and distortion coefficients in OpenCV's YAML/XML
(`cv2.FileStorage`), under the names OpenCV's calibration samples write,
`camera_matrix` and `distortion_coefficients`.

OpenCV is imported inside the functions, not with the module.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import numpy.typing as npt

from ..geometry._validate import as_intrinsics, no_type_check

__all__ = ["open_storage", "read_camera", "write_camera"]

#: Distortion vector lengths OpenCV reads.
_DIST_SIZES = (4, 5, 8, 12, 14)


def _as_path(path: object, name: str = "path") -> Path:
    if not isinstance(path, str | os.PathLike):
        raise ValueError(f"{name} must be a str or a path, got {type(path).__name__}")
    return Path(path)


def open_storage(path: Path, mode: str = "read"):
    """`cv2.FileStorage` on `path` for reading (`mode="read"`) or writing (`"write"`),
    with OpenCV's failures (a missing or malformed file) as a `ValueError` naming the
    path. YAML, XML or JSON by the file's extension; a `.gz` suffix compresses."""
    import cv2

    flag = cv2.FILE_STORAGE_READ if mode == "read" else cv2.FILE_STORAGE_WRITE
    if mode == "read" and not path.is_file():
        raise ValueError(f"path {str(path)!r} is not a file")
    try:
        fs = cv2.FileStorage(str(path), flag)
    except (cv2.error, SystemError) as exc:  # (a parse error comes as either)
        raise ValueError(f"path {str(path)!r} could not be opened by OpenCV: {exc}") from exc
    if not fs.isOpened():
        raise ValueError(f"path {str(path)!r} could not be opened by OpenCV for {mode}")
    return fs


def _matrix(fs, field: str, path: Path) -> np.ndarray | None:
    """The matrix stored under `field` (float64), `None` when the field is absent."""
    node = fs.getNode(field)
    if node.empty() or node.isNone():
        return None
    mat = node.mat()
    if mat is None:
        raise ValueError(f"{field} in {str(path)!r} is not an OpenCV matrix")
    return np.asarray(mat, dtype=np.float64)


@no_type_check
def read_camera(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """The camera of an OpenCV calibration file (YAML, XML or JSON, `.gz` too).

    **Arguments:**
    - `path`: a file with `camera_matrix` (3x3) and, optionally,
      `distortion_coefficients` (4, 5, 8, 12 or 14 numbers, OpenCV's order).

    **Returns:** `(K, dist)`: `K` `(3, 3)` float64 and `dist` `(k,)` float64 (`zeros(5)`
    when the file has no distortion).

    **Raises:** `ValueError` naming the path when it cannot be read, or the field that is
    missing or malformed.
    """
    path = _as_path(path)
    fs = open_storage(path)
    try:
        K = _matrix(fs, "camera_matrix", path)
        dist = _matrix(fs, "distortion_coefficients", path)
    finally:
        fs.release()
    if K is None:
        raise ValueError(f"camera_matrix is missing from {str(path)!r}")
    K = np.asarray(as_intrinsics(K, f"camera_matrix in {str(path)!r}"), np.float64)
    if dist is None:
        return K, np.zeros(5)
    if dist.ndim == 2 and 1 not in dist.shape:
        raise ValueError(
            f"distortion_coefficients in {str(path)!r} must be a vector, got {dist.shape}"
        )
    dist = dist.reshape(-1)
    if dist.size not in _DIST_SIZES:
        raise ValueError(
            f"distortion_coefficients in {str(path)!r} must have 4, 5, 8, 12 or 14 "
            f"elements, got {dist.size}"
        )
    if not np.all(np.isfinite(dist)):
        raise ValueError(f"distortion_coefficients in {str(path)!r} is not finite")
    return K, dist


@no_type_check
def write_camera(
    path: str | os.PathLike,
    camera_matrix: npt.ArrayLike,
    dist_coeffs: npt.ArrayLike | None = None,
) -> None:
    """Write a camera as OpenCV's calibration samples do (`read_camera` reads it back).

    **Arguments:**
    - `path`: the file; its extension picks the format (`.yml`/`.yaml`, `.xml`, `.json`,
      any of them followed by `.gz`).
    - `camera_matrix`: `K` `(3, 3)`.
    - `dist_coeffs`: 4, 5, 8, 12 or 14 coefficients (`None`: `zeros(5)`).

    **Raises:** `ValueError` naming the argument.
    """
    path = _as_path(path)
    K = np.asarray(as_intrinsics(camera_matrix, "camera_matrix"), np.float64)
    if dist_coeffs is None:
        dist = np.zeros(5)
    else:
        try:
            dist = np.asarray(dist_coeffs, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"dist_coeffs could not be read as numbers: {exc}") from exc
        if (dist.ndim == 2 and 1 not in dist.shape) or dist.ndim > 2:
            raise ValueError(f"dist_coeffs must be a vector, got shape {dist.shape}")
        dist = dist.reshape(-1)
        if dist.size not in _DIST_SIZES:
            raise ValueError(f"dist_coeffs must have 4, 5, 8, 12 or 14 elements, got {dist.size}")
        if not np.all(np.isfinite(dist)):
            raise ValueError("dist_coeffs contains NaN or infinite values")
    fs = open_storage(path, "write")
    try:
        fs.write("camera_matrix", K)
        fs.write("distortion_coefficients", dist.reshape(-1, 1))
    finally:
        fs.release()
