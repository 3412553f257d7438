"""A small model database for recognition (the paper's Section 5) and bench scenes of any
of its models.

The database holds the bench's cross prism and four other polyhedra, all in millimetres,
centred near the origin, of about the cross's size: a box, a hexagonal prism, an L-shaped
block and a square pyramid. Each is a `Polyhedron`: vertices `(V, 3)`, edges `(E, 2)` and
faces ordered counter-clockwise seen from outside (right-hand normal pointing out).

`model_bench` puts any of them where the bench's cross prism lies (or at a pose of your
choice) in front of the bench's camera and matches every vertex the camera sees: the
vertex must lie on a face turned towards the camera, and the line of sight to it must
not cross another face first (the L-block and the cross are not convex).

`chessboard` is the planar model of OpenCV's calibration board (its grid lines), used to
superimpose a model on real photographs.

Everything here is plain numpy: it builds data, it is not traced.
"""

from __future__ import annotations

import math

import numpy as np

from ..geometry._camera import project_numpy
from ._bench import DEFAULT_NOISE, Bench, cross_prism, default_bench
from ._polyhedron import Polyhedron, prism, seen_vertices

__all__ = [
    "box",
    "chessboard",
    "hexagonal_prism",
    "l_block",
    "model_bench",
    "model_database",
    "pyramid",
]


def box(size: tuple[float, float, float] = (120.0, 80.0, 50.0)) -> Polyhedron:
    """A cuboid of `size` (mm) centred at the origin: 8 vertices, 12 edges, 6 faces."""
    a, b, c = (float(s) / 2 for s in size)
    outline = np.array([[-a, -b], [a, -b], [a, b], [-a, b]])
    return prism("box", outline, 2 * c)


def hexagonal_prism(radius: float = 60.0, height: float = 40.0) -> Polyhedron:
    """A regular hexagonal prism (circumradius `radius`, `height`, mm): 12 vertices,
    18 edges, 8 faces."""
    angles = np.radians(np.arange(6) * 60.0 + 15.0)
    outline = radius * np.column_stack([np.cos(angles), np.sin(angles)])
    return prism("hexagonal_prism", outline, height)


def l_block(thickness: float = 35.0) -> Polyhedron:
    """An L-shaped block, 140 x 100 mm with arms 45 and 50 mm wide, `thickness` mm thick,
    centred on its bounding box: 12 vertices, 18 edges, 8 faces (not convex)."""
    outline = np.array(
        [[0.0, 0.0], [140.0, 0.0], [140.0, 45.0], [50.0, 45.0], [50.0, 100.0], [0.0, 100.0]]
    )
    return prism("l_block", outline - [70.0, 50.0], thickness)


def pyramid(base: float = 130.0, height: float = 45.0) -> Polyhedron:
    """A square pyramid: base `base` x `base` mm at `z = -height / 3`, apex above its
    centre at `z = 2 height / 3` (the centroid at the origin): 5 vertices, 8 edges,
    5 faces."""
    a = base / 2
    z0 = -height / 3
    vertices = np.array(
        [[-a, -a, z0], [a, -a, z0], [a, a, z0], [-a, a, z0], [0.0, 0.0, z0 + height]]
    )
    edges = [(0, 1), (1, 2), (2, 3), (3, 0), (0, 4), (1, 4), (2, 4), (3, 4)]
    faces = ((3, 2, 1, 0), (0, 1, 4), (1, 2, 4), (2, 3, 4), (3, 0, 4))
    return Polyhedron("pyramid", vertices, np.asarray(edges, dtype=np.int32), faces)


def model_database() -> dict[str, Polyhedron]:
    """The recognition system's models by name: `cross_prism` (the bench object), `box`,
    `hexagonal_prism`, `l_block` and `pyramid` (see their builders for the sizes)."""
    models = (cross_prism(), box(), hexagonal_prism(), l_block(), pyramid())
    return {m.name: m for m in models}


def chessboard(
    pattern: tuple[int, int] = (9, 6), square: float = 0.025, border: int = 1
) -> tuple[Polyhedron, np.ndarray]:
    """The planar chessboard model: its grid of square corners at `z = 0`.

    **Arguments:**
    - `pattern`: inner corners per row and per column, as `cv2.findChessboardCorners`
      takes them (OpenCV's sample board: 9 x 6).
    - `square`: side of a square (model units; OpenCV's sample: 0.025 m).
    - `border`: rows of squares around the inner corners (1: the whole printed board).

    **Returns:** `(model, inner)`: a `Polyhedron` whose vertices are every corner of the
    grid, whose edges are the grid lines between neighbouring corners and whose faces
    are the squares (counter-clockwise seen from `-z`, the side the camera sees), and
    `inner` `(cols * rows,)`, the vertex index of each inner corner in the order
    `cv2.findChessboardCorners` returns them (row by row, `x` fastest).
    """
    cols, rows = (int(p) for p in pattern)
    if cols < 2 or rows < 2:
        raise ValueError(f"pattern must have at least 2 x 2 inner corners, got {pattern}")
    if not (math.isfinite(square) and square > 0):
        raise ValueError(f"square must be positive, got {square}")
    if int(border) < 0:
        raise ValueError(f"border must be >= 0, got {border}")
    b = int(border)
    nx, ny = cols + 2 * b, rows + 2 * b  # corners per row / column of the whole grid
    ix, iy = np.meshgrid(np.arange(nx) - b, np.arange(ny) - b)
    vertices = np.column_stack([ix.ravel(), iy.ravel(), np.zeros(ix.size)]) * float(square)

    def index(x, y):
        return (y + b) * nx + (x + b)

    edges = [
        (index(x, y), index(x + 1, y)) for y in range(-b, ny - b) for x in range(-b, nx - b - 1)
    ]
    edges += [
        (index(x, y), index(x, y + 1)) for y in range(-b, ny - b - 1) for x in range(-b, nx - b)
    ]
    faces = tuple(
        (index(x, y), index(x, y + 1), index(x + 1, y + 1), index(x + 1, y))
        for y in range(-b, ny - b - 1)
        for x in range(-b, nx - b - 1)
    )
    inner = np.array([index(x, y) for y in range(rows) for x in range(cols)], dtype=np.int64)
    model = Polyhedron("chessboard", vertices, np.asarray(edges, dtype=np.int32), faces)
    return model, inner


# --------------------------------------------------------------------------- scenes


def model_bench(
    model: Polyhedron | str,
    seed: int = 0,
    noise: float = DEFAULT_NOISE,
    *,
    R: np.ndarray | None = None,
    t: np.ndarray | None = None,
) -> Bench:
    """A bench scene of any model: the bench's camera (f = 3000 px, 768 x 576, about 2 m
    away) and, by default, the bench object's pose; every vertex the camera sees matched,
    with seeded Gaussian pixel noise of `noise` px.

    **Arguments:**
    - `model`: a `Polyhedron` or the name of one in `model_database()`.
    - `seed`, `noise`: as `default_bench`.
    - `R`, `t`: the model's pose in the world (model to world, mm); default the bench's.

    **Returns:** a `Bench` (`visible` lists the matched vertices). For the cross prism,
    `default_bench` remains the paper's bench (16 chosen vertices); this function matches
    every vertex seen.
    """
    if isinstance(model, str):
        database = model_database()
        if model not in database:
            raise ValueError(f"model must be one of {sorted(database)}, got {model!r}")
        model = database[model]
    if not isinstance(model, Polyhedron):
        raise ValueError(f"model must be a Polyhedron or a model name, got {type(model)}")
    if not (math.isfinite(noise) and noise >= 0):
        raise ValueError(f"noise must be >= 0, got {noise}")
    reference = default_bench(seed=0, noise=0.0)
    R = reference.R if R is None else np.asarray(R, dtype=np.float64)
    t = reference.t if t is None else np.asarray(t, dtype=np.float64)
    if R.shape != (3, 3) or not np.allclose(R.T @ R, np.eye(3), atol=1e-9):
        raise ValueError("R must be a 3x3 rotation matrix")
    if t.shape != (3,) or not np.all(np.isfinite(t)):
        raise ValueError(f"t must be a finite 3-vector, got shape {t.shape}")
    camera = reference.camera
    centre = -reference.R_wc.T @ reference.t_wc
    visible = seen_vertices(model, R, t, centre)
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
        K=reference.K.copy(),
        R_wc=reference.R_wc,
        t_wc=reference.t_wc,
        seed=int(seed),
    )
