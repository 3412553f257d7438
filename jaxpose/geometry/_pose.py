"""The pose type and the per-problem observation bundle shared by every solver."""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from ._camera import normalize_camera, ray_planes

__all__ = ["Observations", "Pose", "observations", "transform"]


class Pose(NamedTuple):
    """Rigid motion mapping model to world: `p = R m + t`.

    **Fields:** `R` rotation matrix `(3, 3)`; `t` translation `(3,)` in model units.
    """

    R: Float[Array, "3 3"]
    t: Float[Array, " 3"]

    @classmethod
    def identity(cls, dtype=jnp.float64) -> Pose:
        return cls(jnp.eye(3, dtype=dtype), jnp.zeros(3, dtype=dtype))


def transform(pose: Pose, points: Float[Array, "n 3"]) -> Float[Array, "n 3"]:
    """World coordinates `R m + t` of model points `m`."""
    return points @ pose.R.T + pose.t[None, :]


class Observations(NamedTuple):
    """One pose problem, precomputed for the solvers.

    **Fields:**
    - `camera`: `C` `(3, 4)`, normalised so that `c3 . [p 1]` is the depth in front.
    - `model`: model points `(n, 3)`.
    - `image`: pixels `(n, 2)`.
    - `mask`: `(n,)` bool, which matches take part (fixed shapes: padding is masked out).
    - `planes`: the visual-ray planes of Eq. 5 as homogeneous rows `(n, 2, 4)`:
      `planes[i, k] . [p 1] = 0` exactly when `p` is on the ray of pixel `i`.
    """

    camera: Float[Array, "3 4"]
    model: Float[Array, "n 3"]
    image: Float[Array, "n 2"]
    mask: Bool[Array, " n"]
    planes: Float[Array, "n 2 4"]


def observations(camera, model, image, mask=None) -> Observations:
    """Bundle one problem (normalising the camera and computing its ray planes)."""
    camera = normalize_camera(jnp.asarray(camera))
    model = jnp.asarray(model, dtype=camera.dtype)
    image = jnp.asarray(image, dtype=camera.dtype)
    if mask is None:
        mask = jnp.ones(model.shape[0], dtype=bool)
    n1, a1, n2, a2 = ray_planes(camera, image)
    planes = jnp.stack(
        [jnp.concatenate([n1, a1[:, None]], axis=1), jnp.concatenate([n2, a2[:, None]], axis=1)],
        axis=1,
    )
    return Observations(camera, model, image, jnp.asarray(mask, dtype=bool), planes)
