"""The small-movement linear method (the paper's Section 2.2, Eqs. 3-7).

A small motion moves every world point by `dp = t + r x p` (Eq. 3, rotation vector `r`).
Put into the two visual-ray planes of each match (Eq. 5) it gives two linear equations
in `x = (t, r)` per match (Eq. 7):

    n_k . t + (p x n_k) . r = -(n_k . p + a_k),      k = 1, 2.

The 2N x 6 stack `A x = B` is solved by least squares, the motion applied exactly
(`R <- Rot(r) R`), and the step repeated.

Two weightings of the rows:
- `"depth"` (default): each row divided by the current depth `s_i = c3 . [p_i 1]`, so
  that the right-hand side is the pixel residual of Eq. 8 (`n_k . p + a_k = s (u^ - u)`),
  and with the normal taken at the *reprojected* pixel, `n^_1 = c1[:3] - u^ c3[:3]`
  (`n^_1 = n_1 - (u^ - u) c3[:3]`; likewise for `v`). That row is the exact derivative of
  the pixel residual, so the iteration is Gauss-Newton on Eq. 8 and its fixed point is
  exactly the Eq. 8 optimum. (Keeping the observed pixel's normal `n_k` drops a term of
  relative size `(u^ - u) / f`: the fixed point then misses the optimum by about 1e-5 px
  on the bench.)
- `"raw"`: the paper's rows as written. They weight each match by its depth, so the
  fixed point minimises the depth-weighted error (equal to Eq. 8's only when all depths
  are equal).

Implementation notes: the rotation is taken about the centroid `p_c` of the current
world points (`dp = t' + r x (p - p_c)`, the same motion with `t' = t + r x p_c`), and
the columns are equilibrated before the 6x6 normal equations are solved; both keep the
system well conditioned in float32.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from ..geometry._numerics import by_precision, masked_centroid
from ..geometry._pose import Observations, Pose, transform
from ..geometry._rotation import rotvec_to_matrix
from ._linalg import cholesky_solve
from ._residuals import depths, final_status, plane_residuals, safe_inverse_depth
from ._status import Status

__all__ = ["LinearResult", "default_tol", "linear", "linear_step"]


class LinearResult(NamedTuple):
    """**Fields:** `pose`; `error` (Eq. 8, px); `step` (size of the last step: rotation in
    rad plus translation relative to the object's size); `status` (`OK`,
    `LINEAR_NOT_CONVERGED`, `BEHIND_CAMERA`, `TOO_FEW_POINTS` or `NOT_FINITE`)."""

    pose: Pose
    error: Float[Array, ""]
    step: Float[Array, ""]
    status: Int[Array, ""]


def default_tol(dtype) -> float:
    """Convergence tolerance on the last step (rad + relative translation) for a dtype.

    Near the optimum the iteration converges quadratically (Gauss-Newton with a small
    residual), so a last step of `1e-4` leaves the pose about `1e-8` from the fixed point.
    """
    return by_precision(dtype, f64=1e-4, f32=1e-3)


def linear_step(pose: Pose, obs: Observations, weighting: str = "depth"):
    """One small-movement step (Eq. 7) from `pose`. Returns `(new_pose, step_size)`."""
    world = transform(pose, obs.model)
    centre = masked_centroid(world, obs.mask)
    normals = obs.planes[..., :3]  # (n, 2, 3)
    rhs = -plane_residuals(world, obs)  # (n, 2)
    if weighting == "depth":
        w = safe_inverse_depth(depths(world, obs))
        pixel = rhs * w[:, None]  # -(u^ - u, v^ - v)
        normals = normals + pixel[:, :, None] * obs.camera[2, :3][None, None, :]
    elif weighting == "raw":
        w = jnp.ones(obs.model.shape[0], dtype=world.dtype)
    else:
        raise ValueError(f"weighting must be 'depth' or 'raw', got {weighting!r}")
    arm = (world - centre[None, :])[:, None, :]  # (n, 1, 3)
    rows = jnp.concatenate([normals, jnp.cross(arm, normals)], axis=-1)  # (n, 2, 6)
    w = jnp.where(obs.mask, w, 0)
    A = (rows * w[:, None, None]).reshape(-1, 6)
    b = (rhs * w[:, None]).reshape(-1)
    # Column equilibration, then the 6x6 normal equations by an unrolled Cholesky (its
    # pivot floor keeps a rank-deficient system finite; such problems are flagged by the
    # caller).
    scale = jnp.sqrt(jnp.sum(A * A, axis=0))
    scale = jnp.where(scale > 0, scale, 1)
    As = A / scale[None, :]
    x = cholesky_solve(As.T @ As, As.T @ b) / scale
    x = jnp.where(jnp.isfinite(x), x, 0)
    dt, r = x[:3], x[3:]
    Rr = rotvec_to_matrix(r)
    new = Pose(Rr @ pose.R, Rr @ (pose.t - centre) + centre + dt)
    size = jnp.sqrt(
        jnp.sum(jnp.where(obs.mask[:, None], (world - centre[None, :]) ** 2, 0))
        / jnp.maximum(jnp.sum(obs.mask), 1)
    )
    size = jnp.where(size > 0, size, 1)
    step = jnp.linalg.norm(r) + jnp.linalg.norm(dt) / size
    return new, step


def linear(
    obs: Observations,
    init: Pose,
    *,
    iterations: int = 5,
    weighting: str = "depth",
    tol: float | None = None,
) -> LinearResult:
    """The small-movement linear method from `init`, for one problem.

    **Arguments:**
    - `obs`: the problem (`jaxpose._pose.observations`).
    - `init`: starting pose (the paper starts from the three-point pose).
    - `iterations`: fixed number of steps (the paper: 2-3 suffice from a good start).
    - `weighting`: `"depth"` (default, fixed point = Eq. 8 optimum) or `"raw"` (the paper's
      rows as written); see the module docstring.
    - `tol`: the last step must be below this (rad + relative translation) for the method
      to count as converged; default `1e-4` in float64 and `1e-3` in float32.

    **Returns:** a `LinearResult`. Non-convergence (a large last step, the "sticky point"
    far from the optimum) and points behind the camera are reported in `status`.
    """
    dtype = obs.camera.dtype
    if tol is None:
        tol = default_tol(dtype)

    def body(_, carry):
        pose, _ = carry
        return linear_step(pose, obs, weighting)

    init = Pose(jnp.asarray(init.R, dtype), jnp.asarray(init.t, dtype))
    start = (init, jnp.asarray(jnp.finfo(dtype).max, dtype))
    pose, step = jax.lax.fori_loop(0, iterations, body, start)
    pose, error, status = final_status(obs, pose, step < tol, Status.LINEAR_NOT_CONVERGED)
    step = jnp.where(jnp.isfinite(step), step, jnp.finfo(dtype).max)
    return LinearResult(pose, error, step, status)
