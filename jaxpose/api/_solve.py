"""The JAX-native entry points: `solve` (one problem, differentiable), `solve_many` (a
batch, batch-first) and `solve_batch` (a large batch from numpy, chunked and sharded over
devices). The OpenCV-convention ones are in `jaxpose.api._pnp`."""

from __future__ import annotations

import functools
from typing import Any, NamedTuple, cast

import jax
import jax.numpy as jnp
import numpy as np
from jax.core import Tracer
from jax.custom_derivatives import SymbolicZero
from jaxtyping import ArrayLike, Bool, Real

from ..geometry import Pose, as_batched, check_problem, no_type_check
from ..strategy import METHODS as METHODS
from ..strategy import (
    TRACED,
    Options,
    Solution,
    escalation,
    resolve,
    rung_applies,
    solve_problems,
    split_values,
    with_values,
)
from ._batch import run_batched
from ._programs import bucket_points, program

__all__ = ["METHODS", "Solution", "solve", "solve_batch", "solve_many"]


# The entry points check their arguments themselves (`check_problem`, `as_batched`: a
# `ValueError` naming the argument), so no run-time type check comes before theirs.
@no_type_check
def solve(
    camera: Real[ArrayLike, "3 4"],
    model: Real[ArrayLike, "n 3"],
    image: Real[ArrayLike, "n 2"],
    mask: Bool[ArrayLike, " n"] | None = None,
    *,
    options: Options | None = None,
    initial: Pose | None = None,
    **changes,
) -> Solution:
    """Recover the pose of a known object from one calibrated image (JAX-native).

    Pure, for ONE problem: composes with `jax.jit`, `jax.vmap` (batch the arrays) and
    `jax.grad`; the pipeline (`jaxpose.strategy.solve_problems`) on a batch of one.
    By default (the mixed method with `refine=1`): the three-point roots of the triplets
    of the 4 matches farthest apart in the image are scored by their Eq. 8 error over all
    matches, the linear method runs from the best one (and, for a coplanar model, from
    its planar partner too), and the accepted pose is polished to the Eq. 8 optimum.
    Where none is accepted the problem escalates (`jaxpose.strategy.escalation`): the
    best roots of the triplets of 12 spread matches, then the paper's whole mixed
    algorithm over every triplet (`jaxpose.mixed`).
    `refine=None` runs the whole mixed algorithm from the start; `method=` one of the
    paper's single methods, from every triplet.

    **Arguments:**
    - `camera`: the 3x4 projection matrix `C`, calibrated in the world frame.
    - `model`: `(n, 3)` model points `m_i`, `n >= 3`.
    - `image`: `(n, 2)` pixels matched to them.
    - `mask`: optional `(n,)` bool, which matches to use (fixed shapes with padding).
    - `options`: a `jaxpose.Options` (default `Options()`), by concern: `search` (the
      method, `"mixed"`, `"three_point"`, `"linear"` or `"nonlinear"`, the last two
      started from every triplet's three-point pose, as in the paper's experiment; the
      mixed algorithm's budgets), `acceptance` (the threshold), `selection` (the
      triplets used: `max_triplets`, `triplet_budget`, the fast path for large batches
      of easy problems), `execution` (the derivative, the buffer). A static argument
      under `jax.jit` (hashable); its thresholds and tolerances are values.
    - `initial`: `None`, or a `Pose` `(R (3, 3), t (3,))` (model to world) to start
      from instead of the three-point roots: the paper's small-movement linear method
      (Section 2.2) from it, then, with the mixed method, Levenberg-Marquardt where it
      does not reach an accepted pose, and the usual acceptance and finish (the local
      answer near it: no other roots or planar partner are tried;
      `jaxpose.strategy._start`). Its `triplet` is then `(0, 1, 2)`. A value, not
      structure: another initial pose compiles nothing.
    - `**changes`: keyword shorthands for settings (or groups) of `options`, e.g.
      `solve(C, M, I, method="linear", threshold=2.0)`; an unknown one raises
      `ValueError`.

    **Returns:** a `Solution`.

    **Gradients** (`jax.grad`, `jax.jacfwd`, `jax.jacrev`, under `jit` and `vmap`): for
    the three optimising methods, `pose` (and `error`, `pose_error`) are differentiable
    with respect to `camera`, `model` and `image` through the optimality conditions of
    Eq. 8 at the answer (implicit function theorem, the full Hessian: exact first
    derivatives, not an unrolled iteration; see `jaxpose.strategy._implicit.polish`). The
    discrete choices (triplet, root, branch, acceptance) carry none. A problem with no
    accepted pose returns its placeholder with a zero gradient; `method="three_point"`
    gives no gradient to the pose.
    """
    options = resolve(options, changes)
    check_problem(camera, model, image, mask)
    start = _check_initial(initial, ())

    def one(x):  # a batch of one (numpy for a plain call: no dispatch)
        if x is None:
            return None
        return x[None] if isinstance(x, Tracer) else np.asarray(x)[None]

    start = None if start is None else Pose(*(cast(Any, one(x)) for x in start))
    return _pipeline(camera, one(model), one(image), one(mask), options, True, start)


def _check_initial(initial, batch: tuple[int, ...]) -> Pose | None:
    """`initial` checked: `None` or a `Pose` of shapes `(*batch, 3, 3)`, `(*batch, 3)`,
    real and (when concrete) finite; `ValueError` naming `initial` otherwise."""
    if initial is None:
        return None
    if not isinstance(initial, Pose):
        raise ValueError(f"initial must be a jaxpose.Pose or None, got {type(initial).__name__}")
    for name, x, tail in (("R", initial.R, (3, 3)), ("t", initial.t, (3,))):
        shape = tuple(getattr(x, "shape", np.shape(x)))
        if shape != (*batch, *tail):
            raise ValueError(f"initial.{name} must have shape {(*batch, *tail)}, got {shape}")
        if not isinstance(x, Tracer) and not np.all(np.isfinite(np.asarray(x, np.float64))):
            raise ValueError(f"initial.{name} must be finite")
    return initial


@no_type_check
def solve_many(
    camera: Real[ArrayLike, "3 4"] | Real[ArrayLike, "B 3 4"],
    model: Real[ArrayLike, "B n 3"],
    image: Real[ArrayLike, "B n 2"],
    mask: Bool[ArrayLike, "B n"] | None = None,
    *,
    options: Options | None = None,
    initial: Pose | None = None,
    **changes,
) -> Solution:
    """`solve` for a batch of `B` problems of equal `n`: the same answers as
    `jax.vmap(solve)`, computed batch-first. `camera` is `(3, 4)`, one camera for every
    problem (`jax.vmap(solve, in_axes=(None, 0, 0, 0))`), or `(B, 3, 4)`, one per problem.

    It is the pipeline itself (`jaxpose.strategy.solve_problems`). The difference from
    a plain `vmap` is the cost: under `vmap`, every problem pays for every rung of the
    escalation and the mixed algorithm's full Levenberg-Marquardt buffer (`vmap` turns
    "only when needed" into "always"); here each rung runs only for the problems that
    need it, gathered a few at a time, the triplets that need Levenberg-Marquardt share
    one buffer, and the cheap steps run in cache-sized passes. Arguments as `solve`
    (`model`, `image`, `mask` with a leading batch axis, `initial` a `Pose` of `B`
    poses); pure, for `jit` and `grad`.
    """
    options = resolve(options, changes)
    _check_many(camera, model, image, mask)
    start = _check_initial(initial, np.shape(model)[:1])
    return _pipeline(camera, model, image, mask, options, False, start)


# ------------------------------------------------------------------ compiled programs


def _pipeline(
    camera, model, image, mask, options: Options, single: bool = False, start=None
) -> Solution:
    """`solve_problems`, compiled. Concrete inputs (a plain call) run a stored program
    (`jaxpose.api._programs`: compiled once per bucket of points and of problems, kept
    on disk, loaded by a new process, built ahead by `jaxpose warmup`), and so do the
    inputs of a plain `jax.grad`, `jax.jacrev`, `jax.jacfwd` or `jax.jvp` (no `jit`
    around it: `_stored_derivative`); other traced ones (under the caller's `jit` or
    `vmap`) run `jax.jit` of the pipeline, whose program JAX keeps for the life of the
    process. Either way a call is as fast from its second call as a jitted one. The
    thresholds and tolerances are the programs' values (`jaxpose.strategy.split_values`):
    changing them compiles nothing.
    `single`: one problem (`B = 1`), returned without its batch axis. `start`: the
    given poses (`Pose`, batched) or `None`: an argument of the programs too."""
    arrays = (camera, model, image, mask, *(() if start is None else start))
    traced = any(isinstance(x, Tracer) for x in arrays)
    values_traced = any(isinstance(getattr(options, f), Tracer) for f in TRACED)
    if values_traced:  # the options' values are the caller's tracers: trace it all
        out = solve_problems(camera, model, image, mask, options, start)
    else:
        key, values = split_values(options)
        if not traced:
            return _stored(camera, model, image, mask, key, values, single, start)
        if _differentiated(arrays) and _derivative_fits(model):
            return _stored_derivative(camera, model, image, mask, key, values, single, start)
        out = _jitted(values, camera, model, image, mask, start, options=key)
    return jax.tree.map(lambda a: a[0], out) if single else out


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
    args, start, B = _padded(camera, model, image, mask, values, start)
    rows = args[2].shape[0]
    if start is not None:  # one program: the given poses are its arguments
        out = program(_stored_program_from, options, single)(*args, *start)
        return out if rows == B else jax.tree.map(lambda x: x[:B], out)
    rungs = escalation(options)
    # The first rung's own program for every problem; each later rung's only for the
    # problems the rungs before it left (`_climb`).
    out = program(_stored_program, rungs[0], single)(*args)
    if single:  # one problem: the later rungs' programs of one problem

        def one(rung, a):
            return _lifted(program(_stored_program, rung, True)(*a))

        return jax.tree.map(lambda x: x[0], _climb(_lifted(out), args, B, rungs[1:], one))

    def many(rung, a):
        return program(_stored_program, rung, False)(*a)

    out = _climb(out, args, B, rungs[1:], many)
    return out if rows == B else jax.tree.map(lambda x: x[:B], out)


def _lifted(tree):
    """`tree` with a leading axis of one."""
    return jax.tree.map(lambda x: x[None], tree)


def _climb(out, args, B: int, later, run, solution=lambda o: o):
    """The later rungs of the escalation (`later`) after the first rung's answers `out`
    (a pytree of arrays with a leading problem axis; `solution(out)` its `Solution`) on
    `_padded`'s `args`: each rung runs (`run(rung, its_args)`: its stored program) only
    on the problems of finite input that the rungs before it left without a pose and to
    which it applies (`rung_applies`), gathered and padded to their bucket
    (`bucket_problems`); its answers replace theirs where it accepts, the last rung's
    wherever it ran. So a batch's cost follows the problems that need each rung, and a
    rung that no problem reaches is neither compiled nor run."""
    values, camera, model, image, mask = args
    need = ~np.asarray(solution(out).accepted).reshape(-1) & _finite_rows(camera, model, image)
    need[B:] = False
    if not later or not need.any():
        return out
    out = jax.tree.map(np.array, out)  # (copies: written in place below)
    used = mask.sum(axis=1)
    for k, rung in enumerate(later, start=1):
        rows = np.flatnonzero(need & rung_applies(rung, used))
        if not rows.size:
            continue
        pad = bucket_problems(rows.size) - rows.size
        pick = np.concatenate([rows, np.repeat(rows[-1:], pad)])
        cameras = camera if camera.ndim == 2 else camera[pick]
        found = run(rung, (values, cameras, model[pick], image[pick], mask[pick]))
        found = jax.tree.map(lambda x: np.asarray(x)[: rows.size], found)
        last = k == len(later)
        keep = np.ones(rows.size, bool) if last else np.asarray(solution(found).accepted)
        for whole, part in zip(jax.tree.leaves(out), jax.tree.leaves(found), strict=True):
            whole[rows[keep]] = part[keep]
        need[rows[keep]] = False
    return jax.device_put(out)  # (not `jnp.asarray`: traced inside a derivative's rule)


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


def _check_many(camera, model, image, mask) -> None:
    """`check_problem` for a batch: `camera (3, 4)` or `(B, 3, 4)`, `model (B, n, 3)`,
    `image (B, n, 2)`, `mask (B, n)`."""
    for name, x, tail in (("model", model, 3), ("image", image, 2)):
        shape = getattr(x, "shape", None)
        if shape is None or len(shape) != 3 or shape[-1] != tail:
            raise ValueError(f"{name} must have shape (B, n, {tail}), got {shape}")
    if image.shape[0] != model.shape[0]:
        raise ValueError(
            f"model and image must hold the same number of problems, got {model.shape[0]} "
            f"and {image.shape[0]}"
        )
    if mask is not None and (getattr(mask, "ndim", None) != 2 or mask.shape[0] != model.shape[0]):
        raise ValueError(f"mask must have shape (B, n), got {getattr(mask, 'shape', None)}")
    if getattr(camera, "ndim", None) == 3 and camera.shape[0] != model.shape[0]:
        raise ValueError(
            f"camera must be (3, 4) or one per problem, (B, 3, 4) with B = {model.shape[0]}, "
            f"got {camera.shape}"
        )

    def item(x):
        return None if x is None else jax.ShapeDtypeStruct(x.shape[1:], x.dtype)

    check_problem(
        item(camera) if getattr(camera, "ndim", None) == 3 else camera,
        item(model),
        item(image),
        item(mask),
    )


def _solve_rows(camera, model, image, mask, *, camera_batched, model_batched, options):
    """`solve` over the rows of a chunk: `solve_many` (batch-first, one shared
    Levenberg-Marquardt buffer) when the camera is shared, else `jax.vmap(solve)`."""
    if not camera_batched:
        if not model_batched:
            model = jnp.broadcast_to(model, (image.shape[0], *model.shape))
        return solve_many(camera, model, image, mask, options=options)
    one = functools.partial(solve, options=options)
    axes = (0, 0 if model_batched else None, 0, 0)
    return jax.vmap(one, in_axes=axes)(camera, model, image, mask)


@no_type_check
def solve_batch(
    camera: Real[ArrayLike, "3 4"] | Real[ArrayLike, "B 3 4"],
    models: Real[ArrayLike, "B n 3"] | Real[ArrayLike, "n 3"],
    images: Real[ArrayLike, "B n 2"],
    masks: Bool[ArrayLike, "B n"] | None = None,
    *,
    options: Options | None = None,
    chunk_size: int | None = None,
    devices=None,
    **changes,
) -> Solution:
    """`jaxpose.solve` over a batch of problems, sharded over devices and chunked.

    Equivalent to `jax.jit(jax.vmap(jaxpose.solve))` on the whole batch (same results,
    row by row; with one shared camera it runs `jaxpose.solve_many`, the batch-first
    path, much faster than a plain `vmap` of the mixed method), but with the batch axis
    split over `devices` (a `"batch"` mesh) and streamed in chunks of `chunk_size`
    problems, so that a million problems fit in memory. Call it eagerly (its inputs are
    concrete arrays); under `jit` use `jax.vmap(jaxpose.solve)` itself. The dtype follows
    the inputs (float32 stays float32; float64 needs `jax_enable_x64`).

    **Arguments:**
    - `camera`: one camera `(3, 4)` for all problems, or one per problem `(B, 3, 4)`.
    - `models`: `(B, n, 3)` model points, or `(n, 3)` shared by all problems.
    - `images`: `(B, n, 2)` pixels.
    - `masks`: optional `(B, n)` bool, which matches each problem uses.
    - `options`, `**changes`: as `jaxpose.solve` (an `Options`, and keyword shorthands
      for its fields: `method`, `threshold`, `triplet_budget`, ...).
    - `chunk_size`, `devices`: see `jaxpose.api.run_batched`.

    **Returns:** a `Solution` whose fields have a leading `B` axis (jax arrays on the
    default device). Problems with non-finite values give `status` `NOT_FINITE` and finite
    placeholders, as `jaxpose.solve` does.

    **Raises:** `ValueError` naming the argument for wrong shapes, dtypes or options.
    """
    options = resolve(options, changes)
    images = as_batched(images, "images", 2, shared=False)
    B, n = images.shape[:2]
    models = as_batched(models, "models", 3, batch_size=B, count=n)
    camera = as_batched(camera, "camera", (3, 4), batch_size=B)
    dtype = jnp.result_type(camera.dtype, models.dtype, images.dtype)
    dtype = np.dtype(jax.dtypes.canonicalize_dtype(dtype))
    if masks is None:
        masks = np.ones((B, n), dtype=bool)
    else:
        masks = np.asarray(masks)
        if masks.dtype != np.bool_ or masks.shape != (B, n):
            raise ValueError(
                f"masks must be a bool array of shape ({B}, {n}), got {masks.dtype} {masks.shape}"
            )
    camera_batched, model_batched = camera.ndim == 3, models.ndim == 3
    shared, batched = [], []
    (batched if camera_batched else shared).append(camera.astype(dtype))
    (batched if model_batched else shared).append(models.astype(dtype))
    batched += [images.astype(dtype), masks]
    order = _argument_order(camera_batched, model_batched)
    out = run_batched(
        _Reordered(order),
        shared,
        batched,
        static={
            "camera_batched": camera_batched,
            "model_batched": model_batched,
            "options": options,
        },
        chunk_size=chunk_size,
        devices=devices,
    )
    return Solution(*jax.tree.map(jnp.asarray, tuple(out)))


def _argument_order(camera_batched: bool, model_batched: bool) -> tuple[int, int, int, int]:
    """Positions of (camera, model, image, mask) in `shared + batched`."""
    shared = [i for i, b in ((0, camera_batched), (1, model_batched)) if not b]
    batched = [i for i, b in ((0, camera_batched), (1, model_batched)) if b] + [2, 3]
    position = {arg: pos for pos, arg in enumerate(shared + batched)}
    return position[0], position[1], position[2], position[3]


class _Reordered:
    """`_solve_rows` taking its arguments in `shared + batched` order (hashable)."""

    def __init__(self, order: tuple[int, ...]):
        self.order = order

    def __call__(self, *args, **static):
        return _solve_rows(*(args[i] for i in self.order), **static)

    def __hash__(self):
        return hash((_Reordered, self.order))

    def __eq__(self, other):
        return isinstance(other, _Reordered) and other.order == self.order
