"""The small-movement linear step and the Eq. 8 error as batch-first kernels.

The readable single-problem functions (`jaxpose.solvers._linear.linear_step` and
`linear`, `_residuals.pixel_residuals`) are the reference; these kernels compute the same
quantities for many problems and many poses at once, in component form
(`jaxpose.solvers._components`): every per-problem scalar is an array of a batch shape,
every per-match quantity an array of that shape plus a trailing points axis, and the
small systems are written out as scalar expressions over those arrays.

**The frame.** A normalised camera `C = [A Q | c4]` (`A` upper triangular, `Q` a
rotation) sees the point `p` at the normalised coordinates `X / Z, Y / Z` of
`(X, Y, Z) = Q p + A^-1 c4` (`Z` is the depth `c3 . [p 1]`), and the pixel residual of
Eq. 8 is `A2 (x^ - x)`, with `A2` the leading 2x2 block of `A` (over `a33`) and `x` the
observed pixel in normalised coordinates. Turning the camera frame about its optical axis
by the rotation that diagonalises `A2^T A2` makes the squared pixel error
`l1 dx^2 + l2 dy^2` along its two axes. `matches_from_observations` does this once per
problem. In that *whitened* frame the two rows of a match are short (`[1, 0, p]`,
`[0, 1, q]` times a weight): the 26 sums of the normal equations cost about 115
floating-point operations per match, and a step takes about 30% less time than with the
rows written in the world frame.

**The step.** `linear_step_kernel` is `linear_step(..., weighting="depth")`: the
depth-weighted rows at the reprojected pixel (Gauss-Newton on Eq. 8), the rotation about
the masked centroid `c` of the world points, the 21 + 6 sums of the normal equations over
the points, column equilibration, the unrolled Cholesky of `cholesky_solve` with its
pivot floor, a non-finite solution component set to `0`, the exact update
`R <- Rot(r) R`, `t <- Rot(r) (t - c) + c + dt`, and the same step size. The system is
solved in the whitened frame (`G' x' = g'`) and its solution turned back to the world
frame (`x = B^T x'`, `B = diag(Q', Q')`, `Q'` the whitened frame): the same solution as
the reference's world-frame system (an orthogonal change of variables) up to rounding,
with 6 products instead of the 57 of `G = B^T G' B`.

**XLA:CPU.** Two constructions keep the work in a few fused loops:
- the sums over the points are one variadic reduction (`_sum_points`): every term shares
  the projection of its match, computed once per match in a single loop (separate `sum`s
  would each recompute it, or write it to memory first);
- the per-problem tail is cut into stages whose outputs are produced together by
  `_together` (a variadic sum over a padded axis of length 2, exact: the one
  multi-output loop that XLA:CPU forms), so that the Cholesky factor, the solution and
  the rotation are computed once, not again in every consumer.
Both carry derivative rules (`jax.custom_jvp`): the kernels can be differentiated like
the references.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from ..geometry._pose import Observations
from ._components import (
    Mat3,
    Vec3,
    cross,
    dot,
    matmul,
    matvec,
    rotvec_matrix,
    transpose_matvec,
)
from ._linear import default_tol
from ._status import Status

__all__ = [
    "Matches",
    "in_chunks",
    "linear_kernel",
    "linear_step_kernel",
    "matches_from_observations",
    "pixel_error_kernel",
]


class Matches(NamedTuple):
    """Pose problems in component form: batch shape `S'`, `n` matches each.

    **Fields** (per problem: shape `S'`; per match: shape `S' + (n,)`):
    - `frame`: the rotation from the world to the whitened camera frame (module
      docstring), a `Mat3`; `offset`: a `Vec3`, so that `frame p + offset` is the point
      `p` in that frame, its third coordinate the depth.
    - `metric_x`, `metric_y`: the squared pixels per unit of normalised coordinate along
      the frame's two image axes (`l1`, `l2`).
    - `centroid`: the masked centroid `m_c` of the model points, a `Vec3`.
    - `model`: the model points about it, `m - m_c`, a `Vec3` per match (`0` where masked
      out).
    - `x`, `y`: the observed pixels in the frame's normalised coordinates (`0` where masked
      out).
    - `mask`: bool per match, which matches take part.
    - `used`: the number of matches taking part (floating).
    - `spread`: the RMS distance of the used model points from their centroid (`1` where
      `0`): the unit of the translation in the step size.
    """

    frame: Mat3
    offset: Vec3
    metric_x: Array
    metric_y: Array
    centroid: Vec3
    model: Vec3
    x: Array
    y: Array
    mask: Array
    used: Array
    spread: Array


def _unit(v: Vec3, fallback: Vec3) -> tuple[Vec3, Array]:
    norm = jnp.sqrt(dot(v, v))
    ok = norm > 0
    inv = jnp.where(ok, 1 / jnp.where(ok, norm, 1), 0)
    return Vec3(*(jnp.where(ok, a * inv, f) for a, f in zip(v, fallback))), norm


def _safe_ratio(num: Array, den: Array) -> Array:
    ok = den != 0
    return jnp.where(ok, num / jnp.where(ok, den, 1), 0)


def matches_from_observations(obs: Observations) -> Matches:
    """`Observations` with any leading batch axes `S'` (camera `S' + (3, 4)`, model
    `S' + (n, 3)`, image `S' + (n, 2)`, mask `S' + (n,)`, as `jax.vmap(observations)`
    makes them) to `Matches`. Pure `jax.numpy`; runs once per problem.

    The camera's left 3x3 block `M = A Q` is split by Gram-Schmidt on its rows from the
    third (`q3 = m3 / |m3|`, ...); a degenerate camera (`M` singular) gives finite
    placeholders.
    """
    camera = jnp.asarray(obs.camera)
    dtype = camera.dtype
    mask = jnp.asarray(obs.mask, dtype=bool)
    zero = jnp.zeros(camera.shape[:-2], dtype)
    one = jnp.ones(camera.shape[:-2], dtype)
    row = [Vec3(camera[..., i, 0], camera[..., i, 1], camera[..., i, 2]) for i in range(3)]
    c4 = [camera[..., i, 3] for i in range(3)]
    # M = A Q: rows of Q by Gram-Schmidt from the third, A upper triangular.
    q3, a33 = _unit(row[2], Vec3(zero, zero, one))
    a23 = dot(row[1], q3)
    r2 = Vec3(*(m - a23 * q for m, q in zip(row[1], q3)))
    q2, a22 = _unit(r2, Vec3(zero, one, zero))
    q1 = cross(q2, q3)
    a11, a12, a13 = dot(row[0], q1), dot(row[0], q2), dot(row[0], q3)
    # the camera-frame offset A^-1 c4, and the observed pixels in normalised coordinates
    # (u = (a11 x + a12 y + a13) / a33, v = (a22 y + a23) / a33)
    o3 = _safe_ratio(c4[2], a33)
    o2 = _safe_ratio(c4[1] - a23 * o3, a22)
    o1 = _safe_ratio(c4[0] - a12 * o2 - a13 * o3, a11)
    u, v = obs.image[..., 0], obs.image[..., 1]
    ey = _safe_ratio(a33[..., None] * v - a23[..., None], a22[..., None])
    ex = _safe_ratio(a33[..., None] * u - a12[..., None] * ey - a13[..., None], a11[..., None])
    # Pixel metric A2^T A2 / a33^2 = [[al, be], [be, ga]], diagonalised by the rotation
    # of angle th (|th| <= pi / 4) about the optical axis.
    s2 = _safe_ratio(one, a33 * a33)
    al, be, ga = a11 * a11 * s2, a11 * a12 * s2, (a12 * a12 + a22 * a22) * s2
    diff = al - ga
    th = 0.5 * jnp.arctan2(2 * be * jnp.where(diff < 0, -1, 1), jnp.abs(diff))
    cs, sn = jnp.cos(th), jnp.sin(th)
    metric_x = al * cs * cs + 2 * be * cs * sn + ga * sn * sn
    metric_y = al * sn * sn - 2 * be * cs * sn + ga * cs * cs
    r1 = Vec3(*(cs * a + sn * b for a, b in zip(q1, q2)))
    r2 = Vec3(*(cs * b - sn * a for a, b in zip(q1, q2)))
    frame = Mat3(r1.x, r1.y, r1.z, r2.x, r2.y, r2.z, q3.x, q3.y, q3.z)
    offset = Vec3(cs * o1 + sn * o2, cs * o2 - sn * o1, o3)
    x = jnp.where(mask, cs[..., None] * ex + sn[..., None] * ey, 0)
    y = jnp.where(mask, cs[..., None] * ey - sn[..., None] * ex, 0)
    # the model about its masked centroid
    w = mask.astype(dtype)
    model = jnp.where(mask[..., None], jnp.asarray(obs.model, dtype), 0)
    count = jnp.sum(w, axis=-1)
    centroid = jnp.sum(model, axis=-2) / jnp.maximum(count, 1)[..., None]
    centred = jnp.where(mask[..., None], model - centroid[..., None, :], 0)
    spread = jnp.sqrt(jnp.sum(centred * centred, axis=(-2, -1)) / jnp.maximum(count, 1))
    spread = jnp.where(spread > 0, spread, 1)
    return Matches(
        frame,
        offset,
        metric_x,
        metric_y,
        Vec3(centroid[..., 0], centroid[..., 1], centroid[..., 2]),
        Vec3(centred[..., 0], centred[..., 1], centred[..., 2]),
        x,
        y,
        mask,
        count,
        spread,
    )


# --------------------------------------------------------------------------- fused loops


@jax.custom_jvp
def _sum_points(terms: tuple[Array, ...]) -> tuple[Array, ...]:
    """`jnp.sum(term, axis=-1)` of every term, as one variadic reduction (one loop)."""
    init = tuple(jnp.zeros((), a.dtype) for a in terms)
    return tuple(
        jax.lax.reduce(
            tuple(terms),
            init,
            lambda a, b: tuple(x + y for x, y in zip(a, b)),
            (terms[0].ndim - 1,),
        )
    )


@_sum_points.defjvp
def _sum_points_jvp(primals, tangents):
    (terms,), (dterms,) = primals, tangents
    return _sum_points(terms), tuple(jnp.sum(d, axis=-1) for d in dterms)


@jax.custom_jvp
def _together(arrays: tuple[Array, ...]) -> tuple[Array, ...]:
    """The arrays (all of one shape) unchanged, computed in one fused loop: a variadic
    sum over a trailing axis of length 2 padded with `0` (exact)."""
    padded = tuple(
        jax.lax.pad(a[..., None], jnp.zeros((), a.dtype), [(0, 0, 0)] * a.ndim + [(0, 1, 0)])
        for a in arrays
    )
    return _sum_points(padded)


@_together.defjvp
def _together_jvp(primals, tangents):
    (arrays,), (darrays,) = primals, tangents
    return _together(arrays), tuple(darrays)


def _fused(arrays: Sequence[Array], group: int = 0) -> list[Array]:
    """`_together` of arrays broadcast to one shape, in loops of `group` arrays each
    (all in one when `0`): XLA vectorises a loop whose body is short."""
    shape = jnp.broadcast_shapes(*(jnp.shape(a) for a in arrays))
    arrays = [jnp.broadcast_to(a, shape) for a in arrays]
    group = group or len(arrays)
    out = []
    for i in range(0, len(arrays), group):
        part = tuple(arrays[i : i + group])
        out += _together(part) if len(part) > 1 else part
    return out


# --------------------------------------------------------------------------- helpers


def _lift(x: Array, ndim: int) -> Array:
    """`x` with leading unit axes up to `ndim` axes (explicit broadcasting)."""
    x = jnp.asarray(x)
    return x.reshape((1,) * (ndim - x.ndim) + x.shape)


def _prepare(R: Mat3, t: Vec3, m: Matches) -> tuple[Mat3, Vec3, Matches, int]:
    """Poses and problems with the same number of batch axes (`ndim`, returned)."""
    ndim = max(*(jnp.ndim(a) for a in (*R, *t)), jnp.ndim(m.used), jnp.ndim(m.mask) - 1)

    def lift(x, extra=0):
        return _lift(x, ndim + extra)

    R = Mat3(*(lift(a) for a in R))
    t = Vec3(*(lift(a) for a in t))
    m = Matches(
        Mat3(*(lift(a) for a in m.frame)),
        Vec3(*(lift(a) for a in m.offset)),
        lift(m.metric_x),
        lift(m.metric_y),
        Vec3(*(lift(a) for a in m.centroid)),
        Vec3(*(lift(a, 1) for a in m.model)),
        lift(m.x, 1),
        lift(m.y, 1),
        lift(m.mask, 1),
        lift(m.used),
        lift(m.spread),
    )
    return R, t, m, ndim


class _Projection(NamedTuple):
    """The matches seen from one pose per problem, in the whitened frame: the arms
    `a = frame R m'` (`Vec3`, per match), the points `(X, Y, Z)` (`Z` the depth), the
    plane residuals `e_x = X - x Z`, `e_y = Y - y Z` (the normalised residuals times the
    depth), the inverse depths `w` (`0` where masked out or at zero depth); and per
    problem the world centroid `c` of the points."""

    arm: Vec3
    X: Array
    Y: Array
    depth: Array
    ex: Array
    ey: Array
    w: Array
    centre: Vec3


def _project(R: Mat3, t: Vec3, m: Matches) -> _Projection:
    Q = m.frame
    c = Vec3(*(a + b for a, b in zip(matvec(R, m.centroid), t)))
    F = matmul(Q, R)
    o = Vec3(*(a + b for a, b in zip(matvec(Q, c), m.offset)))
    F = Mat3(*(a[..., None] for a in F))
    o = Vec3(*(a[..., None] for a in o))
    arm = matvec(F, m.model)
    X, Y, Z = arm.x + o.x, arm.y + o.y, arm.z + o.z
    ok = m.mask & (jnp.abs(Z) > jnp.finfo(Z.dtype).tiny ** 0.5)
    w = jnp.where(ok, 1 / jnp.where(ok, Z, 1), 0)
    return _Projection(arm, X, Y, Z, X - m.x * Z, Y - m.y * Z, w, c)


def _rms(ss: Array, count: Array) -> Array:
    """`rms`'s ending: `sqrt(ss / count)`, `0` at `0`, a NaN kept."""
    ss = ss / jnp.maximum(count, 1)
    ok = ss > 0
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, ss, 1)), jnp.where(ss == 0, 0, ss))


def _squared_error(pr: _Projection, m: Matches) -> Array:
    """Sum over the used matches of the squared pixel residual (Eq. 8's numerator)."""
    lx, ly = m.metric_x[..., None], m.metric_y[..., None]
    w2 = pr.w * pr.w
    term = jnp.where(m.mask, (lx * pr.ex * pr.ex + ly * pr.ey * pr.ey) * w2, 0)
    return jnp.sum(term, axis=-1)


# --------------------------------------------------------------------------- the step


def _normal_sums(pr: _Projection, m: Matches) -> list[Array]:
    """The 26 sums over the matches that make the normal equations in the whitened frame.

    With `W = l w^2` per axis and the reprojected coordinates `x^ = X w`, `y^ = Y w`,
    the rows of a match in `(t', r')` (rotation about the centroid) are
    `sqrt(W_x) [1, 0, p]` and `sqrt(W_y) [0, 1, q]`,
    `p = (-x^, -x^ a_y, a_z + x^ a_x, -a_y)`, `q = (-y^, -y^ a_y - a_z, y^ a_x, a_x)`, and
    the right-hand sides `-sqrt(W) e` (each pixel residual, with the sign of the row).
    Returned: `sum W_x`, `sum W_y`, `sum W_x p_i` (4), `sum W_y q_i` (4),
    `sum W_x p_i p_j + W_y q_i q_j` (`j <= i`, 10), `sum W_x e_x`, `sum W_y e_y`,
    `sum W_x p_i e_x + W_y q_i e_y` (4).
    """
    a, w = pr.arm, pr.w
    xh = pr.X * w
    yh = pr.Y * w
    w2 = w * w
    Wx = m.metric_x[..., None] * w2
    Wy = m.metric_y[..., None] * w2
    p = [-xh, -xh * a.y, a.z + xh * a.x, -a.y]
    q = [-yh, -yh * a.y - a.z, yh * a.x, a.x]
    Wp = [Wx * pi for pi in p]
    Wq = [Wy * qi for qi in q]
    terms = [Wx, Wy, *Wp, *Wq]
    terms += [Wp[i] * p[j] + Wq[i] * q[j] for i in range(4) for j in range(i + 1)]
    terms += [Wx * pr.ex, Wy * pr.ey]
    terms += [Wp[i] * pr.ex + Wq[i] * pr.ey for i in range(4)]
    return list(_sum_points(tuple(terms)))


def _frame_system(sums: list[Array]) -> tuple[dict, list[Array]]:
    """The normal equations `G' x' = g'` of the step in the whitened frame,
    `x' = (dt', r')` (`G'[i, j]`, `i >= j`), from the 26 sums of `_normal_sums`."""
    Wx, Wy = sums[0], sums[1]
    Wp, Wq, pq = sums[2:6], sums[6:10], sums[10:20]
    gx, gy, gpq = sums[20], sums[21], sums[22:26]
    G: dict = {(0, 0): Wx, (1, 1): Wy, (1, 0): jnp.zeros_like(Wx)}
    for i in range(4):
        G[2 + i, 0] = Wp[i]
        G[2 + i, 1] = Wq[i]
    k = 0
    for i in range(4):
        for j in range(i + 1):
            G[2 + i, 2 + j] = pq[k]
            k += 1
    return G, [-gx, -gy, *(-s for s in gpq)]


def _solve6(G: dict, g: list[Array]) -> list[Array]:
    """`cholesky_solve` of the column-equilibrated system, unrolled over arrays: pivots
    floored at `eps trace / 6` of the equilibrated matrix, the solution scaled back, a
    non-finite component set to `0`."""
    n = 6
    dtype = g[0].dtype
    # the column scales and the pivot floor: one stage (the divisions computed once)
    inv = [1 / jnp.where(G[i, i] > 0, jnp.sqrt(G[i, i]), 1) for i in range(n)]
    trace = sum(G[i, i] * (inv[i] * inv[i]) for i in range(n)) / n
    floor = jnp.where(trace > 0, jnp.finfo(dtype).eps * trace, jnp.finfo(dtype).tiny)
    *inv, floor = _fused([*inv, floor])
    A = {(i, j): G[i, j] * (inv[i] * inv[j]) for (i, j) in G}
    b = [g[i] * inv[i] for i in range(n)]
    L: dict = {}
    d: list = [None] * n
    for j in range(n):
        s = A[j, j]
        for k in range(j):
            s = s - L[j, k] * L[j, k]
        s = jnp.where(jnp.isfinite(s), s, floor)
        dj = jax.lax.rsqrt(jnp.maximum(s, floor))
        col = [dj]
        for i in range(j + 1, n):
            s = A[i, j]
            for k in range(j):
                s = s - L[i, k] * L[j, k]
            col.append(s * dj)
        col = _fused(col)
        d[j] = col[0]
        for i in range(j + 1, n):
            L[i, j] = col[i - j]
    # the two triangular solves: multiplications only, left to the caller's stage
    y: list = [None] * n
    for i in range(n):
        s = b[i]
        for k in range(i):
            s = s - L[i, k] * y[k]
        y[i] = s * d[i]
    x: list = [None] * n
    for i in reversed(range(n)):
        s = y[i]
        for k in range(i + 1, n):
            s = s - L[k, i] * x[k]
        x[i] = s * d[i]
    x = [xi * ii for xi, ii in zip(x, inv)]
    return [jnp.where(jnp.isfinite(xi), xi, 0) for xi in x]


def linear_step_kernel(R: Mat3, t: Vec3, matches: Matches) -> tuple[Mat3, Vec3, Array]:
    """One depth-weighted small-movement step of every pose: the mathematics of
    `linear_step(pose, obs, weighting="depth")` (module docstring).

    **Arguments:**
    - `R`, `t`: the poses (`p = R m + t`), a `Mat3` and a `Vec3` of batch shape `S`.
    - `matches`: the problems (`matches_from_observations`), batch shape `S'`
      broadcastable to `S` (e.g. poses `(P, K)`, problems `(P, 1)`).

    **Returns:** `(R, t, step)`, batch shape `S`: the new poses and the size of the step
    (rotation in rad plus translation over `matches.spread`; `R` is taken to be a
    rotation, as the object's size is measured on the model).
    """
    R, t, m, _ = _prepare(R, t, matches)
    pr = _project(R, t, m)
    G, g = _frame_system(_normal_sums(pr, m))
    x = _solve6(G, g)
    # back to the world frame: x = diag(Q, Q)^T x'
    dt = transpose_matvec(m.frame, Vec3(*x[:3]))
    r = transpose_matvec(m.frame, Vec3(*x[3:]))
    Rr = Mat3(*_fused(list(rotvec_matrix(r))))
    c = pr.centre
    R_new = matmul(Rr, R)
    tc = matvec(Rr, Vec3(t.x - c.x, t.y - c.y, t.z - c.z))
    t_new = Vec3(tc.x + c.x + dt.x, tc.y + c.y + dt.y, tc.z + c.z + dt.z)
    step = jnp.sqrt(dot(r, r)) + jnp.sqrt(dot(dt, dt)) / m.spread
    out = _fused([*R_new, *t_new, step])
    return Mat3(*out[:9]), Vec3(*out[9:12]), out[12]


# --------------------------------------------------------------------------- errors


def pixel_error_kernel(R: Mat3, t: Vec3, matches: Matches) -> Array:
    """The Eq. 8 error (RMS pixel residual over the used matches, px) of every pose: the
    value of `rms(pixel_residuals(transform(pose, model), obs), mask)`, a match at zero
    depth contributing `0`, one behind the camera its residual.

    **Arguments:** as `linear_step_kernel`, e.g. candidate poses `(P, C)` against problems
    `(P, 1)`.

    **Returns:** the errors, batch shape `S`.
    """
    R, t, m, _ = _prepare(R, t, matches)
    return _rms(_squared_error(_project(R, t, m), m), m.used)


# --------------------------------------------------------------------------- the method


def linear_kernel(
    R: Mat3,
    t: Vec3,
    matches: Matches,
    iterations: int = 5,
    tol: float | None = None,
) -> tuple[Mat3, Vec3, Float[Array, "*S"], Float[Array, "*S"], Int[Array, "*S"]]:
    """The small-movement linear method (`linear(obs, init, weighting="depth")`) from
    every pose: `iterations` steps (`jax.lax.fori_loop`), then the Eq. 8 error and the
    status.

    **Arguments:**
    - `R`, `t`: the starting poses, batch shape `S`.
    - `matches`: the problems, batch shape `S'` broadcastable to `S`.
    - `iterations`: the fixed number of steps.
    - `tol`: the last step must be below it for the method to count as converged
      (default `default_tol(dtype)`: `1e-4` in float64, `1e-3` in float32).

    **Returns:** `(R, t, error, step, status)`, batch shape `S`, as `LinearResult`: the
    status is `TOO_FEW_POINTS`, `NOT_FINITE`, `BEHIND_CAMERA`, `LINEAR_NOT_CONVERGED` or
    `OK` (first that applies); a non-finite pose is replaced by the identity and its error
    by the largest float, a non-finite step by the largest float.
    """
    R, t, m, _ = _prepare(R, t, matches)
    dtype = m.x.dtype
    if tol is None:
        tol = default_tol(dtype)
    shape = jnp.broadcast_shapes(*(jnp.shape(a) for a in (*R, *t)), jnp.shape(m.used))
    R = Mat3(*(jnp.broadcast_to(jnp.asarray(a, dtype), shape) for a in R))
    t = Vec3(*(jnp.broadcast_to(jnp.asarray(a, dtype), shape) for a in t))
    big = jnp.finfo(dtype).max

    def body(_, carry):
        R, t, _ = carry
        return linear_step_kernel(R, t, m)

    R, t, step = jax.lax.fori_loop(0, iterations, body, (R, t, jnp.full(shape, big, dtype)))
    pr = _project(R, t, m)
    error = _rms(_squared_error(pr, m), m.used)
    front = jnp.all(jnp.where(m.mask, pr.depth > 0, True), axis=-1)
    finite = jnp.isfinite(error)
    for a in (*R, *t):
        finite = finite & jnp.isfinite(a)
    status = jnp.select(
        [m.used < 3, ~finite, ~front, ~(step < tol)],
        [
            jnp.int32(Status.TOO_FEW_POINTS),
            jnp.int32(Status.NOT_FINITE),
            jnp.int32(Status.BEHIND_CAMERA),
            jnp.int32(Status.LINEAR_NOT_CONVERGED),
        ],
        jnp.int32(Status.OK),
    )
    eye = (1, 0, 0, 0, 1, 0, 0, 0, 1)
    R = Mat3(*(jnp.where(finite, a, jnp.asarray(e, dtype)) for a, e in zip(R, eye)))
    t = Vec3(*(jnp.where(finite, a, jnp.zeros((), dtype)) for a in t))
    error = jnp.where(finite, error, big)
    step = jnp.where(jnp.isfinite(step), step, big)
    return R, t, error, step, status


# --------------------------------------------------------------------------- chunks


def in_chunks(fn: Callable, *args, size: int):
    """`fn(*args)` computed on consecutive blocks of `size` along the leading axis of
    every array in `args` (pytrees: `Mat3`, `Vec3`, `Matches`...), one block after the
    other (`jax.lax.map`), the results put back together.

    A kernel's intermediates are a few dozen arrays of the batch's size; over a block
    of a few thousand problems they stay in the processor's cache, over 100,000 they do
    not. Every leaf of `args` must have the same leading size `P`; the last block is
    padded with copies of the last problem (results dropped).
    """
    leaves = jax.tree.leaves(args)
    P = leaves[0].shape[0]
    if any(a.shape[0] != P for a in leaves):
        raise ValueError("in_chunks needs one leading size for every array")
    if P <= size:
        return fn(*args)
    blocks = -(-P // size)
    pad = blocks * size - P

    def split(a):
        if pad:
            a = jnp.concatenate([a, jnp.repeat(a[-1:], pad, axis=0)])
        return a.reshape((blocks, size) + a.shape[1:])

    out = jax.lax.map(lambda block: fn(*block), jax.tree.map(split, args))
    return jax.tree.map(lambda a: a.reshape((blocks * size,) + a.shape[2:])[:P], out)
