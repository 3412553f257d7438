"""Superimposition (the paper's Section 5): a model's edges drawn over an image at a
recovered pose, and a simple renderer of the bench so that there is an image to draw over.

Drawing is OpenCV's (`cv2.line`, antialiased, sub-pixel coordinates). Edges are clipped
to the part in front of the camera and to the image; with lens distortion
(`dist_coeffs`), each edge is sampled along its ideal (pinhole) image and the samples
distorted with `cv2.projectPoints`, so that straight edges bend as the lens bends them.

Conventions as everywhere in jaxpose: the camera is a 3x4 matrix `C` calibrated in the
world frame, a pose `(R, t)` maps model to world (`p = R m + t`); images are numpy arrays
`(h, w)` or `(h, w, 3)` (BGR, OpenCV's order), and every drawing function returns a new
image of the same shape and dtype. Plain numpy and OpenCV: not traced.
"""

from __future__ import annotations

import numpy as np

from ..apps._bench import Bench
from ..apps._polyhedron import Polyhedron, polygon_normals
from ..geometry._camera import project_numpy
from ..geometry._validate import as_camera, as_dist_coeffs, as_points, no_type_check

__all__ = ["draw_model", "draw_points", "overlay", "render", "render_bench"]

_DTYPES = (np.uint8, np.uint16, np.float32, np.float64)
_SHIFT = 4  # sub-pixel bits for cv2.line


# --------------------------------------------------------------------------- validation


def _check_image(image, name="image") -> np.ndarray:
    if not isinstance(image, np.ndarray):
        raise ValueError(f"{name} must be a numpy array, got {type(image).__name__}")
    if image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] not in (1, 3, 4)):
        raise ValueError(f"{name} must have shape (h, w) or (h, w, 1|3|4), got {image.shape}")
    if image.shape[0] == 0 or image.shape[1] == 0:
        raise ValueError(f"{name} must not be empty, got shape {image.shape}")
    if image.dtype not in _DTYPES:
        raise ValueError(
            f"{name} must be uint8, uint16, float32 or float64, got dtype {image.dtype}"
        )
    return image


def _check_model(model) -> Polyhedron:
    if not isinstance(model, Polyhedron):
        raise ValueError(f"model must be a Polyhedron, got {type(model).__name__}")
    return model


def _check_pose(pose) -> tuple[np.ndarray, np.ndarray]:
    try:
        R, t = pose
        R = np.asarray(R, dtype=np.float64)
        t = np.asarray(t, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"pose must be a Pose or a pair (R, t): {exc}") from exc
    if R.shape != (3, 3) or t.shape != (3,):
        raise ValueError(f"pose must hold R (3, 3) and t (3,), got {R.shape} and {t.shape}")
    if not (np.all(np.isfinite(R)) and np.all(np.isfinite(t))):
        raise ValueError("pose contains NaN or infinite values")
    return R, t


def _check_color(color, name="color") -> tuple[float, ...]:
    try:
        c = tuple(float(x) for x in color)
    except (TypeError, ValueError) as exc:
        raise ValueError(
            f"{name} must be a sequence of 3 numbers (B, G, R), got {color!r}"
        ) from exc
    if len(c) != 3 or not all(np.isfinite(c)):
        raise ValueError(f"{name} must be 3 finite numbers (B, G, R), got {color!r}")
    return c


def _check_positive_int(value, name) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
        raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
    return int(value)


def _color_for(image: np.ndarray, color: tuple[float, ...]):
    """The colour as `cv2` wants it for this image: BGR(A), or a grey level."""
    channels = 1 if image.ndim == 2 else image.shape[2]
    if channels == 1:
        b, g, r = color
        return (0.114 * b + 0.587 * g + 0.299 * r,)
    if channels == 4:
        return (*color, np.iinfo(image.dtype).max if image.dtype.kind == "u" else 1.0)
    return color


# --------------------------------------------------------------------------- geometry


class _Camera:
    """A 3x4 camera prepared for drawing: `C` normalised as `project_numpy` does (ideal
    pixels and depths come from `project_numpy(cam.C, world)`), centre, distortion."""

    def __init__(self, camera, dist_coeffs=None):
        C = np.asarray(as_camera(camera, "camera"), dtype=np.float64)
        M = C[:, :3]
        sign = np.sign(np.linalg.det(M))
        self.C = C * sign / np.linalg.norm(M[2])  # c3 . [p 1] is the depth in front
        self.M_inv = np.linalg.inv(self.C[:, :3])
        self.centre = -self.M_inv @ self.C[:, 3]
        self.dist = as_dist_coeffs(dist_coeffs, "dist_coeffs")
        # Intrinsics for distortion: RQ of M (K upper triangular, positive diagonal).
        q, r = np.linalg.qr(np.flipud(self.C[:, :3]).T)
        K = np.flipud(np.fliplr(r.T))
        signs = np.diag(np.sign(np.diag(K)))
        self.K = K @ signs / (K @ signs)[2, 2]
        # K [R | t] = C (normalised): the rows of R = K^-1 M are the camera's axes.

    def distort(self, uv: np.ndarray) -> np.ndarray:
        """Ideal pixels to the pixels the lens produces (identity without distortion)."""
        if self.dist is None or len(uv) == 0:
            return uv
        import cv2

        x = np.column_stack([uv, np.ones(len(uv))]) @ np.linalg.inv(self.K).T
        out, _ = cv2.projectPoints(x.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), self.K, self.dist)
        return out.reshape(-1, 2)


def _clip_depth(a, b, da, db, near):
    """The part of segment `ab` (world) with depth >= near, or None."""
    if da < near and db < near:
        return None
    if da < near:
        a = a + (b - a) * (near - da) / (db - da)
    elif db < near:
        b = b + (a - b) * (near - db) / (da - db)
    return a, b


def _clip_box(p, q, lo, hi):
    """Liang-Barsky: the part of the 2D segment `pq` inside the box `[lo, hi]`, or None."""
    d = q - p
    t0, t1 = 0.0, 1.0
    for k in range(2):
        # The point p + s d is inside a boundary when s * den <= num.
        for num, den in ((p[k] - lo[k], -d[k]), (hi[k] - p[k], d[k])):
            if den == 0:
                if num < 0:
                    return None
            elif den > 0:
                t1 = min(t1, num / den)
            else:
                t0 = max(t0, num / den)
    if t0 > t1:
        return None
    return p + t0 * d, p + t1 * d


def _front_faces(model: Polyhedron, world: np.ndarray, centre: np.ndarray) -> np.ndarray:
    normals = polygon_normals(world, model.faces)
    return np.array(
        [normals[i] @ (centre - world[f[0]]) > 0 for i, f in enumerate(model.faces)], dtype=bool
    )


def _to_fixed(points: np.ndarray) -> np.ndarray:
    return np.round(points * (1 << _SHIFT)).astype(np.int64)


# --------------------------------------------------------------------------- drawing


# `draw_model` and `render_bench` check every argument, its type included (a `ValueError`
# naming it): no run-time type check before theirs (`jaxpose.geometry._validate`).
@no_type_check
def draw_model(
    image: np.ndarray,
    camera,
    model: Polyhedron,
    pose,
    *,
    dist_coeffs=None,
    color=(0, 255, 0),
    thickness: int = 1,
    cull: bool = False,
    samples: int = 24,
) -> np.ndarray:
    """Draw a model's edges over an image at a pose (antialiased `cv2.line`).

    **Arguments:**
    - `image`: `(h, w)` or `(h, w, 3)` (BGR) array, uint8, uint16, float32 or float64.
    - `camera`: the 3x4 matrix `C` (world frame); OpenCV's convention is `K [I | 0]`
      with the pose `(Rodrigues(rvec), tvec)`.
    - `model`: a `Polyhedron`; `pose`: a `Pose` or `(R, t)`, model to world.
    - `dist_coeffs`: OpenCV distortion coefficients of the camera that took `image`;
      edges are then drawn as `samples`-segment curves.
    - `color`: BGR in the image's units (a grey level of it for a one-channel image);
      `thickness`: pixels.
    - `cull`: draw only the edges of faces turned towards the camera (hidden-line
      removal for convex models; for others, edges behind a nearer face still show).

    **Returns:** a new image, same shape and dtype. Edges behind the camera are clipped
    away; edges outside the image are skipped.

    **Raises:** `ValueError` naming the argument for a bad image, camera, model, pose,
    colour or option.
    """
    import cv2

    image = _check_image(image)
    cam = _Camera(camera, dist_coeffs)
    model = _check_model(model)
    R, t = _check_pose(pose)
    col = _color_for(image, _check_color(color))
    thickness = _check_positive_int(thickness, "thickness")
    samples = _check_positive_int(samples, "samples")
    out = image.copy()
    world = np.asarray(model.vertices, dtype=np.float64) @ R.T + t
    _, depth = project_numpy(cam.C, world)
    edges = np.asarray(model.edges, dtype=np.int64).reshape(-1, 2)
    if cull:
        front = _front_faces(model, world, cam.centre)
        shown = set()
        for i, face in enumerate(model.faces):
            if front[i]:
                shown.update(
                    tuple(sorted((face[j], face[(j + 1) % len(face)]))) for j in range(len(face))
                )
        edges = np.array([e for e in edges if tuple(sorted(e)) in shown], dtype=np.int64)
    h, w = image.shape[:2]
    margin = 0.25 * max(h, w)
    lo, hi = np.array([-margin, -margin]), np.array([w + margin, h + margin])
    near = 1e-9 * max(float(np.max(np.abs(depth))) if len(depth) else 1.0, 1e-300)
    for a, b in edges:
        seg = _clip_depth(world[a], world[b], depth[a], depth[b], near)
        if seg is None:
            continue
        (p, q), _ = project_numpy(cam.C, np.stack(seg))
        seg2 = _clip_box(p, q, lo, hi)
        if seg2 is None:
            continue
        p, q = seg2
        if cam.dist is None:
            pts = np.stack([p, q])
        else:
            s = np.linspace(0, 1, samples + 1)[:, None]
            pts = cam.distort(p[None] + s * (q - p)[None])
        fixed = _to_fixed(pts)
        for u, v in zip(fixed[:-1], fixed[1:], strict=True):
            cv2.line(
                out,
                tuple(int(x) for x in u),
                tuple(int(x) for x in v),
                col,
                thickness,
                cv2.LINE_AA,
                _SHIFT,
            )
    return out


def draw_points(
    image: np.ndarray,
    points,
    *,
    color=(0, 0, 255),
    marker: str = "circle",
    size: int = 5,
    thickness: int = 1,
) -> np.ndarray:
    """Mark pixels on an image: `marker` `"circle"` (radius `size`) or `"cross"` (arms of
    `size`), antialiased. `points` `(n, 2)`; returns a new image, same shape and dtype."""
    import cv2

    image = _check_image(image)
    pts = (
        as_points(points, "points", 2, min_count=0) if len(np.asarray(points)) else np.zeros((0, 2))
    )
    col = _color_for(image, _check_color(color))
    size = _check_positive_int(size, "size")
    thickness = _check_positive_int(thickness, "thickness")
    if marker not in ("circle", "cross"):
        raise ValueError(f"marker must be 'circle' or 'cross', got {marker!r}")
    out = image.copy()
    for u, v in _to_fixed(pts):
        if marker == "circle":
            cv2.circle(out, (int(u), int(v)), size << _SHIFT, col, thickness, cv2.LINE_AA, _SHIFT)
        else:
            d = size << _SHIFT
            for a, b in (((u - d, v), (u + d, v)), ((u, v - d), (u, v + d))):
                cv2.line(
                    out,
                    (int(a[0]), int(a[1])),
                    (int(b[0]), int(b[1])),
                    col,
                    thickness,
                    cv2.LINE_AA,
                    _SHIFT,
                )
    return out


def overlay(
    image: np.ndarray,
    camera,
    model: Polyhedron,
    pose,
    *,
    vertices=None,
    observed=None,
    dist_coeffs=None,
    edge_color=(0, 255, 0),
    observed_color=(0, 0, 255),
    reprojected_color=(255, 255, 0),
    thickness: int = 1,
    cull: bool = False,
) -> np.ndarray:
    """The superimposition: the model's edges at `pose`, the observed image points
    (circles) and the reprojections of their model vertices at `pose` (crosses).

    **Arguments:** as `draw_model`, plus `vertices` `(k,)` indices of the matched model
    vertices and `observed` `(k, 2)` their image points (pixels of the image as taken,
    i.e. distorted when `dist_coeffs` is given); both or neither.

    **Returns:** a new image, same shape and dtype.
    """
    out = draw_model(
        image,
        camera,
        model,
        pose,
        dist_coeffs=dist_coeffs,
        color=edge_color,
        thickness=thickness,
        cull=cull,
    )
    if (vertices is None) != (observed is None):
        raise ValueError("vertices and observed must be given together")
    if vertices is None:
        return out
    idx = np.asarray(vertices)
    if idx.ndim != 1 or not np.issubdtype(idx.dtype, np.integer):
        raise ValueError(f"vertices must be a 1-D integer array, got {idx.dtype} {idx.shape}")
    if np.any(idx < 0) or np.any(idx >= len(model.vertices)):
        raise ValueError(f"vertices must index the model's {len(model.vertices)} vertices")
    obs = as_points(observed, "observed", 2, min_count=1)
    if len(obs) != len(idx):
        raise ValueError(f"observed has {len(obs)} points but vertices has {len(idx)}")
    R, t = _check_pose(pose)
    cam = _Camera(camera, dist_coeffs)
    uv, depth = project_numpy(cam.C, np.asarray(model.vertices, np.float64)[idx] @ R.T + t)
    uv = cam.distort(uv[depth > 0])
    out = draw_points(out, obs, color=observed_color, marker="circle", size=5, thickness=thickness)
    return draw_points(
        out, uv, color=reprojected_color, marker="cross", size=4, thickness=thickness
    )


# --------------------------------------------------------------------------- rendering


def render(
    camera,
    model: Polyhedron,
    pose,
    image_size: tuple[int, int],
    *,
    color=(150, 175, 205),
    background=(96, 96, 96),
    light=None,
    supersample: int = 2,
) -> np.ndarray:
    """A flat-shaded image of a polyhedron on a grey background.

    Faces turned away from the camera are culled; the others are filled (`cv2.fillPoly`)
    into a depth buffer (the inverse depth of a face is affine in the pixel, so each
    pixel's depth is exact), shaded by a light at the camera (brightness `0.35 + 0.65
    cos`, the angle between the face's normal and the line of sight), rendered at
    `supersample` times the size and reduced (antialiasing).

    **Arguments:** `camera` `C` (3, 4); `model`; `pose` (`Pose` or `(R, t)`);
    `image_size` `(width, height)`; `color`, `background` BGR (0-255).

    **Returns:** uint8 `(height, width, 3)` BGR image.
    """
    import cv2

    cam = _Camera(camera)
    model = _check_model(model)
    R, t = _check_pose(pose)
    try:
        width, height = (int(x) for x in image_size)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"image_size must be (width, height), got {image_size!r}") from exc
    if width < 1 or height < 1:
        raise ValueError(f"image_size must be positive, got {image_size!r}")
    base = np.array(_check_color(color))
    back = np.array(_check_color(background, "background"))
    s = _check_positive_int(supersample, "supersample")
    W, H = width * s, height * s
    world = np.asarray(model.vertices, dtype=np.float64) @ R.T + t
    uv, depth = project_numpy(cam.C, world)
    normals = polygon_normals(world, model.faces)
    front = _front_faces(model, world, cam.centre)
    if light is None:  # behind the camera, above it and to its left (image axes)
        axes = np.linalg.inv(cam.K) @ cam.C[:, :3]  # rows: camera x (right), y (down), z
        light = -axes[2] - 0.8 * axes[1] - 0.4 * axes[0]
    to_light = np.asarray(light, dtype=np.float64).reshape(3)
    if not (np.all(np.isfinite(to_light)) and np.linalg.norm(to_light) > 0):
        raise ValueError(f"light must be a nonzero finite 3-vector, got {light!r}")
    to_light = to_light / np.linalg.norm(to_light)
    canvas = np.empty((H, W, 3), dtype=np.float64)
    canvas[:] = back
    inv_depth = np.zeros((H, W))  # 0: nothing (infinitely far)
    u, v = np.meshgrid((np.arange(W) + 0.5) / s, (np.arange(H) + 0.5) / s)
    for i, face in enumerate(model.faces):
        idx = list(face)
        if not front[i] or np.any(depth[idx] <= 0):
            continue
        mask = np.zeros((H, W), dtype=np.uint8)
        pts = np.round((uv[idx] * s - 0.5) * (1 << _SHIFT)).astype(np.int32)
        cv2.fillPoly(mask, [pts], 1, cv2.LINE_8, _SHIFT)
        rows, cols = np.nonzero(mask)
        if len(rows) == 0:
            continue
        # Depth along the ray of pixel (u, v): s = n.(p0 - o) / (n . M^-1 [u v 1]).
        n = normals[i]
        g = cam.M_inv.T @ n
        num = n @ (world[idx[0]] - cam.centre)
        inv = (g[0] * u[rows, cols] + g[1] * v[rows, cols] + g[2]) / num
        closer = inv > inv_depth[rows, cols]
        rows, cols = rows[closer], cols[closer]
        inv_depth[rows, cols] = inv[closer]
        canvas[rows, cols] = base * (0.3 + 0.7 * max(float(n @ to_light), 0.0))
    out = np.clip(np.round(canvas), 0, 255).astype(np.uint8)
    if s > 1:
        out = cv2.resize(out, (width, height), interpolation=cv2.INTER_AREA)
    return out


@no_type_check
def render_bench(bench: Bench, **kwargs) -> np.ndarray:
    """`render` of a bench (`jaxpose.default_bench` or `jaxpose.apps.model_bench`): its model at
    its true pose, seen by its camera, at its image size. `kwargs` go to `render`."""
    if not isinstance(bench, Bench):
        raise ValueError(f"bench must be a Bench, got {type(bench).__name__}")
    return render(bench.camera, bench.model, (bench.R, bench.t), bench.image_size, **kwargs)
