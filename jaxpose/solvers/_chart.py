"""The local chart around a pose, shared by Levenberg-Marquardt, the pose covariance and
the implicit derivative of the answer.

Around a pose `(R^, t^)`, with `c` the centroid of its masked world points `R^ m_i + t^`
and `L` their RMS radius, the chart coordinates `xi = (w, u)` give

    R = Rot(w) R^,      p_i = Rot(w) (R^ m_i + t^ - c) + c + L u,

a rotation about the centroid and a translation in units of the object's size. At
`xi = 0` the pose is `(R^, t^)`; rotation and translation are decoupled, and all six
coordinates have comparable units whatever the object's size, so one tolerance means the
same for every object. `Rot` is the rotation vector's map (`rotvec_to_matrix`) by
default; Levenberg-Marquardt uses the paper's quaternion vector part
(`quaternion_vector_to_matrix`), regular within 180 degrees of the chart's pose.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from ..geometry._numerics import masked_centroid, masked_mean
from ..geometry._pose import Observations, Pose, transform
from ..geometry._rotation import rotvec_to_matrix
from ._residuals import pixel_residuals

__all__ = ["Chart", "chart_at", "chart_points", "chart_pose", "chart_residuals"]


class Chart(NamedTuple):
    """The chart around `pose`: the centroid `centre` of its masked world points and
    their RMS radius `length` (`1` when they all coincide)."""

    pose: Pose
    centre: Float[Array, " 3"]
    length: Float[Array, ""]


def chart_at(pose: Pose, obs: Observations, world: Float[Array, "n 3"] | None = None) -> Chart:
    """The chart around `pose` for the masked matches of `obs` (`world`: the world points
    `transform(pose, obs.model)` when already at hand)."""
    if world is None:
        world = transform(pose, obs.model)
    return _chart(pose, world, obs.mask)


def _chart(pose: Pose, world: Float[Array, "n 3"], mask: Bool[Array, " n"]) -> Chart:
    centre = masked_centroid(world, mask)
    spread = masked_mean(jnp.sum((world - centre[None, :]) ** 2, axis=1), mask)
    positive = spread > 0
    length = jnp.where(positive, jnp.sqrt(jnp.where(positive, spread, 1)), 1)
    return Chart(pose, centre, length)


def chart_pose(xi: Float[Array, " 6"], chart: Chart, rotation: Callable = rotvec_to_matrix) -> Pose:
    """The pose at chart coordinates `xi = (w, u)`: exactly the chart's pose at `xi = 0`."""
    Rw = rotation(xi[:3])
    R = Rw @ chart.pose.R
    # t^ + (Rw - I)(t^ - c) + L u: exactly t^ at xi = 0.
    arm = chart.pose.t - chart.centre
    t = chart.pose.t + (Rw @ arm - arm) + chart.length * xi[3:]
    return Pose(R, t)


def chart_points(
    xi: Float[Array, " 6"],
    chart: Chart,
    world: Float[Array, "n 3"],
    rotation: Callable = rotvec_to_matrix,
) -> Float[Array, "n 3"]:
    """The world points at chart coordinates `xi`, moved from the chart pose's own
    `world` points (cheaper than through `chart_pose` where the model is fixed, as in
    Levenberg-Marquardt's iterations)."""
    Rw = rotation(xi[:3])
    return (world - chart.centre[None, :]) @ Rw.T + (chart.centre + chart.length * xi[3:])[None, :]


def chart_residuals(
    xi: Float[Array, " 6"], chart: Chart, obs: Observations
) -> Float[Array, " two_n"]:
    """Eq. 8's pixel residuals `(2n,)` at chart coordinates `xi` (zero where masked),
    through `chart_pose` (so differentiable with respect to `obs`, the model included)."""
    return pixel_residuals(transform(chart_pose(xi, chart), obs.model), obs).reshape(-1)
