r"""The tracker's per-frame solve (issue #32): the paper's small-movement linear method
(Section 2.2, Eqs. 3-7) on edge and point measurements, robustly weighted, as one
compiled program per bucket of measurement counts.

**The rows.** With the camera frame as the world (`C = K [I | 0]`), every measurement is
a plane through the camera centre that the point `X = R m + t` of its model point `m`
should lie on: an image line `l = (n, -n . q)` (`|n| = 1`: a moving-edge match, the
edge's normal `n` through the matched pixel `q`) is the plane `a = K^T l`; a pixel
`(u, v)` (a KLT point) the two planes `K_1 - u e3`, `K_2 - v e3` of its visual ray (the
paper's Eq. 5). The residual `a . X / Z` is then a pixel distance (to the line; along
`u` or `v`), and the small motion `dX = dt + r x (X - X_c)` (Eq. 3, turned about the
centroid `X_c` of the measured points) gives the row of Eq. 7 divided by the depth `Z`,
with the plane's normal taken at the reprojected point, `(a - (a . X / Z) e3) / Z`:
the exact derivative of the pixel residual, so that the iteration is Gauss-Newton on the
pixel errors (the `"depth"` weighting of `jaxpose.solvers.linear`).

**Robust weights** (iteratively reweighted least squares). Each measurement is weighted
by Tukey's biweight of its residual (an edge's distance, a point's pixel error) over a
robust scale (1.4826 times the median, edges and points apart, never below
`min_scale` and at most `max_scale`), and each kind by the inverse square of its scale
(the better measured kind counts more). The 6 x 6 normal equations are equilibrated
and solved by the unrolled Cholesky of `jaxpose.solvers._linalg.cholesky_solve`, the
motion applied exactly (`R <- Rot(r) R`, `jaxpose.geometry.rotvec_to_matrix`), and the step repeated
(`jax.lax.while_loop`: `iterations` steps, or until a step has fewer than
`max(min_rows, 6)` weighted rows (`ok` False) or a non-finite solution (the last pose
kept)).

**Why not `jaxpose.solvers.linear_step` or its kernel.** Those take `Observations`: two
visual-ray planes per match (Eq. 5), all rows of a match weighted alike, no row weights.
The tracker's edge match is one plane (a line, not a pixel), and its rows carry robust
weights recomputed at every step; the component kernel
(`jaxpose.solvers._kernel_linear`) moreover whitens the image axes, in which a row along
an arbitrary edge normal is not one of its two row shapes. The rows are therefore
written here once (`plane_rows`, also used by the offline refinement,
`jaxpose.apps._track_refine`); the rotation update and the 6 x 6 solve are the
solvers' own.

**Fixed shapes.** The measurements are padded (masked out) to `bucket_points(E + P)`
units (8, 16, ..., 1024, then powers of two), one unit per edge match (one row, the
second masked) or KLT point (two rows), so a handful of programs serve every frame; each
is compiled once and stored on disk (`jaxpose.api._programs.program`): a new process
loads it. The dtype is JAX's default float (float64 under x64).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float

from ..api._programs import bucket_points, program
from ..geometry._numerics import masked_centroid
from ..geometry._rotation import hat, rotvec_to_matrix
from ..solvers._linalg import cholesky_solve, symmetric_pinv
from ..strategy._covariance import PoseCovariance

__all__ = [
    "Measurements",
    "Solved",
    "TrackRows",
    "frame_covariance",
    "moved_pixels",
    "plane_rows",
    "solve_frame",
]

#: Tukey's biweight constant (95% efficiency under Gaussian noise).
TUKEY = 4.685


class Measurements(NamedTuple):
    """Pinhole-frame measurements: edge lines and points, with their model points."""

    edge_model: np.ndarray  # (E, 3)
    edge_lines: np.ndarray  # (E, 3): n_x u + n_y v + c = 0, |n| = 1
    point_model: np.ndarray  # (P, 3)
    point_pixels: np.ndarray  # (P, 2)


class TrackRows(NamedTuple):
    """A frame's measurements as planes through the camera centre (module docstring),
    one unit per measurement: the `E` edge matches first, then the `P` points.

    **Fields:**
    - `model` `(U, 3)`: each unit's model point.
    - `planes` `(U, 2, 3)`: its planes (camera frame; an edge's second one zero).
    - `mask` `(U, 2)` bool: which rows exist (an edge's second does not).
    - `point` `(U,)` bool: a KLT point (two rows) or an edge match (one).
    - `weights` `(U,)`: each unit's Tukey weight in the last step of the solve (0 where
      rejected, 1 before any).
    - `scales` `(U,)`: the robust scale (px) of its kind in that step: in the normal
      equations a unit counts `weights / scales^2`.
    """

    model: np.ndarray
    planes: np.ndarray
    mask: np.ndarray
    point: np.ndarray
    weights: np.ndarray
    scales: np.ndarray


def track_rows(K: np.ndarray, meas: Measurements, size: int | None = None,
               dtype=np.float64) -> TrackRows:  # fmt: skip
    """`TrackRows` of the measurements of the pinhole camera `K` (weights 1), padded
    with masked-out units to `size` units (default: none)."""
    E, P = len(meas.edge_model), len(meas.point_model)
    U = E + P if size is None else size
    planes = np.zeros((U, 2, 3), dtype)
    planes[:E, 0] = np.reshape(meas.edge_lines, (E, 3)) @ K
    planes[E : E + P] = K[:2]
    planes[E : E + P, :, 2] -= np.reshape(meas.point_pixels, (P, 2))
    mask = np.zeros((U, 2), bool)
    mask[: E + P, 0] = True
    mask[E : E + P, 1] = True
    model = np.zeros((U, 3), dtype)
    model[:E] = np.reshape(meas.edge_model, (E, 3))
    model[E : E + P] = np.reshape(meas.point_model, (P, 3))
    point = np.zeros(U, bool)
    point[E : E + P] = True
    weights = np.zeros(U, dtype)
    weights[: E + P] = 1.0
    return TrackRows(model, planes, mask, point, weights, np.ones(U, dtype))


def plane_rows(
    R: Float[ArrayLike, "3 3"],
    t: Float[ArrayLike, " 3"],
    model: Float[ArrayLike, "U 3"],
    planes: Float[ArrayLike, "U 2 3"],
    mask: Bool[ArrayLike, "U 2"],
    centre: Float[ArrayLike, " 3"] | None = None,
) -> tuple[Float[Array, "U 2"], Float[Array, "U 2 6"], Float[Array, " 3"]]:
    """The residuals `(U, 2)` (px) and rows `(U, 2, 6)` (d residual / d(dt, r), the
    rotation about `centre`) at pose `(R, t)`, 0 where masked out, and the centre
    (default: the centroid of the units' points). One problem; `jax.vmap` it."""
    R, t, model, planes, mask = map(jnp.asarray, (R, t, model, planes, mask))
    X = model @ R.T + t[None, :]
    z = jnp.maximum(X[:, 2], jnp.asarray(1e-12, X.dtype))
    # (elementwise products and sums: a dot_general batched over the units runs one tiny
    # product at a time on XLA:CPU)
    r = jnp.sum(planes * X[:, None, :], axis=-1) / z[:, None]
    e3 = jnp.asarray([0.0, 0.0, 1.0], X.dtype)
    normal = (planes - r[:, :, None] * e3[None, None, :]) / z[:, None, None]
    centre = masked_centroid(X, jnp.any(mask, axis=1)) if centre is None else jnp.asarray(centre)
    arm = jnp.broadcast_to((X - centre[None, :])[:, None, :], normal.shape)
    J = jnp.concatenate([normal, jnp.cross(arm, normal)], axis=-1)
    return jnp.where(mask, r, 0), jnp.where(mask[:, :, None], J, 0), centre


def _robust_scales(residual: Array, kinds: Array, min_scale: Array, max_scale: Array) -> Array:
    """`max(1.4826 median(residual[kind]), min_scale)`, at most `max(max_scale, min_scale)`,
    for each row of `kinds` `(k, U)` (bool), 1 where a kind has none. `residual` is `>= 0`.

    The median is that of `np.median` (the mean of the two middle values for an even
    count), found without sorting (XLA:CPU sorts through a comparator call per
    comparison: 150 us for 512 values here) by bisection on the bits of the float
    (monotone for values `>= 0`): the `j`-th smallest value is the least `v` with at
    least `j + 1` values `<= v`, exact after one step per bit."""
    dtype = residual.dtype
    itype = jnp.int64 if dtype == jnp.float64 else jnp.int32
    bits = jnp.iinfo(itype).bits
    top = jnp.iinfo(itype).max
    keys = jnp.where(kinds, jax.lax.bitcast_convert_type(residual, itype)[None, :], top)
    count = jnp.sum(kinds, axis=1).astype(itype)  # (k,)
    rank = jnp.concatenate([jnp.maximum(count - 1, 0) // 2, count // 2])  # (2k,)
    keys = jnp.concatenate([keys, keys])  # (2k, U): each kind's keys per rank asked

    def body(_, bounds):
        low, high = bounds
        mid = low + (high - low) // 2
        enough = jnp.sum(keys <= mid[:, None], axis=1) >= rank + 1
        return jnp.where(enough, low, mid + 1), jnp.where(enough, mid, high)

    start = (jnp.zeros_like(rank), jnp.full_like(rank, top))
    low, _ = jax.lax.fori_loop(0, bits, body, start)
    middle = jax.lax.bitcast_convert_type(low, dtype)
    k = kinds.shape[0]
    median = 0.5 * (middle[:k] + middle[k:])
    scale = jnp.minimum(jnp.maximum(1.4826 * median, min_scale), jnp.maximum(max_scale, min_scale))
    return jnp.where(count > 0, scale, jnp.ones((), dtype))


def _tukey(residual: Array, scale: Array) -> Array:
    z = residual / (TUKEY * scale)
    return jnp.where(jnp.abs(z) < 1, (1 - z * z) ** 2, 0)


class _State(NamedTuple):
    """The robust solve's loop state."""

    step: Array  # steps made
    R: Array
    t: Array
    scales: Array  # (U,) the robust scale of each unit's kind, in the last step
    tukey: Array  # (U,) Tukey weight of the last step
    rms: Array  # weighted RMS residual (all rows) before the last step taken
    judged: Array  # the edges' (the points' without edges)
    ok: Array
    stop: Array


def _robust_solve(R, t, model, planes, mask, point, iterations, min_rows, min_scale, max_scale):
    """The robust small-movement solve of one frame (module docstring), padded shapes.
    Returns `(R, t, tukey (U,), scales (U,), rms, judged, ok)`."""
    dtype = planes.dtype
    unit = jnp.any(mask, axis=1)
    edge, pt = unit & ~point, unit & point
    need = jnp.maximum(min_rows, 6)
    tiny = jnp.finfo(dtype).tiny

    def body(s: _State) -> _State:
        r, J, centre = plane_rows(s.R, s.t, model, planes, mask)
        residual = jnp.sqrt(jnp.sum(r * r, axis=1))  # |edge distance|, |point error|
        s_e, s_p = _robust_scales(residual, jnp.stack([edge, pt]), min_scale, max_scale)
        scale = jnp.where(point, s_p, s_e)
        tukey = jnp.where(unit, _tukey(residual, scale), 0)
        w = tukey[:, None] * mask  # row weights
        enough = jnp.sum(w > 0) >= need
        weights = tukey / (scale * scale)
        Jw = J * (weights[:, None] * mask)[:, :, None]
        A = jnp.einsum("uki,ukj->ij", Jw, J)
        b = -jnp.einsum("uki,uk->i", Jw, r)
        col = jnp.sqrt(jnp.maximum(jnp.diagonal(A), tiny))
        x = cholesky_solve(A / (col[:, None] * col[None, :]), b / col) / col
        finite = jnp.all(jnp.isfinite(x))
        x = jnp.where(finite, x, 0)
        dR = rotvec_to_matrix(x[3:])
        R1, t1 = dR @ s.R, dR @ (s.t - centre) + centre + x[:3]
        wr2 = w * r * r
        rms = jnp.sqrt(jnp.sum(wr2) / jnp.maximum(jnp.sum(w), tiny))
        kind = jnp.where(jnp.any(edge & (tukey > 0)), edge, pt)[:, None]
        judged = jnp.sqrt(
            jnp.sum(jnp.where(kind, wr2, 0)) / jnp.maximum(jnp.sum(jnp.where(kind, w, 0)), tiny)
        )
        take = enough & finite
        return _State(
            s.step + 1,
            jnp.where(take, R1, s.R),
            jnp.where(take, t1, s.t),
            scale,
            tukey,
            jnp.where(take, rms, s.rms),
            jnp.where(take, judged, s.judged),
            jnp.where(enough, s.ok | finite, False),
            ~take,
        )

    zero = jnp.zeros((), dtype)
    start = _State(jnp.zeros((), jnp.int32), R, t, jnp.ones(unit.shape, dtype),
                   jnp.zeros(unit.shape, dtype), zero, zero, jnp.zeros((), bool),
                   jnp.zeros((), bool))  # fmt: skip
    s = jax.lax.while_loop(lambda s: (s.step < iterations) & ~s.stop, body, start)
    return s.R, s.t, s.tukey, s.scales, s.rms, s.judged, s.ok


#: The compiled solve: one program per bucket of units (and dtype), stored on disk.
_PROGRAM = program(_robust_solve)


class Solved(NamedTuple):
    """A frame's solve: the pose, the Tukey weights of the edge matches `(E,)` and of
    the points `(P,)` in the last step, the weighted RMS residual (px) over all rows and
    over the edges' (the points' without edges), whether the pose was solved, and the
    measurements with their last weights (for `refine_track`)."""

    R: np.ndarray
    t: np.ndarray
    w_e: np.ndarray
    w_p: np.ndarray
    rms: float
    judged: float
    ok: bool
    rows: TrackRows


def _float() -> type:
    return jax.dtypes.canonicalize_dtype(np.float64).type


def _orthonormal(R: np.ndarray) -> np.ndarray:
    """The rotation nearest `R`."""
    u, _, vt = np.linalg.svd(R)
    return u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt


#: The compiled solve's executables by (bucket, dtype), once each has run (a program
#: read from disk is proven by its first run, in `Program.__call__`): called directly.
_READY: dict[tuple, object] = {}


def solve_frame(R, t, K, meas: Measurements, *, iterations: int, min_rows: int,
                min_scale: float, max_scale: float = np.inf) -> Solved:  # fmt: skip
    """The robust small-movement solve of one frame from `(R, t)` (module docstring),
    compiled; numpy in and out (float64). `max_scale` caps the robust scales (px; never
    below `min_scale`)."""
    E, P = len(meas.edge_model), len(meas.point_model)
    U = E + P
    if E + 2 * P < max(min_rows, 6):  # too few rows to weigh: nothing to solve
        rows = track_rows(K, meas)
        return Solved(R, t, np.zeros(E), np.zeros(P), 0.0, 0.0, False,
                      rows._replace(weights=np.zeros(U)))  # fmt: skip
    f = _float()
    size = bucket_points(U)
    padded = track_rows(K, meas, size, f)
    args = (np.asarray(R, f), np.asarray(t, f), padded.model, padded.planes, padded.mask,
            padded.point, np.int32(iterations), np.int32(min_rows), f(min_scale),
            f(max_scale))  # fmt: skip
    run = _READY.get((size, f))
    if run is None:
        out = _PROGRAM(*args)
        _READY[size, f] = _PROGRAM.executable(*args)
    else:
        out = run(*args)  # type: ignore[operator]
    R1, t1, tukey, scales, rms, judged, ok = (np.asarray(a) for a in out)
    if not (np.all(np.isfinite(R1)) and np.all(np.isfinite(t1))):
        # Measurements that leave a motion unmeasured (edges all nearly parallel, no
        # points) can send the iterations off to a non-finite pose: no pose, the start kept.
        rows = track_rows(K, meas)
        return Solved(R, t, np.zeros(E), np.zeros(P), 0.0, 0.0, False,
                      rows._replace(weights=np.zeros(U)))  # fmt: skip
    tukey = tukey[:U].astype(np.float64)
    rows = TrackRows(padded.model[:U].astype(np.float64), padded.planes[:U].astype(np.float64),
                     padded.mask[:U], padded.point[:U], tukey,
                     scales[:U].astype(np.float64))  # fmt: skip
    return Solved(_orthonormal(R1.astype(np.float64)), t1.astype(np.float64), tukey[:E],
                  tukey[E:], float(rms), float(judged), bool(ok), rows)  # fmt: skip


def _covariance(R, t, model, planes, mask, weights, scales):
    """The Gauss-Newton covariance of the last step's weighted rows at `(R, t)` (see
    `frame_covariance`), padded shapes: `(covariance (6, 6), rank)`."""
    _, J, centre = plane_rows(R, t, model, planes, mask)
    unit = jnp.any(mask, axis=1)
    info = jnp.where(unit, weights / (scales * scales), 0)
    Jw = J * (info[:, None] * mask)[:, :, None]
    A = jnp.einsum("uki,ukj->ij", Jw, J)  # information of (dt, r), r about `centre`
    inv, rank, _ = symmetric_pinv(A)
    # (dt, r) -> (w, dt'): w = r, dt' = dt - hat(t - centre) r (the rotation about the
    # camera frame's origin, as `jaxpose.pose_covariance` reports it)
    eye, zero = jnp.eye(3, dtype=t.dtype), jnp.zeros((3, 3), t.dtype)
    T = jnp.block([[zero, eye], [eye, -hat(t - centre)]])
    cov = T @ inv @ T.T
    return 0.5 * (cov + cov.T), rank


_COVARIANCE = program(_covariance)
#: The rows `frame_covariance` last answered for, and its answer.
_LAST: list = [None, None]


def frame_covariance(result) -> PoseCovariance | None:
    """The first-order covariance of a tracked frame's pose, or None on a frame without
    one (`TrackedFrame.rows` None, or no weighted row).

    The solve's last step weighs each measurement by its Tukey weight over its kind's
    robust scale squared (edges and points apart: `TrackRows.weights / scales^2`); the
    inverse of those normal equations at the frame's pose, `(sum w / s^2 J^T J)^+`, is
    the Gauss-Newton covariance with the robust scales as the noise of each kind (an
    inlier's pixel error has that standard deviation). It is reported in the order and
    parameterisation of `jaxpose.pose_covariance`: `(w, dt)`, `R = exp(hat(w)) R^`,
    `t = t^ + dt` (radians, model units). The measurements' biases (a printed line taken
    for an edge) are not in it: it is the spread the noise alone leaves.

    **Arguments:** `result`, a `jaxpose.apps.TrackedFrame`.

    **Returns:** a `jaxpose.PoseCovariance` (JAX arrays, as `jaxpose.pose_covariance`
    gives): `covariance` `(6, 6)`; `sigma` the robust
    scale (px) of the edges where any took part, else of the points; `rank` 6 where the
    measurements fix every motion, fewer where they leave one free (the pseudo-inverse:
    that motion gets no variance).
    """
    rows = getattr(result, "rows", None)
    if rows is None or not getattr(result, "ok", False) or not np.any(rows.weights > 0):
        return None
    if _LAST[0] is rows:  # (the same frame asked again: `--point` and `--rrd` both ask)
        return _LAST[1]
    U = len(rows.weights)
    size = bucket_points(U)
    f = _float()

    def pad(a, fill=0):
        out = np.full((size, *a.shape[1:]), fill, a.dtype)
        out[:U] = a
        return out

    args = (np.asarray(result.R, f), np.asarray(result.t, f), pad(rows.model.astype(f)),
            pad(rows.planes.astype(f)), pad(rows.mask), pad(rows.weights.astype(f)),
            pad(rows.scales.astype(f), 1))  # fmt: skip
    cov, rank = _COVARIANCE(*args)
    used = rows.weights > 0
    edges = used & ~rows.point
    sigma = rows.scales[edges][0] if np.any(edges) else rows.scales[used][0]
    _LAST[:] = rows, PoseCovariance(cov, jnp.asarray(sigma, cov.dtype), rank)
    return _LAST[1]


def moved_pixels(K, model: np.ndarray, a: tuple, b: tuple) -> float:
    """How far (px, the most over `model`'s points) pose `b` moves them from pose `a`
    in the pinhole camera `K`."""
    if len(model) == 0:
        return 0.0
    u, v = (K @ (model @ p[0].T + p[1]).T for p in (a, b))
    depth = np.maximum(np.abs(u[2]), 1e-12), np.maximum(np.abs(v[2]), 1e-12)
    return float(np.max(np.hypot(*(u[:2] / depth[0] - v[:2] / depth[1]))))
