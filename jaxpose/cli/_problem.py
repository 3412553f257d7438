"""Pose problem files (for `jaxpose solve`): the `Problem` type and the formats, JSON and
OpenCV YAML, that `_problem_read` reads and `_problem_write` writes.

A problem is a camera, model points and the image points matched to them. It comes in
one file, or in up to three (`--model`, `--image`, `--camera`), each in one of these
formats, chosen by the file's suffix:

**JSON** (`.json`). One object; every key but the points is optional:

```json
{
  "camera": {"K": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]],
             "dist": [k1, k2, p1, p2, k3],
             "R": [[...], [...], [...]], "t": [tx, ty, tz]},
  "image_size": [width, height],
  "model_points": [[x, y, z], ...],
  "image_points": [[u, v], ...],
  "mask": [true, false, ...]
}
```

- `camera`: either `K` (intrinsics), with optional OpenCV distortion `dist` and the
  world-to-camera motion `x_cam = R p + t` (`R` as a 3x3 matrix or `rvec` as a rotation
  vector; default: the world frame is the camera frame, OpenCV's convention), or `C`, a
  3x4 projection matrix calibrated in the world frame (no distortion).
- `model_points`: `(n, 3)`; or, instead, `polyhedron` (`{"vertices": (V, 3), "edges":
  (E, 2), "faces": [[...], ...]}`, faces optional) with `matched_vertices` (`n` vertex
  indices matched to the image points). A polyhedron also gives the recording its
  wireframe.
- `image_points`: `(n, 2)` pixels as observed (distortion is removed with `dist`).
- `mask`: optional `(n,)` booleans, which matches to use.
- `true_pose`: optional ground truth `{"R" or "rvec", "t"}` (model to world), drawn in
  the recording beside the recovered pose.
- `image_size`: optional `[width, height]` in pixels, for the recording's camera.

A `--model` file may also be a bare `(n, 3)` list, an `--image` file a bare `(n, 2)`
list, and a `--camera` file the `camera` object itself. Unknown keys are an error (a
misspelt key would otherwise be ignored silently).

**OpenCV YAML** (`.yaml`, `.yml`, also `.xml`), read with `cv2.FileStorage`, as OpenCV's
calibration tools write it: `camera_matrix` (3x3), `distortion_coefficients`,
`image_width`, `image_height`, `object_points` (n x 3), `image_points` (n x 2), and
optionally `projection_matrix` (3x4, instead of `camera_matrix`), `camera_rotation`
(3x3, or a rotation vector) and `camera_translation` (world to camera), `mask`,
`model_vertices` (V x 3) with `model_edges` (E x 2) and `matched_vertices`. Other nodes
are ignored, so a calibration file can serve as the `--camera` file directly.

**Text** (`.csv`, `.txt`): a `--model` or `--image` file may be a plain table of numbers
(comma- or whitespace-separated, `#` comments), one point per row.

Every reader raises `ProblemError` (a `ValueError`) with a one-line message naming the
file and the field at fault.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import NoReturn

import numpy as np

from ..apps._polyhedron import Polyhedron

__all__ = ["Problem", "ProblemError"]

JSON_SUFFIXES = (".json",)
YAML_SUFFIXES = (".yaml", ".yml", ".xml")
TEXT_SUFFIXES = (".csv", ".txt")


class ProblemError(ValueError):
    """A problem file that cannot be read: the message is one line naming the file."""


@dataclasses.dataclass(frozen=True)
class Problem:
    """One pose problem read from files, ready for `jaxpose.solve`.

    **Fields:**
    - `camera`: the 3x4 projection matrix `C` in the world frame (`K [R | t]`).
    - `model_points`: `(n, 3)`; `image_points`: `(n, 2)`, distortion removed;
      `observed_points`: `(n, 2)` as read (with distortion).
    - `mask`: `(n,)` bool or None (all matches).
    - `K`, `dist`: intrinsics and distortion when the camera was given as `K` (else
      `None`); `R_wc`, `t_wc`: its world-to-camera motion.
    - `image_size`: `(width, height)` or None.
    - `polyhedron`: the model with its edges (or None); `true_pose`: `(R, t)` or None.
    - `sources`: the files read.
    """

    camera: np.ndarray
    model_points: np.ndarray
    image_points: np.ndarray
    observed_points: np.ndarray
    mask: np.ndarray | None = None
    K: np.ndarray | None = None
    dist: np.ndarray | None = None
    R_wc: np.ndarray | None = None
    t_wc: np.ndarray | None = None
    image_size: tuple[int, int] | None = None
    polyhedron: Polyhedron | None = None
    true_pose: tuple[np.ndarray, np.ndarray] | None = None
    sources: tuple[str, ...] = ()


def _fail(path: Path, message: str) -> NoReturn:
    """Raise `ProblemError` with `message` about the file `path`."""
    raise ProblemError(f"{path}: {message}")


def _format(path: Path) -> str:
    """The format of the file `path` by its suffix: `"json"`, `"yaml"` or `"text"`."""
    suffix = path.suffix.lower()
    if suffix in JSON_SUFFIXES:
        return "json"
    if suffix in YAML_SUFFIXES:
        return "yaml"
    if suffix in TEXT_SUFFIXES:
        return "text"
    _fail(
        path,
        f"unknown format {suffix or '(no suffix)'!r}: expected "
        + ", ".join(JSON_SUFFIXES + YAML_SUFFIXES + TEXT_SUFFIXES),
    )
