"""Residuals of the pose parameters (layer 2): pure functions `(params, obs) -> (2n,)`.

All three share one fact about the visual-ray planes of Eq. 5: for a point `P = [p 1]`
and a normalised camera (`c3 . P` is the depth `s`),

    n1 . p + a1 = (c1 - u c3) . P = s (u^ - u),      n2 . p + a2 = s (v^ - v),

so the plane residual of Eq. 10 is the pixel residual of Eq. 8 scaled by the depth.

- `rotvec_residual`: `params = (r, t)`, `R = Rot(r)` (Rodrigues), pixel residuals.
- `quaternion_residual`: `params = (q1, q2, q3, a, b, c)`, `q0 = sqrt(1 - |q|^2)`, pixel
  residuals: the paper's non-linear parameterisation.
- `ray_residual`: `params = (r, t)`, the visual-ray (Eq. 10) residuals `n_k . p + a_k`.

Masked matches contribute zeros. Points at zero depth give a finite placeholder.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from ..geometry._pose import Observations, Pose, transform
from ..geometry._rotation import quaternion_vector_to_matrix, rotvec_to_matrix
from ._status import Status

__all__ = [
    "pixel_residuals",
    "plane_residuals",
    "quaternion_residual",
    "ray_residual",
    "rms",
    "rotvec_residual",
]


def _homogeneous(points):
    return jnp.concatenate([points, jnp.ones_like(points[:, :1])], axis=1)


def plane_residuals(world: Float[Array, "n 3"], obs: Observations) -> Float[Array, "n 2"]:
    """Eq. 10: `planes[i, k] . [p_i 1]` for world points `p_i` (zero where masked)."""
    res = jnp.einsum("nkj,nj->nk", obs.planes, _homogeneous(world))
    return jnp.where(obs.mask[:, None], res, 0)


def depths(world: Float[Array, "n 3"], obs: Observations) -> Float[Array, " n"]:
    """Depth `c3 . [p 1]` of world points in front of the (normalised) camera."""
    return world @ obs.camera[2, :3] + obs.camera[2, 3]


def in_front(world: Float[Array, "n 3"], obs: Observations) -> Bool[Array, ""]:
    """Whether every masked world point has positive depth (is in front of the camera)."""
    return jnp.all(jnp.where(obs.mask, depths(world, obs) > 0, True))


def safe_inverse_depth(s):
    """`1 / s`, with a finite placeholder (and a zero gradient) where `s` is ~0."""
    tiny = jnp.finfo(s.dtype).tiny ** 0.5
    ok = jnp.abs(s) > tiny
    return jnp.where(ok, 1 / jnp.where(ok, s, 1), 0)


def pixel_residuals(world: Float[Array, "n 3"], obs: Observations) -> Float[Array, "n 2"]:
    """Eq. 8's residuals `(u^ - u, v^ - v)` of world points (zero where masked)."""
    return plane_residuals(world, obs) * safe_inverse_depth(depths(world, obs))[:, None]


def rounding_level(obs: Observations) -> Float[Array, ""]:
    """The Eq. 8 error (px) below which a pose fits to rounding: `64 eps (1 + max |pixel|)`
    over the used matches (about 1e-11 px in float64, 8e-3 px in float32 for 1000-px
    images). An error below it is an exact fit, a global optimum."""
    eps = jnp.finfo(obs.image.dtype).eps
    return 64 * eps * (1 + jnp.max(jnp.where(obs.mask[:, None], jnp.abs(obs.image), 0)))


def rms(residuals: Float[Array, "n 2"], mask) -> Float[Array, ""]:
    """Eq. 8: `sqrt(mean_i |r_i|^2)` over the masked matches.

    Its gradient is finite at a zero residual (where `sqrt` alone would give NaN). A
    non-finite residual of a used match gives a non-finite error (NaN stays NaN, so that
    callers' finiteness tests see it); masked-out matches are ignored whatever they hold."""
    count = jnp.maximum(jnp.sum(mask), 1)
    ss = jnp.sum(jnp.where(mask[:, None], residuals, 0) ** 2) / count
    ok = ss > 0
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, ss, 1)), jnp.where(ss == 0, 0, ss))


def pose_error(pose: Pose, obs: Observations) -> Float[Array, ""]:
    """Eq. 8 error (RMS px) of one pose over the problem's masked matches."""
    return rms(pixel_residuals(transform(pose, obs.model), obs), obs.mask)


def final_status(
    obs: Observations, pose: Pose, converged: Bool[Array, ""], failure: int
) -> tuple[Pose, Float[Array, ""], Int[Array, ""]]:
    """A solver's final pose, its Eq. 8 error and its status.

    The status is the first that applies of `TOO_FEW_POINTS` (under three matches),
    `NOT_FINITE`, `BEHIND_CAMERA`, `failure` (where `converged` is false) and `OK`. A
    non-finite pose becomes the identity and its error the dtype's largest value, so that
    no NaN leaves the solver.
    """
    dtype = obs.camera.dtype
    world = transform(pose, obs.model)
    error = rms(pixel_residuals(world, obs), obs.mask)
    finite = jnp.isfinite(error) & jnp.all(jnp.isfinite(pose.R)) & jnp.all(jnp.isfinite(pose.t))
    status = jnp.select(
        [jnp.sum(obs.mask) < 3, ~finite, ~in_front(world, obs), ~converged],
        [Status.TOO_FEW_POINTS, Status.NOT_FINITE, Status.BEHIND_CAMERA, failure],
        Status.OK,
    ).astype(jnp.int32)
    pose = jax.tree.map(lambda a, b: jnp.where(finite, a, b), pose, Pose.identity(dtype))
    return pose, jnp.where(finite, error, jnp.finfo(dtype).max), status


@jax.jit
def rotvec_residual(params: Float[Array, " 6"], obs: Observations) -> Float[Array, " two_n"]:
    """Pixel residuals of the pose `R = Rot(params[:3])` (rotation vector), `t = params[3:]`."""
    world = obs.model @ rotvec_to_matrix(params[:3]).T + params[None, 3:]
    return pixel_residuals(world, obs).reshape(-1)


@jax.jit
def quaternion_residual(params: Float[Array, " 6"], obs: Observations) -> Float[Array, " two_n"]:
    """Pixel residuals of the pose `R = R(q0, q1, q2, q3)` with `(q1, q2, q3) = params[:3]`
    and `q0 = sqrt(1 - |q|^2)` (the paper's non-linear parameterisation), `t = params[3:]`."""
    world = obs.model @ quaternion_vector_to_matrix(params[:3]).T + params[None, 3:]
    return pixel_residuals(world, obs).reshape(-1)


@jax.jit
def ray_residual(params: Float[Array, " 6"], obs: Observations) -> Float[Array, " two_n"]:
    """Eq. 10: the visual-ray plane residuals `n_k . (Rot(r) m + t) + a_k`, `params = (r, t)`.

    Equal to the pixel residual times the depth: the paper's linear method zeroes the
    first-order expansion of these.
    """
    world = obs.model @ rotvec_to_matrix(params[:3]).T + params[None, 3:]
    return plane_residuals(world, obs).reshape(-1)
