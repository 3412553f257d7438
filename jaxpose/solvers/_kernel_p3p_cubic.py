"""The cubic of the three-point kernel (`_kernel_p3p`): its real roots in closed form
with arithmetic only, then polished.

`arccos`, `cos` and `cbrt` are library calls on XLA:CPU (17, 7 and 23 ns per element
here, repeated for every use inside a fused loop): `_trisect` and `_cbrt` replace them
with a few Newton / Halley steps. `cubic_start` and `cubic_polish` are the closed
form and the guarded Newton steps of `_p3p._cubic_roots`, on arrays of any shape.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ..geometry._numerics import safe_div, safe_sqrt
from ._p3p import depressed_cubic

__all__ = ["cubic_polish", "cubic_start"]


def _cbrt(v):
    """Real cube root with arithmetic only (no library call): a start from the exponent
    bits (within ~6%), then three Halley steps (cubic convergence). Magnitudes outside
    `[2^-3k, 2^3k]` are scaled into it first, away from overflow and subnormals."""
    dtype = v.dtype
    a = jnp.abs(v)
    f64 = jnp.finfo(dtype).bits == 64
    itype, bias, shift, k = (jnp.int64, 1023, 52, 200) if f64 else (jnp.int32, 127, 23, 40)
    tiny, big = a < 2.0 ** (-3 * k), a > 2.0 ** (3 * k)
    s = jnp.where(tiny, a * 2.0 ** (3 * k), jnp.where(big, a * 2.0 ** (-3 * k), a))
    bits = jax.lax.bitcast_convert_type(s, itype)
    y = jax.lax.bitcast_convert_type(bits // 3 + ((2 * bias) << shift) // 3, dtype)
    for _ in range(3):
        y3 = y * y * y
        y = y * ((y3 + 2 * s) / (2 * y3 + s))
    y = jnp.where(tiny, y * 2.0**-k, jnp.where(big, y * 2.0**k, y))
    y = jnp.where(s == 0, 0, jnp.where(a == jnp.inf, a, y))  # 0 (subnormals too), inf
    return jnp.where(v < 0, -y, y)


def _trisect(t):
    """`cos(arccos(t) / 3)` for `t` in `[-1, 1]`, with arithmetic only.

    `c = 1/2 + r e`, `r = sqrt(1 + t)`: the Chebyshev equation `4 c^3 - 3 c = t` becomes
    `4 r e^3 + 6 e^2 = 1`, increasing and convex in `e` over `[0.35, 0.41]` for every
    `r` in `[0, sqrt 2]` (no double root at `t = -1` any more): four Newton steps from
    the chord reach the root to rounding. Returns `c` and `sin(arccos(t) / 3) >= 0`,
    from `1 - c = (1 - t) / (2 c + 1)^2`, free of cancellation at `t = 1`.
    """
    r = jnp.sqrt(1 + t)
    e0, e2 = 1 / jnp.sqrt(6.0), 0.5 / jnp.sqrt(2.0)
    e = e0 + (e2 - e0) / jnp.sqrt(2.0) * r
    for _ in range(4):
        e2_ = e * e
        e = e - (4 * r * e2_ * e + 6 * e2_ - 1) / (12 * r * e2_ + 12 * e)
    c = 0.5 + r * e
    k = 2 * c + 1
    s = jnp.sqrt((1 - t) * (1 + c)) / k
    return c, s


def cubic_start(a, b, c):
    """Initial real roots of `x^3 + a x^2 + b x + c` (the closed form of
    `_p3p._cubic_roots`, its trigonometric branch through `_trisect`, Cardano's through
    `_cbrt`), three arrays."""
    p, q, disc, three, m, arg = depressed_cubic(a, b, c)
    co, si = _trisect(arg)
    half = jnp.sqrt(3.0) / 2
    # 2 m cos(phi - 2 pi k / 3), phi = arccos(arg) / 3, k = 0, 1, 2
    trig = [2 * m * co, 2 * m * (-0.5 * co + half * si), 2 * m * (-0.5 * co - half * si)]
    s = safe_sqrt(disc)
    u = _cbrt(-q / 2 + jnp.where(q <= 0, s, -s))
    one = u - safe_div(p, 3 * u)
    return [jnp.where(three, x, one) - a / 3 for x in trig]


def cubic_polish(roots, a, b, c):
    """Two guarded Newton steps on each root (as `_p3p._cubic_roots`)."""

    def f(x):
        return ((x + a) * x + b) * x + c

    out = []
    for x in roots:
        for _ in range(2):
            fx = f(x)
            xn = x - safe_div(fx, (3 * x + 2 * a) * x + b)
            x = jnp.where(jnp.abs(f(xn)) < jnp.abs(fx), xn, x)
        out.append(x)
    return out
