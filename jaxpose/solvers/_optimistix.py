"""The adapters between jaxpose and optimistix / lineax: the Levenberg-Marquardt solver of
`jaxpose.solvers._nonlinear` (`lm_solver`), with a traced step limit and a trust region
in the parameters' dtype, and `NormalCholesky`, a lineax solver for its small damped
least-squares systems.

Imported when a solver is first built (traced), not with jaxpose: optimistix, equinox and
lineax take about half a second to import, which a process that only loads compiled
programs (`jaxpose.api._programs`) never needs.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.flatten_util as jfu
import jax.numpy as jnp
import lineax as lx
import optimistix as optx

from ._linalg import cholesky_solve

__all__ = ["NormalCholesky", "lm_solver"]


class _Static(eqx.Module):
    """A pytree with no leaves that carries `value` (e.g. a pytree structure) through
    `jit` as static data."""

    value: Any = eqx.field(static=True)


class NormalCholesky(lx.AbstractLinearSolver):
    """A lineax solver for small dense least-squares systems: the normal equations by
    `cholesky_solve` (unrolled), instead of a LAPACK QR per system.

    Levenberg-Marquardt's damped step solves `[J; sqrt(lambda) I] x = [r; 0]`, which is
    well conditioned by its damping; forming `A^T A` squares the condition number, so the
    columns are equilibrated first. Used by `jaxpose.solvers._nonlinear` (6 parameters).
    Forward solves only (`transpose` is not needed by optimistix's implicit adjoint,
    which solves its own system)."""

    def init(self, operator, options):
        del options
        return operator.as_matrix(), _Static(operator.in_structure())

    def compute(self, state, vector, options):
        del options
        A, structure = state
        b, _ = jfu.ravel_pytree(vector)
        zeros = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), structure.value)
        _, unflatten = jfu.ravel_pytree(zeros)
        scale = jnp.sqrt(jnp.sum(A * A, axis=0))
        scale = jnp.where(scale > 0, scale, 1)
        As = A / scale[None, :]
        x = cholesky_solve(As.T @ As, As.T @ b) / scale
        return unflatten(x), lx.RESULTS.successful, {}

    def transpose(self, state, options):
        raise NotImplementedError("NormalCholesky solves forward least-squares systems only")

    def conj(self, state, options):
        return state, options

    def assume_full_rank(self):
        return True


class _TrustRegion(optx.ClassicalTrustRegion):
    """optimistix's classical trust region, with its initial step size in the parameters'
    dtype (optimistix creates it as `jnp.array(1.0)`, float64 whenever x64 is enabled,
    which breaks float32 solves in an x64 process)."""

    def init(self, y, f_info_struct):
        state = super().init(y, f_info_struct)
        return type(state)(step_size=state.step_size.astype(jax.tree.leaves(y)[0].dtype))


class _StepLimit(optx.AbstractLeastSquaresSolver):
    """A least-squares solver that stops after `options["step_limit"]` steps, a traced
    integer (optimistix's `max_steps` is static: the loop's bound), reporting
    `nonlinear_max_steps_reached` as optimistix does at its own bound. Lets one compiled
    solver serve calls with different budgets (the mixed algorithm's retries)."""

    solver: optx.AbstractLeastSquaresSolver
    rtol: float
    atol: float
    norm: Callable = eqx.field(static=True)

    def init(self, fn, y, args, options, f_struct, aux_struct, tags):
        inner = self.solver.init(fn, y, args, options, f_struct, aux_struct, tags)
        return inner, jnp.array(0, jnp.int32)

    def step(self, fn, y, args, options, state, tags):
        inner, count = state
        y, inner, aux = self.solver.step(fn, y, args, options, inner, tags)
        return y, (inner, count + 1), aux

    def terminate(self, fn, y, args, options, state, tags):
        inner, count = state
        stop, result = self.solver.terminate(fn, y, args, options, inner, tags)
        limit = (options or {}).get("step_limit")
        if limit is None:  # optimistix's own `max_steps` alone
            return stop, result
        out = ~stop & (count >= limit)
        return stop | out, optx.RESULTS.where(out, optx.RESULTS.nonlinear_max_steps_reached, result)

    def postprocess(self, fn, y, aux, args, options, state, tags, result):
        return self.solver.postprocess(fn, y, aux, args, options, state[0], tags, result)


def lm_solver(rtol, atol):
    lm = optx.LevenbergMarquardt(rtol=rtol, atol=atol, linear_solver=NormalCholesky())
    lm = eqx.tree_at(lambda s: s.search, lm, _TrustRegion())
    return _StepLimit(lm, rtol, atol, lm.norm)
