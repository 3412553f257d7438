"""The embedded default bench (a replica of the paper's Section 4 set-up) and random scenes.

The paper's object is a polyhedron with 14 faces, 36 edges and 24 vertices measuring
155 x 143 x 20 mm: a 12-sided prism. We model it as a cross-shaped plate (a "plus" sign
whose arms have different widths and offsets, so that it has no symmetry), about 2 m
from a 25 mm camera digitised at 768 x 576 pixels, with 16 of its vertices visible and
matched. Image points carry seeded Gaussian noise.

Everything here is plain numpy: it builds data, it is not traced.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..geometry._camera import project_numpy
from ._polyhedron import Polyhedron, prism, seen_vertices

__all__ = [
    "DEFAULT_NOISE",
    "Bench",
    "Scene",
    "cross_prism",
    "default_bench",
    "random_rotation",
    "random_rotations",
    "random_scene",
]

# Outline of the cross in the plate's plane (mm), counter-clockwise, 12 corners.
# Width 155 mm along x (-80..75), height 143 mm along y (-70..73).
# Vertical arm: x in [-25, 22]; horizontal arm: y in [-20, 31].
_CROSS_OUTLINE = np.array(
    [
        [-25.0, -70.0],
        [22.0, -70.0],
        [22.0, -20.0],
        [75.0, -20.0],
        [75.0, 31.0],
        [22.0, 31.0],
        [22.0, 73.0],
        [-25.0, 73.0],
        [-25.0, 31.0],
        [-80.0, 31.0],
        [-80.0, -20.0],
        [-25.0, -20.0],
    ]
)
_THICKNESS = 20.0
DEFAULT_NOISE = 0.8  # px: the optimum pose error then averages 0.58 mm over seeds (paper: 0.578)

# 25 mm lens, 756 x 581 sensor cells digitised at 768 x 576: focal length about 3000 px.
_IMAGE_SIZE = (768, 576)
_K = np.array([[3000.0, 0.0, 384.0], [0.0, 3000.0, 288.0], [0.0, 0.0, 1.0]])


def cross_prism() -> Polyhedron:
    """The bench object: a 12-gon cross-shaped prism, 155 x 143 x 20 mm, centred at the
    origin, 24 vertices (0-11 on the top face z = +10, 12-23 on the bottom z = -10),
    36 edges and 14 faces."""
    return prism("cross_prism", _CROSS_OUTLINE, _THICKNESS)


@dataclasses.dataclass(frozen=True)
class Scene:
    """One pose problem with its ground truth.

    `camera` is the 3x4 matrix `C` (world frame); the true pose maps model to world,
    `p = R m + t`; `image_points` are the noisy observations of `model_points`, and
    `clean_points` the noise-free projections.
    """

    camera: np.ndarray
    model_points: np.ndarray
    image_points: np.ndarray
    clean_points: np.ndarray
    R: np.ndarray
    t: np.ndarray
    noise: float


@dataclasses.dataclass(frozen=True)
class Bench(Scene):
    """The default bench: a `Scene` plus the object model, which vertices are matched,
    the intrinsics, the world-to-camera pose and the image size."""

    model: Polyhedron = None  # type: ignore[assignment]
    visible: np.ndarray = None  # type: ignore[assignment]
    K: np.ndarray = None  # type: ignore[assignment]
    R_wc: np.ndarray = None  # type: ignore[assignment]
    t_wc: np.ndarray = None  # type: ignore[assignment]
    image_size: tuple[int, int] = _IMAGE_SIZE
    seed: int = 0


def _rot(axis: str, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    if axis == "x":
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    if axis == "y":
        return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _look_at(centre: np.ndarray, target: np.ndarray, up: np.ndarray) -> np.ndarray:
    """World-to-camera rotation of a camera at `centre` looking at `target` (OpenCV axes:
    x right, y down, z forward)."""
    z = target - centre
    z = z / np.linalg.norm(z)
    x = np.cross(z, up)
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    return np.stack([x, y, z])


def default_bench(seed: int = 0, noise: float = DEFAULT_NOISE) -> Bench:
    """The paper's bench, replicated: the cross prism about 2 m in front of a 25 mm camera
    (f = 3000 px, 768 x 576), 16 matched vertices, Gaussian pixel noise of `noise` px
    (seeded by `seed`).

    The world frame is the robot's (z up); the camera stands at (0, -1.55, 1.25) m looking
    down at the table origin, where the plate lies tilted by a few degrees. Units: mm.
    """
    model = cross_prism()
    # Object pose in the world: lying on the table, turned and tilted a little.
    R = _rot("z", math.radians(27.0)) @ _rot("y", math.radians(8.0)) @ _rot("x", math.radians(-6.0))
    t = np.array([40.0, 25.0, 10.0])
    centre = np.array([0.0, -1550.0, 1250.0])
    R_wc = _look_at(centre, np.array([0.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]))
    t_wc = -R_wc @ centre
    camera = _K @ np.column_stack([R_wc, t_wc])

    # Matched: the 12 top vertices and the 4 seen bottom vertices nearest the camera.
    seen = seen_vertices(model, R, t, centre)
    k = len(_CROSS_OUTLINE)
    bottom = seen[seen >= k]
    distance = np.linalg.norm(model.vertices[bottom] @ R.T + t - centre, axis=1)
    visible = np.concatenate([np.arange(k), np.sort(bottom[np.argsort(distance)[:4]])])
    model_points = model.vertices[visible]
    clean, _ = project_numpy(camera, model_points @ R.T + t)
    rng = np.random.default_rng(seed)
    image_points = clean + rng.normal(scale=noise, size=clean.shape)
    return Bench(
        camera=camera,
        model_points=model_points,
        image_points=image_points,
        clean_points=clean,
        R=R,
        t=t,
        noise=float(noise),
        model=model,
        visible=visible,
        K=_K.copy(),
        R_wc=R_wc,
        t_wc=t_wc,
        seed=int(seed),
    )


def random_rotations(rng: np.random.Generator, n: int) -> np.ndarray:
    """`n` rotation matrices `(n, 3, 3)` drawn uniformly (normalised Gaussian quaternions)."""
    q = rng.normal(size=(n, 4))
    w, x, y, z = (q / np.linalg.norm(q, axis=1, keepdims=True)).T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A rotation matrix drawn uniformly (from a normalised Gaussian quaternion)."""
    return random_rotations(rng, 1)[0]


def random_scene(
    rng: np.random.Generator,
    n: int,
    *,
    noise: float = 0.0,
    kind: str = "ordinary",
    focal: float = 800.0,
    world_camera: bool = True,
) -> Scene:
    """A random pose problem in the standard synthetic PnP protocol (RPnP/OPnP/MLPnP).

    Camera-frame points are drawn uniform in `[-2,2]x[-2,2]x[4,8]` (`kind="ordinary"`),
    `[1,2]x[1,2]x[4,8]` (`"quasi_singular"`) or on a plane `[-2,2]^2` at depth 4-8
    (`"planar"`, the plane randomly tilted by up to 30 degrees); `f = focal`, principal
    point (320, 240). The model frame is a random rigid motion of the camera frame.
    When `world_camera`, the camera is also placed at a random world pose (so `C` is a
    general 3x4 matrix); otherwise `C = K [I | 0]` (OpenCV's convention).
    """
    if kind == "ordinary":
        pc = rng.uniform([-2, -2, 4], [2, 2, 8], size=(n, 3))
    elif kind == "quasi_singular":
        pc = rng.uniform([1, 1, 4], [2, 2, 8], size=(n, 3))
    elif kind == "planar":
        xy = rng.uniform(-2, 2, size=(n, 2))
        tilt = _rot("x", rng.uniform(-0.5, 0.5)) @ _rot("y", rng.uniform(-0.5, 0.5))
        pc = np.column_stack([xy, np.zeros(n)]) @ tilt.T + np.array([0, 0, rng.uniform(4, 8)])
    else:
        raise ValueError(f"kind must be 'ordinary', 'quasi_singular' or 'planar', got {kind!r}")
    K = np.array([[focal, 0.0, 320.0], [0.0, focal, 240.0], [0.0, 0.0, 1.0]])
    if world_camera:
        R_wc = random_rotation(rng)
        t_wc = rng.normal(scale=2.0, size=3)
    else:
        R_wc, t_wc = np.eye(3), np.zeros(3)
    camera = K @ np.column_stack([R_wc, t_wc])
    world = (pc - t_wc) @ R_wc  # camera frame -> world frame
    # The object's model frame: a random rigid motion of the world points.
    R = random_rotation(rng)
    t = world.mean(axis=0) + rng.normal(scale=0.1, size=3)
    model_points = (world - t) @ R  # so that world = R m + t
    clean, _ = project_numpy(camera, world)
    image = clean + rng.normal(scale=noise, size=clean.shape) if noise > 0 else clean.copy()
    return Scene(
        camera=camera,
        model_points=model_points,
        image_points=image,
        clean_points=clean,
        R=R,
        t=t,
        noise=float(noise),
    )
