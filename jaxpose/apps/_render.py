"""A small software renderer for test sequences with known poses (the ground truth a
tracker is tested on, issue #32): a polyhedral model drawn at a pose into a grey image
with OpenCV, and smooth trajectories of poses.

Drawing. The faces turned towards the camera are filled far to near (the painter's
algorithm: exact for a convex model, approximate for others) at `supersample` times the
resolution, with sub-pixel vertex positions (each polygon inset by half a fine pixel,
which OpenCV's fill adds back), then averaged down by blocks (area anti-aliasing: an
edge's grey level across it follows the pixel area it covers; an edge lands within
`1 / (2 supersample)` pixel of its projection, unbiased). A
face is flat-shaded (Lambert's law under a directional light, or a grey level given per
face) or textured: a grey texture image laid on the face's plane and tiled, warped
into the image by the plane's homography. Distortion (OpenCV's model) is applied to the
finished image by a remap. Then, in order: a lighting change (gain and offset), an
occluding rectangle, a Gaussian blur, Gaussian noise; the result is clipped to uint8.

Camera frame as in `jaxpose.apps._visibility`: `x = R m + t`, pixels through `K`.
Plain numpy and OpenCV, not traced.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence

import numpy as np

from ..geometry._validate import no_type_check
from ._polyhedron import Polyhedron
from ._visibility import MeshGeometry, _check_pose, mesh_geometry, project

__all__ = ["face_textures", "noise_texture", "render", "render_sequence", "smooth_trajectory"]


def _rodrigues(w: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.Rodrigues(np.asarray(w, np.float64).reshape(3, 1))[0]


@no_type_check
def noise_texture(size: int = 256, *, feature: float = 4.0, seed: int = 0) -> np.ndarray:
    """A grey texture with corners everywhere (for keypoint tracking): uniform noise
    smoothed over `feature` pixels and stretched to 0..255, `(size, size)` uint8,
    seamless when tiled.

    **Raises:** `ValueError` naming `size` or `feature`.
    """
    import cv2

    if isinstance(size, bool) or not isinstance(size, int) or size < 8:
        raise ValueError(f"size must be an int >= 8, got {size!r}")
    if isinstance(feature, bool) or not isinstance(feature, int | float) or not feature > 0:
        raise ValueError(f"feature must be a number > 0, got {feature!r}")
    noise = np.random.default_rng(seed).uniform(0, 1, (size, size)).astype(np.float32)
    tiled = cv2.GaussianBlur(np.tile(noise, (3, 3)), (0, 0), float(feature))
    smooth = tiled[size : 2 * size, size : 2 * size].copy()  # seamless when tiled
    smooth -= smooth.min()
    return np.clip(255 * smooth / max(float(smooth.max()), 1e-12), 0, 255).astype(np.uint8)


def _shades(geo: MeshGeometry, R, shades, light, ambient) -> np.ndarray:
    if shades is not None:
        shades = np.asarray(shades, dtype=np.float64).reshape(-1)
        if shades.shape != (len(geo.normals),) or not np.all(np.isfinite(shades)):
            raise ValueError(f"shades must give one finite grey level per face, {len(shades)}")
        return shades
    light = np.asarray(light, dtype=np.float64).reshape(-1)
    if light.shape != (3,) or not np.all(np.isfinite(light)) or not np.any(light):
        raise ValueError("light must be a nonzero finite 3-vector")
    light = light / np.linalg.norm(light)
    lambert = np.maximum(geo.normals @ R.T @ light, 0.0)
    return 255.0 * (ambient + (1.0 - ambient) * lambert)


def _inset(poly: np.ndarray, d: float) -> np.ndarray:
    """Polygon `(k, 2)` with each side moved `d` inward (OpenCV's fill takes in the pixels
    whose centres lie within half a pixel outside a polygon: insetting by half a
    pixel makes the area drawn unbiased). Corners sharper than about 30 degrees move
    at most `4 d`."""
    area = np.sum(poly[:, 0] * np.roll(poly[:, 1], -1) - np.roll(poly[:, 0], -1) * poly[:, 1])
    side = np.roll(poly, -1, axis=0) - poly
    length = np.linalg.norm(side, axis=1, keepdims=True)
    side = side / np.maximum(length, 1e-12)
    inward = np.column_stack([-side[:, 1], side[:, 0]]) * (1.0 if area > 0 else -1.0)
    before = np.roll(inward, 1, axis=0)  # the side ending at each corner
    cos = np.clip((inward * before).sum(axis=1, keepdims=True), -0.875, 1.0)
    return poly + d * (inward + before) / (1.0 + cos)


def _plane(geo: MeshGeometry, f, R, t, scale: float) -> np.ndarray:
    """`(3, 3)`: texture pixel `(i, j, 1)` of face `f` to its camera-frame point: the
    face's plane point `c + scale (i a0 + j a1)`, `a0, a1` its in-plane axes and `c` the
    corner of its bounding box in them (so a texture covers the face from its pixel
    `(0, 0)`)."""
    a0, a1 = geo.axes[f]
    low = geo.polygons[f].min(axis=0)
    corner = geo.origins[f] + low[0] * a0 + low[1] * a1
    return np.column_stack([R @ a0, R @ a1, R @ corner + t]) @ np.diag([scale, scale, 1.0])


def _paint_texture(canvas, poly, texture, homography, shade, shift) -> None:
    """Fill polygon `poly` (fixed point, `shift` bits) of `canvas` with `texture` warped
    by `homography` (texture pixels to canvas pixels) times `shade / 255`."""
    import cv2

    one = 1 << shift
    lo = np.maximum(np.floor(poly.min(axis=0) / one).astype(int) - 1, 0)
    hi = np.minimum(np.ceil(poly.max(axis=0) / one).astype(int) + 2, canvas.shape[::-1])
    if np.any(hi <= lo):
        return
    w, h = int(hi[0] - lo[0]), int(hi[1] - lo[1])
    move = np.array([[1.0, 0, -lo[0]], [0, 1.0, -lo[1]], [0, 0, 1.0]])
    patch = cv2.warpPerspective(
        texture, move @ homography, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP
    )
    mask = np.zeros((h, w), np.uint8)
    cv2.fillPoly(mask, [poly - (lo * one).astype(np.int32)], 255, cv2.LINE_8, shift)
    region = canvas[lo[1] : hi[1], lo[0] : hi[0]]
    inside = mask > 0
    region[inside] = patch.astype(np.float32)[inside] * np.float32(shade / 255.0)


@no_type_check
def render(
    model: Polyhedron | MeshGeometry,
    K,
    dist,
    R,
    t,
    image_size: tuple[int, int],
    *,
    shades=None,
    light=(-0.4, -0.6, -1.0),
    ambient: float = 0.25,
    texture: np.ndarray | Sequence[np.ndarray] | None = None,
    texture_scale: float = 0.1,
    background: float | np.ndarray = 30.0,
    gain: float = 1.0,
    offset: float = 0.0,
    occluder: tuple[float, float, float, float] | None = None,
    occluder_grey: float = 200.0,
    blur: float = 0.0,
    noise: float = 0.0,
    supersample: int = 4,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """Draw a model at pose `(R, t)` into a grey image (see the module docstring).

    **Arguments:**
    - `model`: a `Polyhedron` or its `MeshGeometry`; `K` `(3, 3)`; `dist`: OpenCV's
      distortion coefficients or None; `R`, `t`: the pose, model to camera.
    - `image_size`: `(width, height)`.
    - `shades`: one grey level per face (0..255); None: Lambert's law with `light`, the
      direction from the object to the light in the camera frame, and `ambient` (0..1).
    - `texture`: a grey uint8 image laid on every face (or one per face), `texture_scale`
      model units per texture pixel, tiled; its grey levels are scaled by the face's
      shade. None: flat faces.
    - `background`: a grey level, or an image `(height, width)` uint8.
    - `gain`, `offset`: the lighting change `grey * gain + offset`.
    - `occluder`: a rectangle `(x0, y0, x1, y1)` in pixels drawn over the object with
      grey level `occluder_grey`; None: none.
    - `blur`: Gaussian blur sigma in pixels (0: none); `noise`: Gaussian noise sigma in
      grey levels (0: none), drawn from `rng` (None: a fixed seed).
    - `supersample`: the drawing's resolution factor (>= 1).

    **Returns:** `(height, width)` uint8.

    **Raises:** `ValueError` naming the argument.
    """
    import cv2

    geo = mesh_geometry(model)
    K, dist, R, t = _check_pose(K, dist, R, t)
    if len(image_size) != 2 or min(int(image_size[0]), int(image_size[1])) < 1:
        raise ValueError(f"image_size must be (width, height) >= 1, got {image_size!r}")
    if isinstance(supersample, bool) or not isinstance(supersample, int) or supersample < 1:
        raise ValueError(f"supersample must be an int >= 1, got {supersample!r}")
    for label, value in (("blur", blur), ("noise", noise), ("texture_scale", texture_scale)):
        if isinstance(value, bool) or not isinstance(value, int | float) or not value >= 0:
            raise ValueError(f"{label} must be a number >= 0, got {value!r}")
    if not 0 <= ambient <= 1:
        raise ValueError(f"ambient must be in [0, 1], got {ambient!r}")
    for label, value in (("gain", gain), ("offset", offset), ("occluder_grey", occluder_grey)):
        if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value):
            raise ValueError(f"{label} must be a finite number, got {value!r}")
    if occluder is not None:
        box = np.asarray(occluder, dtype=np.float64).reshape(-1)
        if box.shape != (4,) or not np.all(np.isfinite(box)):
            raise ValueError(f"occluder must be 4 finite numbers x0, y0, x1, y1: {occluder!r}")
    w, h = int(image_size[0]), int(image_size[1])
    s = supersample
    shade = _shades(geo, R, shades, light, ambient)
    faces = len(geo.normals)
    textures: list[np.ndarray] = []
    if texture is not None:
        textures = [texture] * faces if isinstance(texture, np.ndarray) else list(texture)
        if len(textures) != faces or any(
            not isinstance(x, np.ndarray) or x.ndim != 2 or x.dtype != np.uint8 for x in textures
        ):
            raise ValueError(f"texture must be a 2D uint8 image or {faces} of them")
        if not texture_scale > 0:
            raise ValueError("texture_scale must be > 0 with a texture")
    if isinstance(background, np.ndarray):
        if background.shape != (h, w) or background.dtype != np.uint8:
            raise ValueError(f"background must be a grey level or a ({h}, {w}) uint8 image")
        canvas = cv2.resize(
            background.astype(np.float32), (w * s, h * s), interpolation=cv2.INTER_LINEAR
        )
    else:
        canvas = np.full((h * s, w * s), float(background), np.float32)
    A = np.array([[s, 0, (s - 1) / 2], [0, s, (s - 1) / 2], [0, 0, 1.0]])
    Ks = A @ K
    centre = -R.T @ t
    front = np.flatnonzero(geo.normals @ centre > geo.offsets)
    depth = np.array([(geo.corners[f] @ R.T + t)[:, 2].mean() for f in front])
    shift = 6
    for f in front[np.argsort(-depth)]:
        cam = geo.corners[f] @ R.T + t
        if np.any(cam[:, 2] <= 1e-9):
            continue
        poly = np.round(_inset(project(cam, Ks, None), 0.5) * (1 << shift)).astype(np.int32)
        if np.abs(poly).max() > 2**30:
            continue
        if texture is None:
            cv2.fillPoly(canvas, [poly], float(shade[f]), cv2.LINE_8, shift)
            continue
        _paint_texture(canvas, poly, textures[f], Ks @ _plane(geo, f, R, t, texture_scale),
                       shade[f], shift)  # fmt: skip
    image = cv2.resize(canvas, (w, h), interpolation=cv2.INTER_AREA) if s > 1 else canvas
    if dist is not None:
        grid = np.stack(np.meshgrid(np.arange(w), np.arange(h)), axis=-1).astype(np.float64)
        ideal = cv2.undistortPoints(grid.reshape(-1, 1, 2), K, dist, P=K).reshape(h, w, 2)
        maps = ideal.astype(np.float32)
        image = cv2.remap(image, maps[..., 0], maps[..., 1], cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_REPLICATE)  # fmt: skip
    image = image * np.float32(gain) + np.float32(offset)
    if occluder is not None:
        x0, y0, x1, y1 = (float(v) for v in occluder)
        image[max(int(round(y0)), 0) : max(int(round(y1)), 0),
              max(int(round(x0)), 0) : max(int(round(x1)), 0)] = float(occluder_grey)  # fmt: skip
    if blur > 0:
        image = cv2.GaussianBlur(image, (0, 0), float(blur))
    if noise > 0:
        rng = np.random.default_rng(0) if rng is None else rng
        image = image + rng.normal(0.0, float(noise), image.shape).astype(np.float32)
    return np.clip(np.round(image), 0, 255).astype(np.uint8)


@no_type_check
def face_textures(
    photograph,
    model: Polyhedron | MeshGeometry,
    K,
    dist,
    R,
    t,
    *,
    texture_scale: float = 0.1,
    fallback: np.ndarray | None = None,
    min_cosine: float = 0.2,
) -> list[np.ndarray]:
    """Textures for `render` cut from a photograph of the object at a known pose: each
    face turned towards the camera (the cosine between its normal and its line of sight
    at least `min_cosine`) is rectified, the photograph warped by the homography of the
    face's plane, into a grey image of `texture_scale` model units per pixel covering
    the face's bounding box (as `render` lays textures).

    **Arguments:** `photograph`: grey or BGR uint8; `model`, `K`, `dist`, `R`, `t`: as for
    `render` (the photograph's camera and pose; its distortion is removed first);
    `texture_scale` (> 0); `fallback`: the texture of the faces not seen (None:
    `noise_texture()`); `min_cosine` in `[0, 1)`.

    **Returns:** one uint8 texture per face, in the model's face order.

    **Raises:** `ValueError` naming the argument.
    """
    import cv2

    geo = mesh_geometry(model)
    K, dist, R, t = _check_pose(K, dist, R, t)
    if (
        not isinstance(photograph, np.ndarray)
        or photograph.dtype != np.uint8
        or (photograph.ndim not in (2, 3))
    ):
        raise ValueError("photograph must be a grey or BGR uint8 image")
    grey = photograph if photograph.ndim == 2 else cv2.cvtColor(photograph, cv2.COLOR_BGR2GRAY)
    if dist is not None:
        grey = cv2.undistort(grey, K, dist)
    if isinstance(texture_scale, bool) or not texture_scale > 0:
        raise ValueError(f"texture_scale must be a number > 0, got {texture_scale!r}")
    if not 0 <= min_cosine < 1:
        raise ValueError(f"min_cosine must be in [0, 1), got {min_cosine!r}")
    if fallback is None:
        fallback = noise_texture()
    elif not isinstance(fallback, np.ndarray) or fallback.ndim != 2 or fallback.dtype != np.uint8:
        raise ValueError("fallback must be a 2D uint8 image")
    centre = -R.T @ t
    sight = centre - geo.corners.mean(axis=1)
    cos = (geo.normals * sight).sum(axis=1) / np.maximum(np.linalg.norm(sight, axis=1), 1e-300)
    out = []
    for f in range(len(geo.normals)):
        if cos[f] < max(min_cosine, 1e-9):
            out.append(fallback)
            continue
        extent = np.ptp(geo.polygons[f], axis=0) / texture_scale
        w, h = (int(np.ceil(v)) + 1 for v in extent)
        if w * h > 4096 * 4096:
            raise ValueError("texture_scale is too small for the model's faces")
        H = K @ _plane(geo, f, R, t, texture_scale)
        flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
        out.append(cv2.warpPerspective(grey, H, (w, h), flags=flags,
                                       borderMode=cv2.BORDER_REPLICATE))  # fmt: skip
    return out


@no_type_check
def smooth_trajectory(
    R0,
    t0,
    count: int,
    *,
    centre=None,
    rotation: float = 10.0,
    translation=5.0,
    periods: float = 1.0,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """A smooth sequence of poses around `(R0, t0)`: the model turns about its `centre`
    by a rotation vector whose components are sines (amplitude `rotation` degrees,
    random phases, frequencies between 0.5 and 1 times `periods` over the sequence) and
    that centre moves by sines of amplitude `translation` (model units, a number or
    one per camera axis).

    **Arguments:** `R0` `(3, 3)`, `t0` `(3,)`: the pose at the start's phase;
    `count` >= 1 poses; `centre` `(3,)` model frame (None: the origin); `seed` for the
    phases and frequencies.

    **Returns:** `(Rs, ts)`: `(count, 3, 3)` and `(count, 3)`.

    **Raises:** `ValueError` naming the argument.
    """
    _, _, R0, t0 = _check_pose(np.eye(3), None, R0, t0)
    if isinstance(count, bool) or not isinstance(count, int) or count < 1:
        raise ValueError(f"count must be an int >= 1, got {count!r}")
    centre = np.zeros(3) if centre is None else np.asarray(centre, np.float64).reshape(-1)
    if centre.shape != (3,) or not np.all(np.isfinite(centre)):
        raise ValueError("centre must be 3 finite values")
    amp = np.broadcast_to(np.asarray(translation, np.float64), (3,))
    if not np.all(np.isfinite(amp)) or not np.isfinite(rotation) or not np.isfinite(periods):
        raise ValueError("rotation, translation and periods must be finite")
    rng = np.random.default_rng(seed)
    phase = rng.uniform(0, 2 * np.pi, (2, 3))
    freq = periods * rng.uniform(0.5, 1.0, (2, 3))
    s = np.arange(count)[:, None] / max(count - 1, 1)
    w = np.radians(rotation) * (np.sin(2 * np.pi * freq[0] * s + phase[0]) - np.sin(phase[0]))
    d = amp * (np.sin(2 * np.pi * freq[1] * s + phase[1]) - np.sin(phase[1]))
    Rs = np.stack([_rodrigues(v) @ R0 for v in w])
    p0 = R0 @ centre + t0
    ts = p0 + d - Rs @ centre
    return Rs, ts


@no_type_check
def render_sequence(
    model: Polyhedron | MeshGeometry,
    K,
    dist,
    Rs,
    ts,
    image_size: tuple[int, int],
    *,
    seed: int = 0,
    **options,
) -> Iterator[np.ndarray]:
    """Draw a model at each pose of a sequence: `render` with `options` (the same for
    every frame; the noise drawn anew each frame from one generator seeded by `seed`).

    **Arguments:** `Rs` `(n, 3, 3)`, `ts` `(n, 3)`; the others as for `render`.

    **Returns:** an iterator of `n` `(height, width)` uint8 frames.

    **Raises:** `ValueError` naming the argument (when iterated, for `render`'s).
    """
    Rs, ts = np.asarray(Rs, np.float64), np.asarray(ts, np.float64)
    if Rs.ndim != 3 or Rs.shape[1:] != (3, 3) or ts.shape != (len(Rs), 3):
        raise ValueError(f"Rs and ts must have shapes (n, 3, 3) and (n, 3), got {Rs.shape}, "
                         f"{ts.shape}")  # fmt: skip
    geo = mesh_geometry(model)
    rng = np.random.default_rng(seed)

    def frames() -> Iterator[np.ndarray]:
        for R, t in zip(Rs, ts, strict=True):
            yield render(geo, K, dist, R, t, image_size, rng=rng, **options)

    return frames()
