"""The derivative of the answer with respect to the problem, by the implicit function
theorem at the Eq. 8 optimum.

The mixed algorithm's choices (triplet, root, branch, acceptance) carry no derivative,
and unrolling its iterations would give a poor one; the optimum itself does: `polish`
attaches it to the answer.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool

from ..geometry._pose import Observations, Pose
from ..solvers._chart import chart_at, chart_pose, chart_residuals
from ..solvers._linalg import positive_definite_solve, symmetric_pinv

__all__ = ["newton_step", "polish"]


def polish(
    obs: Observations, pose: Pose, accepted: Bool[Array, ""], derivative: bool = True
) -> Pose:
    """The answer, polished by Newton steps, with the implicit derivative attached.

    In the chart `xi = (w, u)` around the (gradient-free) answer `(R^, t^)`
    (`jaxpose.solvers._chart`: `R = exp(hat(w)) R^`, rotation about the centroid of the
    world points, translation scaled by their RMS radius), let
    `f(xi, theta) = |r(xi, theta)|^2 / 2` be Eq. 8's cost, `theta` the camera, model and
    image, `g = df/dxi`, `H = d^2f/dxi^2` (the full Hessian, not Gauss-Newton's). At the
    optimum `g(0, theta) = 0`, so by the implicit function theorem

        dxi*/dtheta = -H^-1 dg/dtheta.

    That is the derivative of the Newton step `xi = -H^-1 g(0, theta)` with `H` held
    constant. Two Newton steps are taken from the answer (each only when `H` is positive
    definite and the step is below `1e-3`, rad and object radii: at a converged answer they
    move the pose by rounding, and they finish a pose that a solver left within its
    tolerance, e.g. `1e-6` from Levenberg-Marquardt), the second carrying exactly the
    implicit derivative. A singular `H` (a pose the matches do not determine) uses the
    pseudo-inverse. Not accepted: the answer with a zero derivative. First derivatives
    only (`H` carries none).

    **Arguments:**
    - `obs`: the problem (carrying the derivative).
    - `pose`: the answer (its derivative is ignored).
    - `accepted`: whether the answer was accepted.

    - `derivative`: `False`: the same two steps for the value only
      (`newton_step(..., derivative=False)`: Cholesky instead of the pseudo-inverse, no
      LAPACK call, a smaller program), for callers that take no derivative.

    **Returns:** the polished `Pose`.
    """
    target = obs if derivative else jax.lax.stop_gradient(obs)

    def step(_, pose):  # one step's code, run twice; the last one's derivative stands
        return newton_step(target, jax.lax.stop_gradient(pose), accepted, derivative)

    return jax.lax.fori_loop(0, 2, step, jax.lax.stop_gradient(pose))


def newton_step(
    obs: Observations, pose: Pose, accepted: Bool[Array, ""], derivative: bool = True
) -> Pose:
    """One guarded Newton step of Eq. 8 from `pose` (no derivative w.r.t. `pose`); its
    derivative w.r.t. `obs` is the implicit one (see `polish`). `derivative=False`: the
    value alone, `H` solved by `positive_definite_solve` (no LAPACK call; its
    positive-definiteness test is `symmetric_pinv`'s but for matrices singular to
    rounding)."""
    sobs = jax.lax.stop_gradient(obs)
    chart = chart_at(pose, sobs)
    zero = jnp.zeros(6, pose.t.dtype)

    def cost(xi, o):
        r = chart_residuals(xi, chart, o)
        return 0.5 * jnp.sum(r * r)

    H = jax.hessian(cost)(zero, sobs)
    if derivative:
        g = jax.grad(cost)(zero, obs)
        H_inv, _, positive = symmetric_pinv(H)
        step = -(H_inv @ g)
    else:
        step, positive = positive_definite_solve(H, -jax.grad(cost)(zero, sobs))
    value = jax.lax.stop_gradient(step)
    # Taken only within the quadratic convergence region of a minimum: H positive definite
    # (so the step descends) and a step below 1e-3 (rad, object radii). The cost itself is
    # no judge there: its rounding (~eps times the plane terms, not the cost) exceeds the
    # decrease of a 1e-11 step.
    local = jnp.all(jnp.abs(value) < 1e-3) & jnp.all(jnp.isfinite(value))
    xi = jnp.where(positive & local, value, 0) + (step - value)
    return chart_pose(jnp.where(accepted, xi, 0), chart)
