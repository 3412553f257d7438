"""Numerical building blocks shared by every layer: floating dtypes, the precision switch,
and the safe forms of the operations that are singular somewhere.

A *safe* function is finite in value **and** in derivative everywhere, including at
its singular point. The technique (after jaxlie) is the double `jnp.where`: the
singular operation is fed a harmless argument (`1`) where its result is not selected,
so that the untaken branch cannot produce an `inf`/`NaN` that reverse-mode
differentiation would multiply by zero (`0 * inf` is `NaN`):

```python
ok = x > 0
safe = jnp.where(ok, jnp.sqrt(jnp.where(ok, x, 1)), 0)
```

Every function here is pure `jax.numpy`, follows the floating dtype of its inputs and
composes with `jit`, `vmap` and `grad`.
"""

from __future__ import annotations

from typing import TypeVar, overload

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float, Real

__all__ = [
    "adjugate3",
    "as_float",
    "by_precision",
    "det3",
    "float_dtype",
    "masked_centroid",
    "masked_mean",
    "safe_atan2",
    "safe_div",
    "safe_norm",
    "safe_normalize",
    "safe_sqrt",
]

T = TypeVar("T")


# --------------------------------------------------------------------------- dtypes


def float_dtype(*xs: ArrayLike) -> jnp.dtype:
    """The common inexact dtype of `xs`: their promoted dtype if it is floating (or
    complex), JAX's default float otherwise (integers, booleans)."""
    dtype = jnp.result_type(*(jnp.asarray(x) for x in xs))
    if not jnp.issubdtype(dtype, jnp.inexact):
        dtype = jnp.result_type(float)
    return dtype


@overload
def as_float(x: ArrayLike, /) -> Array: ...


@overload
def as_float(x: ArrayLike, y: ArrayLike, /, *xs: ArrayLike) -> tuple[Array, ...]: ...


def as_float(*xs: ArrayLike):  # the overloads above give its return type
    """`xs` as JAX arrays of their common inexact dtype (see `float_dtype`).

    **Returns:** one array for one argument, a tuple of arrays for several.
    """
    arrays = [jnp.asarray(x) for x in xs]
    dtype = float_dtype(*arrays)
    out = tuple(a.astype(dtype) for a in arrays)
    return out[0] if len(out) == 1 else out


def by_precision(dtype, *, f64: T, f32: T) -> T:
    """The setting for a floating dtype: `f64` for 64-bit floats (and wider), `f32` for
    narrower ones (float32, float16, bfloat16).

    Tolerances that depend on the precision are chosen here, in one place, e.g.
    `by_precision(x.dtype, f64=1e-8, f32=1e-5)`.
    """
    return f64 if jnp.finfo(dtype).bits >= 64 else f32


# --------------------------------------------------------------------------- safe forms


def safe_sqrt(x: Real[ArrayLike, "*shape"]) -> Float[Array, "*shape"]:
    """`sqrt(x)` for `x > 0`, else `0`; the derivative is `0` (not `inf`) at `x <= 0`."""
    x = jnp.asarray(x)
    ok = x > 0
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, x, 1)), 0)


def safe_div(num: Real[ArrayLike, "*#shape"], den: Real[ArrayLike, "*#shape"]) -> Array:
    """`num / den` where `den != 0`, else `0` (value and derivative); broadcasting."""
    ok = den != 0
    return jnp.where(ok, num / jnp.where(ok, den, 1), 0)


def safe_atan2(y: Real[ArrayLike, "*#shape"], x: Real[ArrayLike, "*#shape"]) -> Array:
    """`atan2(y, x)`, but `0` with derivative `0` (not `NaN`) where `x^2 + y^2` is `0`."""
    degenerate = (x * x + y * y) == 0
    return jnp.arctan2(jnp.where(degenerate, 0.0, y), jnp.where(degenerate, 1.0, x))


def safe_norm(x: Float[ArrayLike, "..."], axis: int = -1, keepdims: bool = False) -> Array:
    """Euclidean norm along `axis`; value and derivative are `0` at the zero vector.

    **Arguments:**

    - `x`: array of vectors.
    - `axis`: the axis holding the vectors' components.
    - `keepdims`: keep `axis` with size one, as `jnp.sum` does.

    **Returns:**

    `sqrt(sum(x * x, axis))`, the derivative `x / |x|` where `|x| > 0` and `0` at zero.
    """
    sq = jnp.sum(x * x, axis=axis, keepdims=keepdims)
    positive = sq > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, sq, 1)), 0)


def safe_normalize(
    x: Float[ArrayLike, "..."], axis: int = -1, fallback: ArrayLike | None = None
) -> Array:
    """`x / |x|` along `axis`, finite in value and derivative at the zero vector.

    **Arguments:**

    - `x`: array of vectors.
    - `axis`: the axis holding the vectors' components.
    - `fallback`: the result where `x` is the zero vector (broadcast against `x`; its
      derivative is then `0`). Default: `x` itself, i.e. the zero vector stays the zero
      vector (and the derivative there is the identity: `x` divided by `1`).

    **Returns:**

    The unit vectors, shape of `x`.
    """
    x = jnp.asarray(x)
    n = safe_norm(x, axis=axis, keepdims=True)
    ok = n > 0
    unit = x / jnp.where(ok, n, 1)
    if fallback is None:
        return unit
    return jnp.where(ok, unit, fallback)


# --------------------------------------------------------------------------- 3x3 algebra


def det3(M: Float[ArrayLike, "3 3"]) -> Float[Array, ""]:
    """Determinant of a 3x3 matrix, the triple product of its rows `m1 . (m2 x m3)`."""
    M = jnp.asarray(M)
    return M[0] @ jnp.cross(M[1], M[2])


def adjugate3(M: Float[ArrayLike, "3 3"]) -> Float[Array, "3 3"]:
    """Adjugate of a 3x3 matrix, `M @ adj(M) = adj(M) @ M = det(M) I`, without division.

    Its columns are the cross products of the rows of `M` (`m2 x m3, m3 x m1, m1 x m2`),
    so a singular `M` is harmless; `M^-1 = adj(M) / det3(M)` where `det3(M) != 0`.
    """
    M = jnp.asarray(M)
    m1, m2, m3 = M[0], M[1], M[2]
    return jnp.stack([jnp.cross(m2, m3), jnp.cross(m3, m1), jnp.cross(m1, m2)], axis=1)


# --------------------------------------------------------------------------- masked means


def masked_mean(
    values: Float[ArrayLike, "n ..."],
    mask: Bool[ArrayLike, " n"] | Real[ArrayLike, " n"] | None = None,
) -> Float[Array, "..."]:
    """Mean of `values` over their first axis, counting only the rows selected by `mask`.

    $$ \\bar v = \\frac{\\sum_i w_i v_i}{\\max(\\sum_i w_i, 1)} $$

    **Arguments:**

    - `values`: `(n, ...)`, e.g. per-point errors `(n,)` or points `(n, 3)`.
    - `mask`: `(n,)` bool (or `0`/`1` weights), the rows that count; `None`: all of them.

    **Returns:**

    The mean, shape `values.shape[1:]`; `0` when the mask selects nothing (or `n = 0`).
    """
    values = jnp.asarray(values)
    if mask is None:
        return jnp.sum(values, axis=0) / max(values.shape[0], 1)
    w = jnp.asarray(mask).astype(values.dtype)
    total = jnp.sum(w)
    w = w.reshape(w.shape + (1,) * (values.ndim - 1))
    return jnp.sum(values * w, axis=0) / jnp.maximum(total, 1)


def masked_centroid(
    points: Float[ArrayLike, "n d"],
    mask: Bool[ArrayLike, " n"] | Real[ArrayLike, " n"] | None = None,
) -> Float[Array, " d"]:
    """Centroid of the points selected by `mask` (`(n,)` bool or `0`/`1` weights; `None`:
    all); the origin when none is selected. `masked_mean` of points `(n, d)`."""
    return masked_mean(points, mask)
