"""What the rerun modules share: their colours, `rerun`'s lazy import and the numpy
geometry of drawing.

Every `log_*` function takes the `rerun.RecordingStream` to write to (never the global
one), so recordings of several problems can be made side by side. `rerun` itself is
imported only when a recording is made: `import jaxpose` stays light.

| module | what it logs or makes |
|---|---|
| `_rerun_recording` | the stream: `rerun_recording`, `close_recording`, `serve_web_viewer` |
| `_rerun_layout` | the layouts a recording opens on: `rerun_blueprint`, `pointing_blueprint` |
| `_rerun_scene` | the camera and image, a pose of the model, the observations and rays |
| `_rerun_solution` | a solved problem (`log_solution`), every triplet (`log_triplets`) |
| `_rerun_experiment` | the paper's experiment and Table 1 (`log_experiment`) |
| `_rerun_pointing` | a pointing command and the robot (`log_pointing`) |

Entity paths (world units are the model's, e.g. mm; pixels in the image space):

| path | what |
|---|---|
| `world` | the world frame (z up; the camera frame's axes when the world is the camera) |
| `world/camera` | the camera's pose in the world (`Transform3D`, camera to world) |
| `world/camera/image` | its pinhole (intrinsics, image size) and the image, if any |
| `world/camera/image/observed` | the observed image points (2D) |
| `world/camera/image/recovered`, `.../true` | reprojected points and wireframe (2D) |
| `world/model/recovered`, `world/model/true` | the model's wireframe at those poses (3D) |
| `world/points/...`, `world/rays` | matched vertices (3D) and the observed visual rays |
| `world/triplets/hypothesis`, `world/camera/image/triplets/...` | the current triplet's pose |
| `triplets/status` | one log line per triplet: its status and error |
| `metrics/error_px/<method>` | Eq. 8 error per triplet and method (px) |
| `metrics/pose_error_mm/<method>` | the paper's pose error per triplet and method |
| `summary` | the answer, as a Markdown text document |
| `world/pointing/...`, `world/robot/...` | a pointing command (`log_pointing`) |

Per-triplet data lie on the `triplet` sequence timeline (the triplet's index into
`jaxpose.strategy.triplet_indices`). `rerun_blueprint` lays them out: 3D view and image view
on top, the error series and the log below.
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING, Any

import numpy as np

from ..geometry._camera import project_numpy
from ..solvers._status import Status

if TYPE_CHECKING:  # pragma: no cover
    from ..apps._polyhedron import Polyhedron

__all__ = ["METHOD_COLORS", "METHOD_LABELS", "STATUS_COLORS"]

METHOD_LABELS = {
    "three_point": "3-segment",
    "linear": "linear",
    "nonlinear": "non-linear",
    "mixed": "mixed",
}
METHOD_COLORS = {
    "three_point": (150, 150, 150),
    "linear": (66, 135, 245),
    "nonlinear": (230, 159, 0),
    "mixed": (0, 170, 90),
}
_GREEN, _ORANGE, _RED, _PURPLE, _GREY = (
    (40, 200, 90),
    (245, 160, 30),
    (230, 50, 50),
    (170, 90, 220),
    (130, 130, 130),
)
#: Colour of a hypothesis by its `Status`: accepted green, rejected orange, not converged
#: red, outside the non-linear budget purple, no pose (degenerate triplet) grey.
STATUS_COLORS = {
    Status.OK: _GREEN,
    Status.ACCEPTED_LINEAR: _GREEN,
    Status.ACCEPTED_AFTER_NONLINEAR: _GREEN,
    Status.REJECTED: _ORANGE,
    Status.NONLINEAR_NOT_CONVERGED: _RED,
    Status.LINEAR_NOT_CONVERGED: _RED,
    Status.NOT_ATTEMPTED: _PURPLE,
}
_NO_POSE = (
    Status.NO_SOLUTION,
    Status.BEHIND_CAMERA,
    Status.DEGENERATE_IMAGE,
    Status.DEGENERATE_MODEL,
    Status.TOO_FEW_POINTS,
    Status.NOT_FINITE,
)
_OBSERVED = (230, 50, 50)
_RECOVERED = (40, 200, 90)
_TRUE = (80, 140, 255)


def _rr():
    import rerun as rr

    return rr


def _summary(lines: list[str]) -> Any:
    """The Markdown text document of `lines`, for the `summary` entity."""
    rr = _rr()
    return rr.TextDocument("\n".join(lines), media_type=rr.MediaType.MARKDOWN)


# --------------------------------------------------------------------------- geometry (numpy)


def _np(x) -> np.ndarray:
    return np.asarray(x, dtype=np.float64)


@functools.cache
def _jitted(fn):
    import jax

    return jax.jit(fn)


def _f64(fn, *args):
    """`fn(*args)` for a jaxpose function, compiled once, in float64, as numpy."""
    import jax

    with jax.enable_x64(True):
        out = _jitted(fn)(*(np.asarray(a, np.float64) for a in args))
        return jax.tree.map(np.asarray, out)


def _transform(R, t, points) -> np.ndarray:
    return _np(points) @ _np(R).T + _np(t).reshape(1, 3)


def _project(camera, world) -> tuple[np.ndarray, np.ndarray]:
    """Pixels and a front-of-camera flag of world points (numpy, for drawing only).

    In front: a depth (the signed distance of `project_numpy`) above `1e-9` times the
    largest homogeneous pixel coordinate, at least 1: points on the focal plane or behind
    the camera are not drawn."""
    pixels, depth = project_numpy(camera, world)
    scale = np.abs(pixels * depth[:, None]).max(axis=1)
    return pixels, depth > 1e-9 * np.maximum(scale, 1.0)


def _camera_parts(camera, K=None, R_wc=None, t_wc=None):
    """`(K, R_wc, t_wc, centre)` of a camera: given, or decomposed from `C` (float64)."""
    if K is not None and R_wc is not None and t_wc is not None:
        K, R_wc, t_wc = _np(K), _np(R_wc), _np(t_wc).reshape(3)
        return K, R_wc, t_wc, -R_wc.T @ t_wc
    from ..geometry._camera import decompose_camera

    return _f64(decompose_camera, camera)


def _edges(polyhedron: Polyhedron | None, model_points) -> np.ndarray:
    """Edge list `(E, 2)` over the rows of `model_points`, or `(0, 2)`."""
    if polyhedron is None:
        return np.zeros((0, 2), dtype=np.int64)
    return np.asarray(polyhedron.edges, dtype=np.int64).reshape(-1, 2)


def _strips3d(world, edges) -> np.ndarray:
    """Segments `(E, 2, 3)` (one array: rerun's fast path)."""
    return world[edges]


def _strips2d(camera, world, edges) -> np.ndarray:
    """Projected segments `(E', 2, 2)`, those with both ends in front of the camera."""
    uv, front = _project(camera, world)
    return uv[edges[front[edges].all(axis=1)]]


def _hypothesis_ok(status: int | np.integer) -> bool:
    return int(status) not in [int(s) for s in _NO_POSE]


def _status_color(status: int | np.integer) -> tuple[int, int, int]:
    return STATUS_COLORS.get(Status(int(status)), _GREY)


def _world_is_camera(R_wc, t_wc) -> bool:
    return bool(np.allclose(R_wc, np.eye(3)) and np.allclose(t_wc, 0))


def _world_up(R_wc, t_wc) -> np.ndarray:
    """The world's up direction as drawn: z, or -y (OpenCV's camera axes) when the world
    is the camera frame."""
    return np.array([0.0, -1.0, 0.0]) if _world_is_camera(R_wc, t_wc) else np.array([0.0, 0, 1])
