"""Rendered test scenes for recognition: a model of a database, flat-shaded at a random
pose over a textured, cluttered background, partly hidden by an occluder, blurred and
noisy, with its ground truth (camera, pose, the true pixels of its vertices and which of
them the image shows).

Pixels follow OpenCV's convention (integer coordinates at pixel centres): a step edge
that `camera` projects at `x = 9.5` lies between columns 9 and 10 of the image.
Plain numpy and OpenCV: not traced.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..apps._bench import random_rotation
from ..apps._polyhedron import Polyhedron, seen_vertices
from ..geometry._camera import project_numpy
from ..geometry._validate import no_type_check
from ._overlay import render

__all__ = ["RenderedScene", "rendered_scene"]

_MARGIN = 12  # px kept free around the model's projection


class RenderedScene(NamedTuple):
    """A rendered scene and its ground truth."""

    image: np.ndarray
    """uint8 `(h, w, 3)` BGR."""
    camera: np.ndarray
    """`(3, 4)` float64: `C = K [I | 0]` (the world frame is the camera's), as
    `jaxpose.apps.Bench.camera`."""
    model: str | None
    """The model's name in the database, or None for a scene of clutter only."""
    R: np.ndarray | None
    """`(3, 3)` true rotation, model to world (None without a model)."""
    t: np.ndarray | None
    """`(3,)` true translation, model to world (None without a model)."""
    pixels: np.ndarray
    """`(V, 2)` float64: true projections of the model's vertices (`(0, 2)` without)."""
    visible: np.ndarray
    """`(V,)` bool: vertices neither hidden by the model itself nor by the occluder."""


# --------------------------------------------------------------------------- validation


def _check_range(value, name: str) -> tuple[float, float]:
    try:
        lo, hi = (float(x) for x in value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a pair (low, high), got {value!r}") from exc
    if not (0 <= lo <= hi < 1):
        raise ValueError(f"{name} must satisfy 0 <= low <= high < 1, got {value!r}")
    return lo, hi


def _check_nonnegative(value, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise ValueError(f"{name} must be a number, got {value!r}")
    if not (math.isfinite(float(value)) and value >= 0):
        raise ValueError(f"{name} must be finite and >= 0, got {value!r}")
    return float(value)


def _check_int(value, name: str, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < low:
        raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
    return int(value)


# --------------------------------------------------------------------------- drawing


def _background(rng: np.random.Generator, width: int, height: int) -> np.ndarray:
    """A dim, tinted background: a linear gradient plus smooth texture, float BGR."""
    import cv2

    level = rng.uniform(20, 85) + rng.uniform(-12, 12, size=3)
    u, v = np.meshgrid(np.linspace(-1, 1, width), np.linspace(-1, 1, height))
    theta = rng.uniform(0, 2 * np.pi)
    ramp = rng.uniform(0, 25) * (np.cos(theta) * u + np.sin(theta) * v)
    coarse = rng.normal(size=(max(height // 40, 2), max(width // 40, 2))).astype(np.float32)
    texture = cv2.resize(coarse, (width, height), interpolation=cv2.INTER_CUBIC)
    grey = ramp + rng.uniform(3, 10) * texture
    return level[None, None, :] + grey[..., None]


def _random_color(rng: np.random.Generator) -> tuple[float, float, float]:
    b, g, r = rng.uniform(0, 255, size=3)
    return float(b), float(g), float(r)


def _clutter(rng: np.random.Generator, image: np.ndarray, count: int) -> None:
    """`count` random line segments, then a few rectangles and polylines, drawn in place."""
    import cv2

    h, w = image.shape[:2]
    for _ in range(count):
        a = rng.uniform([0, 0], [w, h])
        angle = rng.uniform(0, 2 * np.pi)
        b = a + rng.uniform(20, 200) * np.array([np.cos(angle), np.sin(angle)])
        cv2.line(
            image,
            (int(a[0] * 16), int(a[1] * 16)),
            (int(b[0] * 16), int(b[1] * 16)),
            _random_color(rng),
            int(rng.integers(1, 4)),
            cv2.LINE_AA,
            4,
        )
    for _ in range(int(rng.integers(1, 4))):
        centre = rng.uniform([0, 0], [w, h])
        size = rng.uniform(15, 90, size=2)
        box = cv2.boxPoints(((centre[0], centre[1]), (size[0], size[1]), rng.uniform(0, 180)))
        fill = -1 if rng.uniform() < 0.5 else int(rng.integers(1, 3))
        pts = np.round(box * 16).astype(np.int32)
        if fill < 0:
            cv2.fillPoly(image, [pts], _random_color(rng), cv2.LINE_AA, 4)
        else:
            cv2.polylines(image, [pts], True, _random_color(rng), fill, cv2.LINE_AA, 4)
    for _ in range(int(rng.integers(1, 3))):
        start = rng.uniform([0, 0], [w, h])
        steps = rng.normal(scale=40, size=(int(rng.integers(2, 5)), 2))
        pts = np.round(np.vstack([start, start + np.cumsum(steps, axis=0)]) * 16).astype(np.int32)
        cv2.polylines(image, [pts], False, _random_color(rng), 2, cv2.LINE_AA, 4)


def _place(
    rng: np.random.Generator, model: Polyhedron, K: np.ndarray, width: int, height: int
) -> tuple[np.ndarray, np.ndarray]:
    """A random pose `(R, t)` (camera frame) showing the whole model in frame, 150-350 px
    across, not seen edge-on (its projected vertices spread in both directions)."""
    vertices = np.asarray(model.vertices, dtype=np.float64)
    vertices = vertices - vertices.mean(axis=0)
    f = K[0, 0]
    largest = min(350.0, 0.9 * min(width, height) - 2 * _MARGIN)
    R, t = np.eye(3), np.array([0.0, 0.0, 1.0])
    for _ in range(200):
        R = random_rotation(rng)
        size = rng.uniform(min(150.0, largest), largest)
        rotated = vertices @ R.T
        extent = float(np.max(np.ptp(rotated[:, :2], axis=0)))
        z = f * extent / size + float(np.max(-rotated[:, 2])) * 0.5
        t = np.array([0.0, 0.0, z])
        uv, depth = project_numpy(K @ np.eye(3, 4), rotated + t)
        if np.any(depth <= 0):
            continue
        spread = np.linalg.svd(uv - uv.mean(axis=0), compute_uv=False)
        if spread[1] < 0.4 * spread[0]:
            continue
        lo, hi = uv.min(axis=0), uv.max(axis=0)
        room_lo = _MARGIN - lo
        room_hi = np.array([width - 1 - _MARGIN, height - 1 - _MARGIN]) - hi
        if np.any(room_lo > room_hi):
            continue
        shift = rng.uniform(room_lo, room_hi)
        # Move the model in its depth plane so that its projection shifts by `shift`.
        t = t + np.append(shift * z / f, 0.0)
        uv, _ = project_numpy(K @ np.eye(3, 4), rotated + t)
        inside = (uv >= _MARGIN - 2) & (uv <= np.array([width, height]) - 1 - _MARGIN + 2)
        if np.all(inside):
            break
    centre = np.asarray(model.vertices, dtype=np.float64).mean(axis=0)
    return R, t - R @ centre


def _occluder(
    rng: np.random.Generator, silhouette: np.ndarray, fraction: float
) -> np.ndarray | None:
    """A random convex polygon (16x fixed point, for `cv2.fillPoly` with shift 4) covering
    about `fraction` of the silhouette, or None for none."""
    import cv2

    area = int(np.count_nonzero(silhouette))
    if fraction <= 0 or area == 0:
        return None
    rows, cols = np.nonzero(silhouette)
    k = int(rng.integers(len(rows)))
    h, w = silhouette.shape
    # Centre outside the silhouette's middle: a silhouette pixel pushed away from the mean.
    mean = np.array([cols.mean(), rows.mean()])
    centre = np.array([cols[k], rows[k]], dtype=np.float64)
    centre = centre + 0.5 * (centre - mean)
    corners = int(rng.integers(4, 7))
    angles = np.sort(rng.uniform(0, 2 * np.pi, size=corners))
    radii = rng.uniform(0.6, 1.0, size=corners)
    unit = np.column_stack([np.cos(angles), np.sin(angles)]) * radii[:, None]

    def polygon(r):
        return np.round((centre + r * unit) * 16).astype(np.int32)

    def covered(r):
        mask = np.zeros((h, w), np.uint8)
        cv2.fillPoly(mask, [polygon(r)], 1, cv2.LINE_8, 4)
        return np.count_nonzero(mask & silhouette) / area

    lo, hi = 0.0, float(np.hypot(h, w))
    for _ in range(24):
        mid = (lo + hi) / 2
        if covered(mid) < fraction:
            lo = mid
        else:
            hi = mid
    return cv2.convexHull(polygon(hi))


# --------------------------------------------------------------------------- scenes


@no_type_check
def rendered_scene(
    seed: int,
    database: dict[str, Polyhedron],
    *,
    model: str | None = "cross_prism",
    occlusion: tuple[float, float] = (0.0, 0.3),
    clutter: int = 12,
    noise: float = 2.0,
    blur: float = 1.0,
    image_size: tuple[int, int] = (640, 480),
    focal: float = 800.0,
) -> RenderedScene:
    """A model of `database` rendered (`jaxpose.viz.render`, flat-shaded) at a random pose
    over clutter, with its ground truth. Deterministic given `seed`.

    The camera is `K [I | 0]`, focal length `focal` px, principal point at the image's
    centre. The model is drawn uniformly rotated, 150-350 px across, wholly in frame and
    not seen edge-on, in a random light colour; the background is a dim tinted gradient
    with smooth texture, `clutter` random line segments and a few random rectangles and
    polylines. A random convex polygon in a random flat colour hides a fraction of the
    model's silhouette drawn uniformly in `occlusion`. Last, Gaussian blur of `blur` px
    (standard deviation; 0 for none) and Gaussian noise of `noise` grey levels.

    **Arguments:**
    - `seed`: integer >= 0.
    - `database`: model name -> `Polyhedron` (e.g. `jaxpose.apps.model_database()`).
    - `model`: the name of the model to show, or None for clutter only.
    - `occlusion`: `(low, high)`, the range of the hidden fraction, `0 <= low <= high < 1`.
    - `clutter`: number of random segments; `noise`, `blur` as above.
    - `image_size`: `(width, height)`, each at least 64.

    **Returns:** `RenderedScene`; `visible` marks the vertices on a face turned towards
    the camera, not behind another face, and at least 3 px clear of the occluder.

    **Raises:** `ValueError` naming the argument for a bad argument.
    """
    import cv2

    seed = _check_int(seed, "seed", 0)
    if not isinstance(database, dict) or not all(
        isinstance(m, Polyhedron) for m in database.values()
    ):
        raise ValueError("database must be a dict of name -> Polyhedron")
    if model is not None and model not in database:
        raise ValueError(f"model must be None or a name in database, got {model!r}")
    low, high = _check_range(occlusion, "occlusion")
    clutter = _check_int(clutter, "clutter", 0)
    noise = _check_nonnegative(noise, "noise")
    blur = _check_nonnegative(blur, "blur")
    focal = _check_nonnegative(focal, "focal")
    if focal == 0:
        raise ValueError("focal must be > 0")
    try:
        width, height = (int(x) for x in image_size)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"image_size must be (width, height), got {image_size!r}") from exc
    if width < 64 or height < 64:
        raise ValueError(f"image_size must be at least (64, 64), got {image_size!r}")

    rng = np.random.default_rng(seed)
    K = np.array([[focal, 0, (width - 1) / 2], [0, focal, (height - 1) / 2], [0, 0, 1]])
    camera = K @ np.eye(3, 4)
    canvas = np.clip(_background(rng, width, height), 0, 255).astype(np.uint8)
    _clutter(rng, canvas, clutter)
    if model is None:
        image = canvas
        scene = RenderedScene(image, camera, None, None, None, np.zeros((0, 2)), np.zeros(0, bool))
    else:
        poly = database[model]
        R, t = _place(rng, poly, K, width, height)
        color = tuple(float(x) for x in rng.uniform(160, 250, size=3))
        pixels, _ = project_numpy(camera, np.asarray(poly.vertices, np.float64) @ R.T + t)
        # Render only the model's bounding box. `render` puts pixel centres at
        # half-integers: shift by half a pixel more so that the image follows OpenCV's
        # convention for `camera`.
        x0, y0 = np.maximum(np.floor(pixels.min(axis=0)).astype(int) - 4, 0)
        x1, y1 = np.minimum(np.ceil(pixels.max(axis=0)).astype(int) + 5, [width, height])
        move = np.array([[1.0, 0, 0.5 - x0], [0, 1.0, 0.5 - y0], [0, 0, 1.0]])
        size = (int(x1 - x0), int(y1 - y0))
        dark = render(move @ camera, poly, (R, t), size, color=color, background=(0, 0, 0))
        light = render(move @ camera, poly, (R, t), size, color=color, background=(255, 255, 255))
        # The renderer is linear in the background: composite over the canvas exactly.
        behind = np.ones((height, width, 3))
        behind[y0:y1, x0:x1] = (light.astype(np.float64) - dark) / 255
        front = np.zeros((height, width, 3))
        front[y0:y1, x0:x1] = dark
        image = np.clip(np.round(front + behind * canvas), 0, 255).astype(np.uint8)
        silhouette = (np.mean(behind, axis=2) < 0.5).astype(np.uint8)
        fraction = rng.uniform(low, high) if high > 0 else 0.0
        polygon = _occluder(rng, silhouette, fraction)
        hidden = np.zeros((height, width), np.uint8)
        if polygon is not None:
            cv2.fillPoly(image, [polygon], _random_color(rng), cv2.LINE_AA, 4)
            cv2.fillPoly(hidden, [polygon], 1, cv2.LINE_8, 4)
            hidden = cv2.dilate(hidden, np.ones((7, 7), np.uint8))
        visible = np.zeros(len(pixels), dtype=bool)
        visible[seen_vertices(poly, R, t, np.zeros(3))] = True
        px = np.clip(np.round(pixels).astype(np.int64), 0, [width - 1, height - 1])
        visible &= hidden[px[:, 1], px[:, 0]] == 0
        scene = RenderedScene(image, camera, model, R, t, pixels, visible)
    image = scene.image.astype(np.float64)
    if blur > 0:
        image = cv2.GaussianBlur(image, (0, 0), blur)
    if noise > 0:
        image = image + rng.normal(scale=noise, size=image.shape)
    return scene._replace(image=np.clip(np.round(image), 0, 255).astype(np.uint8))
