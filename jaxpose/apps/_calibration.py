"""Camera calibration from 3D-2D pairs (the paper's Section 4 and Mallem et al. 1999).

The paper calibrates its camera with the robot: the LED at the shank's tip is moved to
known 3D positions and detected in the image, and the 3x4 matrix `C` of Eq. 4,

$$ s \\, [u_i\\ v_i\\ 1]^T = C \\, [X_i\\ 1]^T , $$

is estimated from six or more such pairs (11 unknowns: `C` up to scale, Roberts 1965).

**Linear estimate (DLT).** Each pair gives two equations linear in the twelve entries
`c = vec(C)` (row-major):

$$ [X^T\\ 1\\ \\ 0^T\\ 0\\ \\ {-u}X^T\\ {-u}] \\, c = 0, \\qquad
   [0^T\\ 0\\ \\ X^T\\ 1\\ \\ {-v}X^T\\ {-v}] \\, c = 0 . $$

After Hartley's normalisation (3D points and pixels translated to their centroid and
scaled to an RMS distance of `sqrt(3)` and `sqrt(2)`: `X~ = T3 X`, `u~ = T2 u`), the
stacked `2N x 12` system `A c~ = 0` is solved by SVD (`c~` the right singular vector of
the smallest singular value) and `C = T2^{-1} C~ T3`.

**Refinement (Eq. 8).** Levenberg-Marquardt (optimistix) minimises the reprojection
error in pixels over the 11 degrees of freedom of `C`: the chart
`c~(y) = c~_0 + B y`, `y` in `R^11`, `B` the other eleven right singular vectors (an
orthonormal basis of the complement of `c~_0`), which is regular at and around the
linear estimate and fixes the free scale.

**Degenerate layouts are reported, not solved silently** (`CalibrationStatus`). From the
eigenvalues `l1 >= l2 >= l3` of the normalised points' scatter matrix:
`sqrt(l2 / l1) < flat_tol` (collinear points): `DEGENERATE_MODEL`;
`sqrt(l3 / l1) < flat_tol` (coplanar points: a plane only determines a homography, 8 of
the 11 unknowns): `COPLANAR_POINTS`; fewer than six pairs: `TOO_FEW_POINTS`; and a
second-smallest singular value below `sqrt(eps)` times the largest (a critical
configuration, more than one null direction): `UNDETERMINED_CAMERA`. The camera returned
with such a status is finite but not to be used.

`dlt` and `calibrate` are pure JAX for ONE set of pairs, with an optional mask for fixed
shapes (batch with `jax.vmap`); `simulate_led_pairs` and `calibrate_with_robot` are numpy
helpers that play the paper's procedure with the robot model.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import numpy.typing as npt
from jaxtyping import Array, ArrayLike, Bool, Float, Int, Real

from ..geometry._camera import normalize_camera, project, project_with_depth
from ..geometry._numerics import as_float, by_precision, masked_centroid, safe_sqrt
from ..geometry._validate import no_type_check
from ..solvers._status import StatusCode
from ._robot import Robot, forward_kinematics

__all__ = [
    "Calibration",
    "CalibrationStatus",
    "LedPairs",
    "calibrate",
    "calibrate_with_robot",
    "dlt",
    "led_joint_grid",
    "simulate_led_pairs",
]


class CalibrationStatus(StatusCode):
    """Whether the pairs determine a camera (`Calibration.status`). The codes it shares
    with the solvers' `Status` have the same values."""

    OK = 0, "calibrated"
    NONLINEAR_NOT_CONVERGED = 4, "Levenberg-Marquardt did not converge"
    DEGENERATE_MODEL = 9, "the 3D points are (nearly) collinear"
    TOO_FEW_POINTS = 10, "fewer than six valid 3D-2D pairs"
    NOT_FINITE = 11, "non-finite values in the input or during solving"
    COPLANAR_POINTS = (
        16,
        "the 3D points are (nearly) coplanar: they do not determine a 3x4 camera matrix",
    )
    UNDETERMINED_CAMERA = (
        17,
        "the 3D-2D pairs do not determine the camera matrix (the DLT system has more than "
        "one null direction)",
    )


class Calibration(NamedTuple):
    """An estimated camera.

    **Fields:**
    - `camera`: `(3, 4)` the matrix `C`, normalised (`||m3|| = 1`, `det M > 0`, so that
      `c3 . [X 1]` is the depth of `X`); finite, but meaningless unless `status` is `OK`.
    - `error`: `()` Eq. 8 reprojection error (RMS, px) of `camera` over the used pairs.
    - `dlt_error`: `()` the same for the linear (DLT) estimate.
    - `steps`: `()` int32 Levenberg-Marquardt steps taken (0 without refinement).
    - `status`: `()` int32 `CalibrationStatus`: `OK`, `TOO_FEW_POINTS`, `DEGENERATE_MODEL`
      (collinear points), `COPLANAR_POINTS`, `UNDETERMINED_CAMERA`,
      `NONLINEAR_NOT_CONVERGED` or `NOT_FINITE`.

    JAX arrays from `calibrate`; numpy arrays from `calibrate_with_robot`.
    """

    camera: Float[Array | np.ndarray, "3 4"]
    error: Float[Array | np.ndarray, ""]
    dlt_error: Float[Array | np.ndarray, ""]
    steps: Int[Array | np.ndarray, ""]
    status: Int[Array | np.ndarray, ""]


class _Linear(NamedTuple):
    camera_n: Float[Array, "3 4"]  # in normalised coordinates, unit Frobenius norm
    basis: Float[Array, "12 11"]  # orthonormal complement of vec(camera_n)
    T3: Float[Array, "4 4"]
    T2: Float[Array, "3 3"]
    points_n: Float[Array, "n 3"]
    pixels_n: Float[Array, "n 2"]
    scale2: Float[Array, ""]  # pixels_n = scale2 (pixels - centroid)
    status: Int[Array, ""]


# --------------------------------------------------------------------------- helpers


def _similarity(x, w):
    """Hartley's normalising similarity of points `x` (n, d) weighted by `w` (n,):
    centroid to the origin, RMS distance `sqrt(d)`. Returns `(T (d+1, d+1), scale)`."""
    d = x.shape[1]
    count = jnp.maximum(jnp.sum(w), 1)
    mean = masked_centroid(x, w)
    ms = jnp.sum(jnp.sum((x - mean[None, :]) ** 2, axis=1) * w) / count
    ok = ms > 0
    scale = jnp.where(ok, math.sqrt(d) / jnp.sqrt(jnp.where(ok, ms, 1)), 1)
    T = jnp.eye(d + 1, dtype=x.dtype) * scale
    T = T.at[:d, d].set(-scale * mean).at[d, d].set(1)
    return T, scale


def _check_inputs(points, pixels, mask):
    points, pixels = as_float(points, pixels)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must have shape (n, 3), got {tuple(points.shape)}")
    if pixels.shape != (points.shape[0], 2):
        raise ValueError(
            f"pixels must have shape ({points.shape[0]}, 2) to match points, got "
            f"{tuple(pixels.shape)}"
        )
    n = points.shape[0]
    if mask is None:
        mask = jnp.ones(n, dtype=bool)
    mask = jnp.asarray(mask, dtype=bool)
    if mask.shape != (n,):
        raise ValueError(f"mask must have shape ({n},), got {tuple(mask.shape)}")
    return points, pixels, mask


def _linear(points, pixels, mask, flat_tol) -> _Linear:
    dtype = points.dtype
    finite = jnp.all(jnp.isfinite(points)) & jnp.all(jnp.isfinite(pixels))
    points = jnp.where(finite, points, 0)
    pixels = jnp.where(finite, pixels, 0)
    w = mask.astype(dtype)
    T3, _ = _similarity(points, w)
    T2, scale2 = _similarity(pixels, w)
    Xn = points @ T3[:3, :3].T + T3[None, :3, 3]
    un = pixels @ T2[:2, :2].T + T2[None, :2, 2]

    # Layout: eigenvalues of the normalised scatter (ascending).
    count = jnp.maximum(jnp.sum(w), 1)
    scatter = (Xn * w[:, None]).T @ Xn / count
    lam = jnp.maximum(jnp.linalg.eigvalsh(scatter), 0)
    top = jnp.where(lam[2] > 0, lam[2], 1)
    collinear = jnp.sqrt(lam[1] / top) < flat_tol
    coplanar = jnp.sqrt(lam[0] / top) < flat_tol

    Xh = jnp.concatenate([Xn, jnp.ones_like(Xn[:, :1])], axis=1)
    zero = jnp.zeros_like(Xh)
    r1 = jnp.concatenate([Xh, zero, -un[:, :1] * Xh], axis=1)
    r2 = jnp.concatenate([zero, Xh, -un[:, 1:] * Xh], axis=1)
    A = jnp.stack([r1, r2], axis=1).reshape(-1, 12) * jnp.repeat(w, 2)[:, None]
    if A.shape[0] < 12:  # static: pad so that the SVD always returns all 12 directions
        A = jnp.concatenate([A, jnp.zeros((12 - A.shape[0], 12), dtype)], axis=0)
    _, s, Vt = jnp.linalg.svd(A, full_matrices=False)
    c = Vt[-1]
    undetermined = s[10] <= jnp.sqrt(jnp.finfo(dtype).eps) * s[0]

    status = jnp.select(
        [~finite, jnp.sum(mask) < 6, collinear, coplanar, undetermined],
        [
            CalibrationStatus.NOT_FINITE,
            CalibrationStatus.TOO_FEW_POINTS,
            CalibrationStatus.DEGENERATE_MODEL,
            CalibrationStatus.COPLANAR_POINTS,
            CalibrationStatus.UNDETERMINED_CAMERA,
        ],
        CalibrationStatus.OK,
    ).astype(jnp.int32)
    return _Linear(c.reshape(3, 4), Vt[:11].T, T3, T2, Xn, un, scale2, status)


def _denormalise(lin: _Linear, Cn):
    return jnp.linalg.solve(lin.T2, Cn @ lin.T3)


def _rms(residuals, mask):
    count = jnp.maximum(jnp.sum(mask), 1)
    ss = jnp.sum(jnp.where(mask[:, None], residuals, 0) ** 2) / count
    return safe_sqrt(ss)


def _residual(y, args):
    """Pixel residuals of the chart point `y` (11,), masked, flattened (2n,)."""
    lin, mask = args
    Cn = (lin.camera_n.reshape(-1) + lin.basis @ y).reshape(3, 4)
    r = (project(Cn, lin.points_n) - lin.pixels_n) / lin.scale2
    return jnp.where(mask[:, None], r, 0).reshape(-1)


def _finish(C, error, dlt_error, steps, status):
    dtype = C.dtype
    ok = jnp.all(jnp.isfinite(C)) & jnp.isfinite(error)
    C = jnp.where(ok, normalize_camera(jnp.where(ok, C, 0)), jnp.eye(3, 4, dtype=dtype))
    status = jnp.where(ok, status, CalibrationStatus.NOT_FINITE).astype(jnp.int32)
    big = jnp.finfo(dtype).max
    return Calibration(
        camera=C,
        error=jnp.where(ok, error, big),
        dlt_error=jnp.where(jnp.isfinite(dlt_error), dlt_error, big),
        steps=jnp.asarray(steps, jnp.int32),
        status=status,
    )


# --------------------------------------------------------------------------- public


# `dlt` and `calibrate` check their arguments' shapes themselves (a `ValueError` naming
# the argument): no run-time type check comes before theirs.
@no_type_check
def dlt(
    points: Real[ArrayLike, "n 3"],
    pixels: Real[ArrayLike, "n 2"],
    mask: Bool[ArrayLike, " n"] | None = None,
    *,
    flat_tol: float = 1e-3,
) -> Calibration:
    """The linear (DLT) estimate of the camera matrix from 3D-2D pairs, Hartley-normalised.

    **Arguments:**
    - `points`: `(n, 3)` world points (e.g. the LED positions), `n >= 6` used.
    - `pixels`: `(n, 2)` their image points.
    - `mask`: optional `(n,)` bool, which pairs to use (fixed shapes with padding).
    - `flat_tol`: layout tolerance on the normalised points' thickness ratios
      `sqrt(l2 / l1)` (collinear) and `sqrt(l3 / l1)` (coplanar); see the module docstring.

    **Returns:** a `Calibration` (`steps = 0`, `error = dlt_error`).

    **Raises:** `ValueError` naming the argument for inconsistent shapes.
    """
    points, pixels, mask = _check_inputs(points, pixels, mask)
    lin = _linear(points, pixels, mask, flat_tol)
    C = _denormalise(lin, lin.camera_n)
    error = _rms(_residual(jnp.zeros(11, points.dtype), (lin, mask)).reshape(-1, 2), mask)
    return _finish(C, error, error, 0, lin.status)


@no_type_check
def calibrate(
    points: Real[ArrayLike, "n 3"],
    pixels: Real[ArrayLike, "n 2"],
    mask: Bool[ArrayLike, " n"] | None = None,
    *,
    flat_tol: float = 1e-3,
    rtol: float | None = None,
    atol: float | None = None,
    gtol: float | None = None,
    max_steps: int = 100,
) -> Calibration:
    """The camera matrix from 3D-2D pairs: DLT, then Levenberg-Marquardt on Eq. 8.

    $$ \\min_{C} \\sqrt{\\frac{1}{N} \\sum_i \\| \\pi(C, X_i) - (u_i, v_i) \\|^2} $$

    over the 11 degrees of freedom of `C` (see the module docstring), started from the
    DLT estimate. Pure JAX for one set of pairs (`jit`, `vmap`).

    **Arguments:**
    - `points`, `pixels`, `mask`, `flat_tol`: as `dlt`.
    - `rtol`, `atol`: optimistix's tolerances (default `1e-10` / `1e-12` in float64,
      `1e-5` / `1e-6` in float32).
    - `gtol`: stationarity test at the end, as `jaxpose.solvers.nonlinear` (default `1e-6` in
      float64, `1e-2` in float32); an exact fit (error below `sqrt(eps)` times the
      pixels' spread) counts as converged.
    - `max_steps`: Levenberg-Marquardt's iteration budget.

    **Returns:** a `Calibration`; the refined camera is kept only if its error is not
    above the DLT's. Status `NONLINEAR_NOT_CONVERGED` when the refinement did not
    converge (the better of the two cameras is still returned).

    **Raises:** `ValueError` naming the argument for inconsistent shapes.
    """
    import optimistix as optx  # imported when first used (see `solvers._optimistix`)

    from ..solvers._optimistix import lm_solver

    points, pixels, mask = _check_inputs(points, pixels, mask)
    dtype = points.dtype
    rtol = by_precision(dtype, f64=1e-10, f32=1e-5) if rtol is None else rtol
    atol = by_precision(dtype, f64=1e-12, f32=1e-6) if atol is None else atol
    gtol = by_precision(dtype, f64=1e-6, f32=1e-2) if gtol is None else gtol
    lin = _linear(points, pixels, mask, flat_tol)
    args = (lin, mask)
    y0 = jnp.zeros(11, dtype)
    dlt_error = _rms(_residual(y0, args).reshape(-1, 2), mask)
    sol = optx.least_squares(
        _residual, lm_solver(rtol, atol), y0, args, max_steps=max_steps, throw=False
    )
    y = jnp.where(jnp.all(jnp.isfinite(sol.value)), sol.value, y0)
    r = _residual(y, args)
    error = _rms(r.reshape(-1, 2), mask)
    J = jax.jacfwd(_residual)(y, args)
    tiny = jnp.finfo(dtype).tiny ** 0.5
    cosine = jnp.abs(J.T @ r) / (jnp.linalg.norm(J, axis=0) * jnp.linalg.norm(r) + tiny)
    exact = error <= jnp.sqrt(jnp.finfo(dtype).eps) / lin.scale2
    stopped = (sol.result == optx.RESULTS.successful) | (
        sol.result == optx.RESULTS.nonlinear_max_steps_reached
    )
    converged = stopped & ((jnp.max(cosine) < gtol) | exact)
    better = error <= dlt_error
    y = jnp.where(better, y, y0)
    error = jnp.where(better, error, dlt_error)
    Cn = (lin.camera_n.reshape(-1) + lin.basis @ y).reshape(3, 4)
    status = jnp.where(
        (lin.status == CalibrationStatus.OK) & ~converged,
        CalibrationStatus.NONLINEAR_NOT_CONVERGED,
        lin.status,
    )
    return _finish(_denormalise(lin, Cn), error, dlt_error, sol.stats["num_steps"], status)


# --------------------------------------------------------------------------- with the robot


class LedPairs(NamedTuple):
    """Simulated calibration pairs from the robot's LED (numpy).

    **Fields:**
    - `joints`: `(N, 4)` the joint commands.
    - `points`: `(N, 3)` LED positions by forward kinematics (world frame, mm), with the
      robot's positioning noise if any.
    - `pixels`: `(N, 2)` their detections: projections plus Gaussian noise (px).
    - `visible`: `(N,)` bool, the LED is in front of the camera and inside the image.
    """

    joints: np.ndarray
    points: np.ndarray
    pixels: np.ndarray
    visible: np.ndarray


def led_joint_grid(
    robot: Robot,
    *,
    centre: tuple[float, float] = (0.0, 0.0),
    spread: float = 80.0,
    tilts_deg: tuple[float, ...] = (25.0, 45.0, 65.0),
    pans: int = 4,
) -> np.ndarray:
    """A joint grid for calibration: the carriage on a 3 x 3 grid `centre +- spread`
    (mm, base frame), and at each carriage position every tilt in `tilts_deg` at `pans`
    pan angles evenly around the circle. The LED heights then span
    `h - L cos(tilt)`, so the points are not coplanar.

    **Returns:** numpy `(9 * len(tilts_deg) * pans, 4)` joint vectors, clipped to the
    robot's limits.
    """
    if pans < 1:
        raise ValueError(f"pans must be >= 1, got {pans}")
    if not tilts_deg:
        raise ValueError("tilts_deg must not be empty")
    offsets = np.array([-1.0, 0.0, 1.0]) * spread
    pan_angles = np.arange(pans) * (2 * np.pi / pans) - np.pi + np.pi / pans
    rows = [
        (centre[0] + dx, centre[1] + dy, pan, np.radians(tilt))
        for dx in offsets
        for dy in offsets
        for tilt in tilts_deg
        for pan in pan_angles
    ]
    q = np.asarray(rows, dtype=np.float64)
    return np.clip(q, np.asarray(robot.lower), np.asarray(robot.upper))


_fk_batch = jax.jit(jax.vmap(forward_kinematics, in_axes=(None, 0)))
_project_with_depth = jax.jit(project_with_depth)


def simulate_led_pairs(
    robot: Robot,
    camera: npt.ArrayLike,
    joints: npt.ArrayLike,
    *,
    noise: float = 0.0,
    position_noise: float = 0.0,
    seed: int = 0,
    image_size: tuple[int, int] | None = None,
) -> LedPairs:
    """The paper's calibration procedure, simulated: move the LED by forward kinematics
    of each joint vector and detect it in the image of the (true) `camera`.

    **Arguments:**
    - `robot`: the `Robot`.
    - `camera`: `(3, 4)` the true camera.
    - `joints`: `(N, 4)` joint commands (e.g. `led_joint_grid(robot)`).
    - `noise`: Gaussian detection noise (px, per coordinate).
    - `position_noise`: Gaussian error of the LED's real position around the commanded
      one (mm, per coordinate): the robot's own inaccuracy.
    - `seed`: the noise's seed.
    - `image_size`: `(width, height)`; LEDs outside it are not visible. `None`: no
      bounds (only in front of the camera).

    **Returns:** `LedPairs` (the commanded positions as `points`; the detections of the
    real ones as `pixels`).

    **Raises:** `ValueError` naming the argument for a wrong shape or negative noise.
    """
    q = np.asarray(joints, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != 4:
        raise ValueError(f"joints must have shape (N, 4), got {q.shape}")
    C = np.asarray(camera, dtype=np.float64)
    if C.shape != (3, 4) or not np.all(np.isfinite(C)):
        raise ValueError(f"camera must be a finite 3x4 matrix, got shape {C.shape}")
    if noise < 0 or position_noise < 0:
        raise ValueError(f"noise and position_noise must be >= 0, got {noise}, {position_noise}")
    rng = np.random.default_rng(seed)
    r = Robot(*(np.asarray(x, np.float64) for x in robot))
    with jax.enable_x64(True):
        points = np.asarray(_fk_batch(r, q).tip, np.float64)
        real = points + rng.normal(scale=position_noise, size=points.shape)
        uv, depth = _project_with_depth(C, real)
        uv, depth = np.asarray(uv, np.float64), np.asarray(depth, np.float64)
    visible = depth > 0
    if image_size is not None:
        w, h = image_size
        visible &= (uv[:, 0] >= 0) & (uv[:, 0] <= w) & (uv[:, 1] >= 0) & (uv[:, 1] <= h)
    pixels = uv + rng.normal(scale=noise, size=uv.shape)
    return LedPairs(q, points, pixels, visible)


_calibrate_jit = jax.jit(calibrate)


def calibrate_with_robot(
    robot: Robot,
    camera: npt.ArrayLike,
    joints: npt.ArrayLike | None = None,
    *,
    noise: float = 0.5,
    position_noise: float = 0.0,
    seed: int = 0,
    image_size: tuple[int, int] | None = None,
) -> tuple[Calibration, LedPairs]:
    """Simulate the paper's robot calibration end to end and estimate the camera.

    `simulate_led_pairs` (default joints: `led_joint_grid(robot)`), then `calibrate` on
    the visible pairs (float64).

    **Returns:** `(calibration, pairs)`; compare `calibration.camera` with the true
    `camera` (e.g. by `jaxpose.geometry.decompose_camera` or reprojection).
    """
    if joints is None:
        joints = led_joint_grid(robot)
    pairs = simulate_led_pairs(
        robot,
        camera,
        joints,
        noise=noise,
        position_noise=position_noise,
        seed=seed,
        image_size=image_size,
    )
    with jax.enable_x64(True):
        cal = _calibrate_jit(pairs.points, pairs.pixels, pairs.visible)
        cal = Calibration(*(np.asarray(x) for x in cal))
    return cal, pairs
