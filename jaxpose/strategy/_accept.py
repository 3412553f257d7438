"""The acceptance rule of the mixed algorithm (the paper's Section 3, steps 2 and 4), in
one place: every method, cascade and fallback of `jaxpose.strategy` accepts a pose by it.

A pose is accepted when its run converged and its Eq. 8 error is below the problem's
threshold. The threshold is `Options.threshold` (px; the paper's, given by the
recognition system), or, with `threshold=None`, adaptive: `(1 + rel_threshold)` times the
lowest converged error of the problem's candidates ("reached the best pose found"), never
below the rounding level of exact data (`jaxpose.solvers._residuals.rounding_level`);
a problem with no converged candidate gets no finite threshold (its fallback decides).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from ..geometry._pose import Observations
from ..solvers._residuals import rounding_level
from ._options import Options

__all__ = ["accepts", "threshold"]


def threshold(obs: Observations, best: Float[Array, "*B"], options: Options) -> Float[Array, "*B"]:
    """Each problem's acceptance threshold (px) from `best`, the lowest converged error of
    its candidates (the largest float where none converged).

    **Arguments:** `obs`, one problem or a batch (leading axes `*B`, as `best`);
    `options` (read: `threshold`, `rel_threshold`).
    """
    dtype = best.dtype
    if options.threshold is not None:
        return jnp.full_like(best, options.threshold)
    big = jnp.finfo(dtype).max
    floor = rounding_level
    for _ in range(best.ndim):
        floor = jax.vmap(floor)
    level = floor(obs).astype(dtype)
    return jnp.where(best < big, jnp.maximum(best * (1 + options.rel_threshold), level), big)


def accepts(
    converged: Bool[Array, "*S"], error: Float[Array, "*S"], thr: Float[Array, "*#S"]
) -> Bool[Array, "*S"]:
    """The rule itself: converged, with an Eq. 8 error below the threshold."""
    return converged & (error < thr)
