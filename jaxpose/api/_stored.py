"""The stored programs of a plain call of `solve` and `solve_many` (concrete arrays, or
the inputs of a plain `jax.grad`): the problems padded to their buckets, the escalation
climbed a program a rung on the problems each rung needs (`_climb`), and the answer's
Jacobian for a plain derivative (`_derivative_program`). Calls under the caller's `jit`
or `vmap` run `_jitted` instead (`jaxpose.api._solve._pipeline` chooses)."""

from __future__ import annotations

import dataclasses
import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.core import Tracer
from jax.custom_derivatives import SymbolicZero

from ..geometry import Pose
from ..strategy import Options, Solution, escalation, rung_applies, solve_problems, with_values
from ._programs import bucket_points, program

__all__ = ["climb", "values_only"]


def _with_values(values, camera, model, image, mask, start, options: Options) -> Solution:
    return solve_problems(camera, model, image, mask, with_values(options, values), start)


_jitted = jax.jit(_with_values, static_argnames=("options",))


def _stored_program(values, camera, model, image, mask, options: Options, single: bool):
    """The stored program of `_pipeline` (`single`: the first problem's answer)."""
    out = _with_values(values, camera, model, image, mask, None, options)
    return jax.tree.map(lambda x: x[0], out) if single else out


def _stored_program_from(values, camera, model, image, mask, R, t, options: Options, single):
    """The stored program of `_pipeline` from given poses `Pose(R, t)`."""
    out = _with_values(values, camera, model, image, mask, Pose(R, t), options)
    return jax.tree.map(lambda x: x[0], out) if single else out


def bucket_problems(B: int) -> int:
    """The padded batch size of a plain `solve_many` call of `B` problems: `B` up to 4,
    else the next power of two."""
    return B if B <= 4 else 1 << (int(B) - 1).bit_length()


def _stored(
    camera, model, image, mask, options: Options, values, single: bool, start=None
) -> Solution:
    """The pipeline on concrete inputs through its stored program: the points padded to
    their bucket (`bucket_points`, the padding masked out), the problems to theirs
    (`bucket_problems`, repeating the last), and the answers cut back."""
    options = values_only(options)
    args, start, B = _padded(camera, model, image, mask, values, start)
    rows = args[2].shape[0]
    if start is not None:  # one program: the given poses are its arguments
        out = program(_stored_program_from, options, single)(*args, *start)
        return out if rows == B else jax.tree.map(lambda x: x[:B], out)
    rungs = escalation(options)

    def run(rung, a):  # (one problem: its answer lifted to a batch of one)
        found = program(_stored_program, rung, single)(*a)
        return _lifted(found) if single else found

    # The first rung's own program for every problem; each later rung's only for the
    # problems the rungs before it left (`_climb`).
    out = _climb(run(rungs[0], args), args, B, rungs[1:], run)
    if single:
        return jax.tree.map(lambda x: x[0], out)
    return out if rows == B else jax.tree.map(lambda x: x[:B], out)


def values_only(options: Options) -> Options:
    """The options of a stored program of concrete inputs: `derivative=False`. Nothing
    differentiates a call on concrete arrays (a plain `jax.grad` runs
    `_derivative_program`), and the values are the same: the answer finished by the
    linear method's steps (`jaxpose.strategy.finish_linear_batch`) instead of Newton
    steps whose implicit derivative needs a pseudo-inverse per problem (a plain
    `solve_many` of 4,096 problems of 13 matches: 172 against 4.6 us per problem, AMD
    EPYC with AVX-512)."""
    return dataclasses.replace(options, derivative=False)


def _lifted(tree):
    """`tree` with a leading axis of one."""
    return jax.tree.map(lambda x: x[None], tree)


def _climb(out, args, B: int, later, run, solution=lambda o: o):
    """The later rungs of the escalation (`later`, `climb`) after the first rung's answers
    `out` (a pytree of arrays with a leading problem axis; `solution(out)` its
    `Solution`) on `_padded`'s `args`, for the first `B` problems of finite input: each
    rung's stored program (`run(rung, its_args)`) on the problems that need it, gathered
    and padded to their bucket (`bucket_problems`)."""
    values, camera, model, image, mask = args
    need = ~np.asarray(solution(out).accepted).reshape(-1) & _finite_rows(camera, model, image)
    need[B:] = False
    if not later or not need.any():
        return out

    def rung_rows(rung, rows):
        pick = np.concatenate([rows, np.repeat(rows[-1:], bucket_problems(rows.size) - rows.size)])
        cameras = camera if camera.ndim == 2 else camera[pick]
        return run(rung, (values, cameras, model[pick], image[pick], mask[pick]))

    out = jax.tree.map(np.array, out)  # (copies: written in place)
    climb(out, need, mask.sum(axis=1), later, rung_rows, lambda f: solution(f).accepted)
    return jax.device_put(out)  # (not `jnp.asarray`: traced inside a derivative's rule)


def climb(out, need, used, later, run, accepted) -> None:
    """The escalation's later rungs (`later`) on the problems `need` marks, after the first
    rung: each rung runs (`run(rung, rows)`: its answers for the problems `rows`, a pytree
    like `out` whose leading axis starts with them) only on the problems still in need
    to which it applies (`rung_applies`, on their `used` matches); its answers replace
    theirs in `out` (numpy arrays, written in place) where it accepts (`accepted(found)`),
    the last rung's wherever it ran. So a batch's cost follows the problems that need
    each rung, and a rung no problem reaches is neither compiled nor run. The rule of
    every numpy-level caller: a plain `solve` / `solve_many`, `solve_pnp`,
    `solve_pnp_batch`."""
    need = np.array(need, bool)
    for k, rung in enumerate(later, start=1):
        rows = np.flatnonzero(need & rung_applies(rung, used))
        if not rows.size:
            continue
        found = jax.tree.map(lambda x: np.asarray(x)[: rows.size], run(rung, rows))
        keep = np.ones(rows.size, bool) if k == len(later) else np.asarray(accepted(found), bool)
        for whole, part in zip(jax.tree.leaves(out), jax.tree.leaves(found), strict=True):
            whole[rows[keep]] = part[keep]
        need[rows[keep]] = False


def _finite_rows(camera, model, image) -> np.ndarray:
    """Which problems of `_padded`'s arrays have finite inputs only (the others have their
    placeholder answer from every rung, `jaxpose.strategy.finite_inputs`: they need
    none)."""
    finite = np.isfinite(model).all(axis=(1, 2)) & np.isfinite(image).all(axis=(1, 2))
    cam = np.isfinite(camera).reshape(-1 if camera.ndim == 3 else 1, 12).all(axis=1)
    return finite & cam


def _padded(camera, model, image, mask, values, start):
    """The arguments of a stored program, `(values, camera, model, image, mask)`, and
    the given poses `(R, t)` (or `None`), as numpy arrays of one floating dtype: the
    points padded to their bucket (`bucket_points`; padding matches repeat the first,
    masked out), the problems to theirs (`bucket_problems`, repeating the last). Also
    returns `B`, the number of problems before padding."""
    camera, model, image = (np.asarray(x) for x in (camera, model, image))
    dtype = jnp.result_type(float, camera.dtype, model.dtype, image.dtype)
    dtype = np.dtype(jax.dtypes.canonicalize_dtype(dtype))
    B, n = model.shape[:2]
    mask = np.ones((B, n), bool) if mask is None else np.asarray(mask, bool)
    size, rows = bucket_points(n), bucket_problems(B)

    def points(x):
        fill = np.zeros((B, size - n, *x.shape[2:]), x.dtype)
        if x.dtype != np.bool_:
            fill[:] = x[:, :1]
        return np.concatenate([x, fill], axis=1)

    def problems(x):
        return np.concatenate([x, np.repeat(x[-1:], rows - B, axis=0)]) if rows > B else x

    model, image, mask = (problems(points(x)) for x in (model, image, mask))
    model, image = model.astype(dtype), image.astype(dtype)
    camera = (problems(camera) if camera.ndim == 3 else camera).astype(dtype)
    if start is not None:
        start = tuple(problems(np.asarray(x)).astype(dtype) for x in start)
    return (values.astype(dtype), camera, model, image, mask), start, B


# ------------------------------------------------------- derivatives of a plain call

#: The largest Jacobian `_stored_derivative` computes, in entries per output component
#: (problems times the `12 + 5 n` inputs of each, after padding): a larger batch takes
#: the traced path, whose reverse mode keeps no Jacobian.
DERIVATIVE_ENTRIES = 1 << 18


class _Jacobian(NamedTuple):
    """The derivative of each problem's differentiable outputs, flattened in the order
    `R` (9), `t` (3), `error`, `pose_error` (14 in all; `OUTPUTS`), with respect to its
    inputs: `camera (B, 14, 12)` (its own or the shared camera, row-major), `model
    (B, 14, n, 3)`, `image (B, 14, n, 2)`."""

    camera: Any
    model: Any
    image: Any


OUTPUTS = 14


def _flat(R, t, error, pose_error):
    """The differentiable outputs of `B` problems as one `(B, 14)` array."""
    B = error.shape[0]
    return jnp.concatenate([R.reshape(B, 9), t, error[:, None], pose_error[:, None]], axis=1)


def _unflat(d) -> tuple:
    """`_flat`'s inverse: `(B, 14)` to `(R, t, error, pose_error)`."""
    B = d.shape[0]
    return d[:, :9].reshape(B, 3, 3), d[:, 9:12], d[:, 12], d[:, 13]


def _derivative_program(values, camera, model, image, mask, start, options: Options):
    """The stored program of a differentiated plain call: the pipeline's `Solution` and
    its `_Jacobian` at the answer. The pipeline is linearized once (its derivative is
    the implicit one at the Eq. 8 optimum, `jaxpose.strategy._implicit.polish`: the
    same linear map `jax.grad` transposes on the traced path); the problems being
    independent, the 14 output components' cotangents, each set in every problem at
    once, give every problem's row w.r.t. its points (reverse), and the camera's 12
    entries, each set in every problem's camera, give its columns (forward)."""
    given = None if start is None else Pose(*start)

    def floats(c, m, i):
        out = _with_values(values, c, m, i, mask, given, options)
        return (out.pose.R, out.pose.t, out.error, out.pose_error), out

    primal, linear, out = jax.linearize(floats, camera, model, image, has_aux=True)
    B, dtype = model.shape[0], primal[2].dtype
    zero_model, zero_image = jnp.zeros_like(model), jnp.zeros_like(image)
    entries = jnp.eye(12, dtype=camera.dtype).reshape(12, 3, 4)
    if camera.ndim == 3:
        entries = jnp.broadcast_to(entries[:, None], (12, *camera.shape))
    by_camera = jax.vmap(lambda d: _flat(*linear(d, zero_model, zero_image)))(entries)
    transpose = jax.linear_transpose(linear, camera, model, image)
    components = jnp.broadcast_to(jnp.eye(OUTPUTS, dtype=dtype)[:, None], (OUTPUTS, B, OUTPUTS))
    _, by_model, by_image = jax.vmap(lambda ct: transpose(_unflat(ct)))(components)
    return out, _Jacobian(
        camera=jnp.moveaxis(by_camera, 0, 2),
        model=jnp.moveaxis(by_model, 0, 1),
        image=jnp.moveaxis(by_image, 0, 1),
    )


def _differentiated(arrays) -> bool:
    """Whether the traced ones among `arrays` are the inputs of a plain `jax.grad`,
    `jax.vjp`, `jax.jacrev`, `jax.jacfwd`, `jax.jvp` or `jax.linearize`: all of the
    innermost trace, a forward or linearizing one, with concrete values (not under the
    caller's `jit` or `vmap`, nor a second derivative). Only the camera, model and image
    may be traced. (JAX's internal trace types: with another JAX, `False`, the traced
    path.)"""
    try:
        from jax._src import core
        from jax._src.interpreters import ad

        trace = core.trace_ctx.trace
        if not isinstance(trace, (ad.JVPTrace, ad.LinearizeTrace)):
            return False
    except (ImportError, AttributeError):  # pragma: no cover - another JAX
        return False
    camera, model, image, mask, *start = arrays
    if any(isinstance(x, Tracer) for x in (mask, *start)):
        return False
    traced = [x for x in (camera, model, image) if isinstance(x, Tracer)]
    return all(
        getattr(x, "_trace", None) is trace
        and hasattr(x, "primal")
        and not isinstance(x.primal, Tracer)
        for x in traced
    )


def _derivative_fits(model) -> bool:
    """Whether the Jacobian of a plain call on `model`'s problems stays below
    `DERIVATIVE_ENTRIES` (`_derivative_program`)."""
    B, n = model.shape[:2]
    return bucket_problems(B) * (12 + 5 * bucket_points(n)) <= DERIVATIVE_ENTRIES


def _stored_derivative(
    camera, model, image, mask, options: Options, values, single: bool, start
) -> Solution:
    """The pipeline, differentiated, under a plain `jax.grad` (or `jax.jacrev`,
    `jax.jacfwd`, `jax.jvp`; `_differentiated`): a `jax.custom_jvp` whose rule, given
    the concrete inputs, runs the stored program of the answer and its Jacobian
    (`_derivative_program`: compiled once per bucket, kept on disk, built ahead by
    `jaxpose warmup`) and applies the Jacobian to the tangents (`_tangents`), a linear
    map that reverse mode transposes. The same derivative as the traced path's (the
    implicit one at the optimum), without tracing the pipeline in each new process.
    Batched inputs (`(B, ...)`, as `solve_many`); `single`: the first problem's answer,
    without its batch axis."""

    def traced(c, m, i):
        out = _jitted(values, c, m, i, mask, start, options=options)
        return jax.tree.map(lambda a: a[0], out) if single else out

    def run(c, m, i):
        if any(isinstance(x, Tracer) for x in (c, m, i)):  # pragma: no cover - staged
            return traced(c, m, i)
        out = _stored(c, m, i, mask, options, values, False, start)
        return jax.tree.map(lambda a: a[0], out) if single else out

    def rule(primals, tangents):
        if any(isinstance(x, Tracer) for x in primals):  # pragma: no cover - staged
            tangents = [_instantiated(t) for t in tangents]
            return jax.jvp(traced, primals, tangents)
        c, m, i = primals
        out, jac = _answer_and_jacobian(c, m, i, mask, options, values, start)
        d_camera, d_model, d_image = (None if isinstance(t, SymbolicZero) else t for t in tangents)
        R, t, error, pose_error = _tangents(jac, d_camera, d_model, d_image, single=single)
        if single:
            out = jax.tree.map(lambda a: a[0], out)

        def none(x) -> Any:
            return np.zeros(np.shape(x), jax.dtypes.float0)

        tangent = Solution(
            Pose(R, t), error, pose_error, none(out.status), none(out.accepted), none(out.triplet)
        )
        return jax.tree.map(jnp.asarray, out), tangent

    run = jax.custom_jvp(run)
    run.defjvp(rule, symbolic_zeros=True)
    return run(camera, model, image)


def _instantiated(t):
    """A tangent of `jax.custom_jvp`'s symbolic zeros, as an array."""
    if isinstance(t, SymbolicZero):
        zero: Any = t
        return np.zeros(zero.shape, zero.dtype)
    return t


def _answer_and_jacobian(camera, model, image, mask, options: Options, values, start):
    """The `Solution` of `B` problems and its `_Jacobian` (numpy arrays), from the
    stored derivative programs (as `_stored`: the first rung's, then each later rung's
    for the problems left without a pose, `_climb`), cut back to the problems and points
    given."""
    args, start, B = _padded(camera, model, image, mask, values, start)
    n = np.shape(model)[1]
    rungs = escalation(options) if start is None else (options,)
    first = program(_derivative_program, rungs[0])(*args, start)

    def run(rung, a):
        return program(_derivative_program, rung)(*a, None)

    out, jac = _climb(first, args, B, rungs[1:], run, solution=lambda o: o[0])
    out = jax.tree.map(lambda x: np.asarray(x)[:B], out)
    jac = _Jacobian(*(np.asarray(x)[:B] for x in jac))
    return out, _Jacobian(jac.camera, jac.model[:, :, :n], jac.image[:, :, :n])


@functools.partial(jax.jit, static_argnames=("single",))
def _tangents(jac: _Jacobian, d_camera, d_model, d_image, *, single: bool) -> tuple:
    """The tangents of `(R, t, error, pose_error)` for those of the camera, model and
    image (`None`: zero): the Jacobian's linear map. One compiled call (a plain
    derivative binds one operation, not one per step)."""
    B, dtype = jac.camera.shape[0], jac.camera.dtype
    d = jnp.zeros((B, OUTPUTS), dtype)
    if d_camera is not None:
        d_camera = jnp.broadcast_to(jnp.reshape(d_camera, (-1, 12)), (B, 12))
        d = d + jnp.einsum("bkc,bc->bk", jac.camera, d_camera.astype(dtype))
    if d_model is not None:
        d = d + jnp.einsum("bkpj,bpj->bk", jac.model, d_model.astype(dtype))
    if d_image is not None:
        d = d + jnp.einsum("bkpj,bpj->bk", jac.image, d_image.astype(dtype))
    out = _unflat(d)
    return tuple(x[0] for x in out) if single else out
