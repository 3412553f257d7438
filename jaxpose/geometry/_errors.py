"""Error measures of a pose: pixels (the paper's Eq. 8) and the paper's pose error in model units.

A pose `(R, t)` maps model points to the world, `p_i = R m_i + t`; the camera `C`
(3, 4) is calibrated in the world frame (see `jaxpose._camera`). One problem, no batch
axis (`model` (n, 3), `image` (n, 2)); batch with `jax.vmap`.

Every function is pure `jax.numpy`, follows the floating dtype of its inputs, composes
with `jit`, `vmap` and `grad`, and never produces NaN. In particular the square roots
are shimmed so that the gradient at an exact pose (zero residual) is finite (zero).
An optional `mask` (n,) of booleans selects the points that count; an all-False mask
gives 0.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float, Real

from ._camera import backproject, project
from ._numerics import as_float, masked_mean, safe_norm, safe_sqrt
from ._pose import Pose, transform

# The arguments every error measure takes (one problem).
Camera = Real[ArrayLike, "3 4"]
Rotation = Real[ArrayLike, "3 3"]
Translation = Real[ArrayLike, " 3"]
ModelPoints = Real[ArrayLike, "n 3"]
ImagePoints = Real[ArrayLike, "n 2"]
Mask = Bool[ArrayLike, " n"] | None

__all__ = [
    "pose_error",
    "pose_error_per_point",
    "reprojection_residuals",
    "reprojection_rms",
]


def reprojection_residuals(
    C: Camera,
    R: Rotation,
    t: Translation,
    model: ModelPoints,
    image: ImagePoints,
) -> Float[Array, "n 2"]:
    """Pixel residuals of a pose: projection of each posed model point minus its match.

    $$ r_i = \\pi(C, R m_i + t) - (u_i, v_i) $$

    **Arguments:**

    - `C`: camera, shape (3, 4).
    - `R`, `t`: pose (model to world), shapes (3, 3) and (3,).
    - `model`: model points, shape (n, 3).
    - `image`: matched pixels, shape (n, 2).

    **Returns:**

    Residuals, shape (n, 2), in pixels. A posed point on the camera's focal plane
    projects to the finite placeholder of `jaxpose._camera.project` (about `1 / eps`
    pixels), so its residual is huge but finite.
    """
    C, R, t, model, image = as_float(C, R, t, model, image)
    return project(C, transform(Pose(R, t.reshape(3)), model)) - image


def reprojection_rms(
    C: Camera,
    R: Rotation,
    t: Translation,
    model: ModelPoints,
    image: ImagePoints,
    mask: Mask = None,
) -> Float[Array, ""]:
    """Root-mean-square reprojection error of a pose (the paper's Eq. 8), in pixels.

    $$ e = \\sqrt{\\frac{1}{N} \\sum_i (\\hat u_i - u_i)^2 + (\\hat v_i - v_i)^2} $$

    the mean taken over the points selected by `mask` (all of them by default).

    **Arguments:**

    - `C`: camera, shape (3, 4).
    - `R`, `t`: pose (model to world), shapes (3, 3) and (3,).
    - `model`: model points, shape (n, 3).
    - `image`: matched pixels, shape (n, 2).
    - `mask`: optional (n,) bool; the points that count.

    **Returns:**

    Scalar `e`. 0 for an all-False mask (or no points). At `e = 0` the gradient is 0
    (not NaN).
    """
    r = reprojection_residuals(C, R, t, model, image)
    return safe_sqrt(masked_mean(jnp.sum(r * r, axis=1), mask))


def pose_error_per_point(
    C: Camera,
    R: Rotation,
    t: Translation,
    model: ModelPoints,
    image: ImagePoints,
) -> Float[Array, " n"]:
    """The paper's per-vertex pose error (Section 4), in model units.

    $$ E_i = d_i \\sin a_i $$

    with `d_i = ||p_i - o||` the distance from the camera centre `o` to the computed
    vertex `p_i = R m_i + t`, and `a_i` the angle between the visual ray of the observed
    pixel `(u_i, v_i)` (unit direction `b_i`, pointing in front of the camera) and the
    ray from `o` to `p_i`. `sin a_i` is the norm of the cross product of the two unit
    directions, so

    $$ E_i = \\| (p_i - o) \\times b_i \\| $$

    the distance from `p_i` to the line of the visual ray; `E_i ~ d_i a_i` for small
    angles. For `a_i > 90` degrees (the vertex is behind the camera, seen along the
    ray), `sin a_i` would fall again and hide the failure; there `E_i = d_i` (as at
    `a_i = 90` degrees), i.e. `E_i` is the distance from `p_i` to the half-line of the
    ray, continuous in the pose.

    **Arguments:**

    - `C`: camera, shape (3, 4).
    - `R`, `t`: pose (model to world), shapes (3, 3) and (3,).
    - `model`: model points, shape (n, 3).
    - `image`: matched pixels, shape (n, 2).

    **Returns:**

    `E`, shape (n,). At `E_i = 0` the gradient is 0 (not NaN). Placeholder for a
    singular camera: the centre and the ray directions take the zero placeholders of
    `jaxpose._camera.backproject`; a zero ray direction counts as perpendicular, giving
    `E_i = ||p_i - o||` (never a deceptive 0 unless `p_i = o`).
    """
    C, R, t, model, image = as_float(C, R, t, model, image)
    centre, rays = backproject(C, image)
    v = transform(Pose(R, t.reshape(3)), model) - centre[None, :]
    sideways = safe_norm(jnp.cross(v, rays), axis=1)
    ahead = jnp.sum(v * rays, axis=1) > 0
    return jnp.where(ahead, sideways, safe_norm(v, axis=1))


def pose_error(
    C: Camera,
    R: Rotation,
    t: Translation,
    model: ModelPoints,
    image: ImagePoints,
    mask: Mask = None,
) -> Float[Array, ""]:
    """Mean of the paper's per-vertex pose error (Section 4), in model units.

    $$ E = \\frac{1}{N} \\sum_i d_i \\sin a_i $$

    over the points selected by `mask` (all by default); see `pose_error_per_point`.

    **Arguments:**

    - `C`: camera, shape (3, 4).
    - `R`, `t`: pose (model to world), shapes (3, 3) and (3,).
    - `model`: model points, shape (n, 3).
    - `image`: matched pixels, shape (n, 2).
    - `mask`: optional (n,) bool; the points that count.

    **Returns:**

    Scalar `E` (model units); 0 for an all-False mask; gradient finite (0 terms) at an exact pose.
    """
    return masked_mean(pose_error_per_point(C, R, t, model, image), mask)
