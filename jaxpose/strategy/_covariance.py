"""First-order uncertainty of a pose.

A pose `(R^, t^)` is perturbed in the parameterisation

    R = exp(hat(w)) R^,      t = t^ + dt,      vector order (w, dt),

`w` a rotation vector in radians (a rotation of the world frame, applied after `R^`) and
`dt` a translation in model units. The Gauss-Newton covariance of Eq. 8's pixel
residuals `r` (2n, zero for masked matches) at the pose is

    Sigma = sigma^2 (J^T J)^+,      J = dr / d(w, dt) at (0, 0),

with `sigma` the standard deviation of the pixel noise (per coordinate), given or
estimated from the residual sum of squares as `sqrt(RSS / (2n - 6))`.

Internally the Jacobian is taken in a better-conditioned chart that rotates about the
centroid `c` of the world points and scales the translation by their RMS radius `L`
(`jaxpose.solvers._chart`, shared with the gradients of `jaxpose.solve`),

    p_i = exp(hat(w)) (R^ m_i + t^ - c) + c + L u,

the same pose as `(w, dt)` with `dt = L u - hat(t^ - c) w` to first order; the
covariance is mapped back exactly by that linear map.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float, Int, Real

from ..geometry._pose import Pose, observations
from ..geometry._rotation import hat
from ..solvers._chart import Chart, chart_at, chart_residuals
from ..solvers._linalg import symmetric_pinv

__all__ = ["PoseCovariance", "pose_covariance"]


class PoseCovariance(NamedTuple):
    """A pose's first-order uncertainty.

    **Fields:**
    - `covariance`: `(6, 6)` covariance of `(w, dt)`, `R = exp(hat(w)) R^`, `t = t^ + dt`
      (rad and model units). In directions the matches do not determine (`rank < 6`) it
      is the pseudo-inverse's: zero there, finite everywhere.
    - `sigma`: the pixel noise standard deviation used (given, or estimated; `0` when it
      is to be estimated but there is no redundancy, `2n <= 6`).
    - `rank`: numerical rank of the `(2n, 6)` residual Jacobian (`6` when the matches
      determine the pose).
    """

    covariance: Float[Array, "6 6"]
    sigma: Float[Array, ""]
    rank: Int[Array, ""]


def _chart_to_pose_params(chart: Chart) -> Float[Array, "6 6"]:
    """The linear map from chart coordinates `(w, u)` to `(w, dt)` at the chart's pose."""
    dtype = chart.centre.dtype
    eye = jnp.eye(3, dtype=dtype)
    zero = jnp.zeros((3, 3), dtype)
    return jnp.block([[eye, zero], [-hat(chart.pose.t - chart.centre), chart.length * eye]])


def pose_covariance(
    camera: Real[ArrayLike, "3 4"],
    model: Real[ArrayLike, "n 3"],
    image: Real[ArrayLike, "n 2"],
    pose: Pose,
    mask: Bool[ArrayLike, " n"] | None = None,
    *,
    sigma: Real[ArrayLike, ""] | None = None,
) -> PoseCovariance:
    """Gauss-Newton covariance of a pose from Eq. 8's pixel residuals at that pose.

    $$ \\Sigma = \\sigma^2 (J^T J)^+, \\qquad J = \\partial r / \\partial (w, dt) $$

    with `R = exp(hat(w)) R^`, `t = t^ + dt` around the given pose `(R^, t^)`, vector
    order `(w, dt)`: `w` in radians (applied on the left, in the world frame), `dt` in
    model units. Valid to first order for independent Gaussian pixel noise of standard
    deviation `sigma` per coordinate, at the Eq. 8 optimum (e.g. `jaxpose.solve(...).pose`).

    Pure JAX for one problem (`jit`, `vmap`, `grad`), NaN-free: a Jacobian that does not
    determine the pose gives the pseudo-inverse (see `PoseCovariance.rank`).

    **Arguments:**
    - `camera`: the 3x4 projection matrix `C`, calibrated in the world frame.
    - `model`: `(n, 3)` model points.
    - `image`: `(n, 2)` pixels matched to them.
    - `pose`: the pose `Pose(R, t)` (model to world) to linearise at.
    - `mask`: optional `(n,)` bool, which matches take part.
    - `sigma`: pixel noise standard deviation (px); `None`: estimated as
      `sqrt(RSS / (2n - 6))` over the `n` masked matches (`0` when `2n <= 6`).

    **Returns:** a `PoseCovariance(covariance, sigma, rank)`.
    """
    obs = observations(camera, model, image, mask)
    dtype = obs.camera.dtype
    pose = Pose(jnp.asarray(pose.R, dtype), jnp.asarray(pose.t, dtype))
    chart = chart_at(pose, obs)
    zero = jnp.zeros(6, dtype)
    r = chart_residuals(zero, chart, obs)
    J = jax.jacfwd(chart_residuals)(zero, chart, obs)
    if sigma is None:
        dof = 2 * jnp.sum(obs.mask) - 6
        rss = jnp.sum(r * r)
        var = jnp.where(dof > 0, rss / jnp.maximum(dof, 1).astype(dtype), 0)
        positive = var > 0
        sigma_ = jnp.where(positive, jnp.sqrt(jnp.where(positive, var, 1)), 0)
    else:
        sigma_ = jnp.asarray(sigma, dtype)
    inv, rank, _ = symmetric_pinv(J.T @ J)
    A = _chart_to_pose_params(chart)
    cov = sigma_**2 * (A @ inv @ A.T)
    return PoseCovariance(0.5 * (cov + cov.T), sigma_, rank)
