r"""The three-point solver as a batch-first kernel in component form.

The algorithm of `jaxpose.solvers._p3p` (its module docstring has the mathematics),
step for step: the same four candidate slots in the same order, the same `real` /
`near` / `positive` flags, the same polish, double-root rule, degeneracy tests and
statuses; values equal up to rounding (float64, 2e4 random instances: identical flags,
poses within 1e-9). Every vector is three arrays of the batch shape (`Vec3`), every 3x3
matrix nine (`Mat3`), every `argmax` / `argmin` of the reference (the six sampled pencil
directions, the most indefinite root of the cubic, the adjugate's diagonal pivot, the
largest `|entry|`, the least component of a normal) a chain of `jnp.where`
(`first_extreme`), and the four candidates arrays with a trailing axis of 4.

**XLA:CPU.** The solver is cut into stages (`_prepare`, `_rotated_cubic`, ...,
`_polish` (the three Newton steps and the tolerances), `_pose`), each computed by a few
loops that write its outputs together (`together`): left to itself XLA writes each
output with a loop of its own that recomputes its whole cone (ten times the operations,
and chains of selects that compiled to code running for minutes). `arccos`, `cos` and
`cbrt` become arithmetic (`_kernel_p3p_cubic`). Shortcuts that keep the values: the
indefiniteness ratios are compared cross-multiplied, the plane bases are not normalised
(the null directions and the discriminant's sign do not depend on their scales), each
residual of the polish is computed once, and `isfinite` of a sum of products with `0`
tests twelve values at once. Rounding only differs: `t = mean(P_i) - R mean(m_i)`, no
implicit-function step (an identity in value), and in `three_point_batch` the bearings
`adj(M) [u v 1]` are normalised once (here) rather than twice. `three_point_batch` lays
out its outputs in the loops that apply the masks, after one loop per triplet for the
degeneracy tests and the status. Batches run in passes of at most `CHUNK` triplets
(cache-resident stages).

No derivative flows through this kernel: its inputs pass through
`jax.lax.stop_gradient`, and the pose solvers that use it attach the implicit
derivative of the poses afterwards (as `_p3p` does with its Newton step on the depths).

- `p3p_components`: the core, `Vec3` bearings and points of any batch shape in,
  `P3PCandidates` (poses as `Mat3` / `Vec3` of `(..., 4)` arrays, unmasked, and the
  flags) out: later kernels can score every root without `(..., 3, 3)` arrays.
- `p3p_batch`: `(T, 3, 3)` arrays in and out, equal to `jax.vmap(p3p)`.
- `three_point_batch`: equal to `jax.vmap(three_point)`, one camera for all triplets or
  one per triplet.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from ..geometry._camera import camera_centre, normalize_camera
from ..geometry._numerics import by_precision, safe_div, safe_sqrt
from ._components import (
    Mat3,
    Vec3,
    adjugate,
    combine,
    cross,
    degeneracy,
    det,
    dot,
    first_extreme,
    mat_to_array,
    norm_sq,
    quadratic_form,
    rows,
    scale,
    sub,
    symmetric,
    together,
    trace_product,
    vec_to_array,
)
from ._kernel_linear import in_chunks
from ._kernel_p3p_cubic import cubic_polish, cubic_start
from ._p3p import _DOUBLE_ROOT_ULPS, _NEAR, _NEAR_RESIDUAL, ThreePointResult
from ._status import Status

__all__ = ["P3PCandidates", "p3p_batch", "p3p_components", "three_point_batch"]

Triple = tuple[Vec3, Vec3, Vec3]

# Triplets per pass of `p3p_batch` / `three_point_batch` (see the module docstring).
CHUNK = 4096


class P3PCandidates(NamedTuple):
    """**Fields:** `R` (`Mat3`) and `t` (`Vec3`) of `(..., 4)` arrays: the poses
    `p = R m + t` of the four slots, unmasked (other slots hold what the algebra gave,
    possibly non-finite); `(..., 4)` masks: `real` (exact solutions, finite), `near`
    (approximate: a double root that noise made complex; finite), `positive` (all three
    depths positive)."""

    R: Mat3
    t: Vec3
    real: Bool[Array, "... 4"]
    near: Bool[Array, "... 4"]
    positive: Bool[Array, "... 4"]


def _rsqrt(x):
    """`1 / sqrt(x)` for `x > 0`, else `0`: the value of `safe_div(1, safe_sqrt(x))`, with
    the square root used once (XLA then keeps it inside one fused loop)."""
    ok = x > 0
    return jnp.where(ok, 1 / jnp.sqrt(jnp.where(ok, x, 1)), 0)


def _unit(v: Vec3) -> Vec3:
    """`v / |v|` as `v` times the reciprocal norm; `0` at `v = 0` (as `_p3p._unit`)."""
    return scale(v, _rsqrt(norm_sq(v)))


def _staged(f, *args, group: int = 8):
    """`f(*args)`, its outputs computed in shared loops and written once (`together`)."""
    return together(f(*args), group)


# --------------------------------------------------------------------------- depths


def _pencil(a, b):
    """The conics `D1 = a23 M12 - a12 M23`, `D2 = a23 M13 - a13 M23` (symmetric)."""
    a12, a13, a23 = a
    b12, b13, b23 = b
    zero = jnp.zeros_like(a12)
    D1 = symmetric(a23, -(a23 * b12), zero, a23 - a12, a12 * b23, -a12)
    D2 = symmetric(a23, zero, -(a23 * b13), -a13, a13 * b23, a23 - a13)
    return D1, D2


def _rotated_cubic(a, b):
    """The cubic `det(A + g B)` in the rotated pencil basis (`_p3p._depths`): `B` the
    member of largest `|det|` among six directions 30 degrees apart, `A` orthogonal to
    it. Returns the direction `(cos, sin)` of `B` and the monic coefficients."""
    D1, D2 = _pencil(a, b)
    dtype = D1.xx.dtype
    angles = jnp.arange(6, dtype=dtype) * (jnp.pi / 6)
    cs, sn = jnp.cos(angles), jnp.sin(angles)
    F = [det(combine(cs[k], D1, sn[k], D2)) for k in range(6)]
    _, (c3, cb, sb) = first_extreme(
        [jnp.abs(v) for v in F],
        [(v, jnp.full_like(v, cs[k]), jnp.full_like(v, sn[k])) for k, v in enumerate(F)],
    )
    B = combine(cb, D1, sb, D2)
    A = combine(-sb, D1, cb, D2)
    c0 = det(A)
    c1 = trace_product(adjugate(A), B)
    c2 = trace_product(A, adjugate(B))
    lead = jnp.where(c3 != 0, c3, jnp.finfo(dtype).tiny)
    return cb, sb, c2 / lead, c1 / lead, c0 / lead


def _most_indefinite(roots, cb, sb, a, b):
    """`(alpha, beta)`, normalised: of the members `alpha D1 + beta D2` at the three
    roots `g`, the one of least `trace(adj D) / |D|^2` (the first on ties). The ratio is
    scale-free: it is compared cross-multiplied on the unnormalised members."""
    D1, D2 = _pencil(a, b)
    members = []
    for g in roots:
        alpha, beta = g * cb - sb, g * sb + cb
        D = combine(alpha, D1, beta, D2)
        trace_adj = (
            (D.yy * D.zz - D.yz * D.zy) + (D.zz * D.xx - D.zx * D.xz) + (D.xx * D.yy - D.xy * D.yx)
        )
        size = D.xx * D.xx
        for v in D[1:]:
            size = size + v * v
        members.append((trace_adj, size, alpha, beta))
    best = members[0]
    for m in members[1:]:
        better = m[0] * best[1] < best[0] * m[1]
        best = tuple(jnp.where(better, x, y) for x, y in zip(m, best, strict=True))
    _, _, alpha, beta = best
    inv = _rsqrt(alpha**2 + beta**2)
    return alpha * inv, beta * inv


def _planes(alpha, beta, a, b):
    """Split `D0 = alpha D1 + beta D2` into its two planes: their two normals, the
    member `E` orthogonal to `D0`, and whether `D0` is indefinite (a real pair)."""
    D1, D2 = _pencil(a, b)
    D0 = combine(alpha, D1, beta, D2)
    E = combine(-beta, D1, alpha, D2)
    adj = adjugate(D0)
    columns = [
        Vec3(adj.xx, adj.yx, adj.zx),
        Vec3(adj.xy, adj.yy, adj.zy),
        Vec3(adj.xz, adj.yz, adj.zz),
    ]
    akk, col = first_extreme([adj.xx, adj.yy, adj.zz], columns, smallest=True)
    w = scale(col, _rsqrt(-akk))
    A = Mat3(
        D0.xx, D0.xy - w.z, D0.xz + w.y,
        D0.yx + w.z, D0.yy, D0.yz - w.x,
        D0.zx - w.y, D0.zy + w.x, D0.zz,
    )  # fmt: skip
    A_rows = rows(A)
    entries = [(i, j) for i in range(3) for j in range(3)]
    _, (n1, n2) = first_extreme(
        [jnp.abs(A_rows[i][j]) for i, j in entries],
        [(Vec3(A_rows[0][j], A_rows[1][j], A_rows[2][j]), Vec3(*A_rows[i])) for i, j in entries],
    )
    return (n1, n2), E, akk < 0


def _each(v):
    """A per-triplet array `(...)` against per-slot arrays `(..., 4)`."""
    return v[..., None]


def _plane_bases(normals, E: Mat3):
    """For each plane (normal `n`): the basis `u = n x e` (`e` the axis of the least
    `|n_i|`, the first on ties), `v = n x u`, and the quadratic form of `E` on it,
    `(g11, g12, g22)` (`_p3p._depths`'s `on_plane`). The reference normalises `n` and
    `u`: the null directions `r1 u + g11 v`, `g22 u + r1 v` and the signs of the
    discriminant do not depend on the scales of `u` and `v`."""
    out = []
    for n in normals:
        zero = jnp.zeros_like(n.x)
        _, u = first_extreme(
            [jnp.abs(n.x), jnp.abs(n.y), jnp.abs(n.z)],
            [Vec3(zero, n.z, -n.y), Vec3(-n.z, zero, n.x), Vec3(n.y, -n.x, zero)],
            smallest=True,
        )
        v = cross(n, u)
        g = (quadratic_form(u, E, u), quadratic_form(u, E, v), quadratic_form(v, E, v))
        out.append((u, v, g))
    return out


def _on_planes(bases, indefinite, b):
    """The four candidate depth vectors (the slots: plane 0's two null directions of
    `E`, then plane 1's), as a `Vec3` of `(..., 4)` arrays, and the masks `real` and
    `near` `(..., 4)` before the polish."""
    (u1, v1, g1), (u2, v2, g2) = bases
    shape = (1,) * u1.x.ndim + (4,)  # per-slot constants against (..., 4) arrays
    second = jnp.asarray([False, False, True, True]).reshape(shape)
    first_dir = jnp.asarray([True, False, True, False]).reshape(shape)

    def pick(p, q):
        return jnp.where(second, _each(q), _each(p))

    u = Vec3(*(pick(p, q) for p, q in zip(u1, u2, strict=True)))
    v = Vec3(*(pick(p, q) for p, q in zip(v1, v2, strict=True)))
    g11, g12, g22 = (pick(p, q) for p, q in zip(g1, g2, strict=True))
    disc = g12 * g12 - g11 * g22
    sq = safe_sqrt(disc)
    r1 = -g12 - jnp.where(g12 >= 0, sq, -sq)
    # the two directions r1 u + g11 v and g22 u + r1 v
    s, w = jnp.where(first_dir, r1, g22), jnp.where(first_dir, g11, r1)
    d = Vec3(s * u.x + w * v.x, s * u.y + w * v.y, s * u.z + w * v.z)
    two = jnp.full_like(b[0], 2)
    Msum = _lift_each(symmetric(two, -b[0], -b[1], two, -b[2], two))
    q = quadratic_form(d, Msum, d)
    lam = scale(d, jnp.where(q > 0, jnp.sqrt(1 / jnp.where(q > 0, q, 1)), 0))
    flip = lam.x + lam.y + lam.z < 0
    lam = Vec3(*(jnp.where(flip, -c, c) for c in lam))
    # every real pair is `near` too (`_p3p._depths`: two copies of `disc`, one with a
    # fused multiply-add, must not both drop a double root)
    near = -disc <= _NEAR * (g12 * g12 + jnp.abs(g11 * g22))
    ok = _each(indefinite)
    return lam, (disc >= 0) & ok, near & ok


def _lift_each(m):
    """`_each` on every component of a `Vec3` / `Mat3`."""
    return type(m)(*(_each(v) for v in m))


def _residual(L: Vec3, a, c):
    """The depth equations `(l_i - l_j)^2 + c_ij l_i l_j - a_ij`, three arrays."""
    d01, d02, d12 = L.x - L.y, L.x - L.z, L.y - L.z
    return (
        d01 * d01 + c[0] * (L.x * L.y) - a[0],
        d02 * d02 + c[1] * (L.x * L.z) - a[1],
        d12 * d12 + c[2] * (L.y * L.z) - a[2],
    )


def _maxabs(f):
    return jnp.maximum(jnp.maximum(jnp.abs(f[0]), jnp.abs(f[1])), jnp.abs(f[2]))


def _newton(L: Vec3, f, err, a, c):
    """One guarded Newton step of the polish (`_p3p._depths`) on the depths `L`
    `(..., 4)` of residuals `f` (the largest |residual| `err`): kept where it lowers
    `err`. Returns the depths, their residuals and `err`."""
    c12, c13, c23 = c
    d01, d02, d12 = L.x - L.y, L.x - L.z, L.y - L.z
    # J = [[p, q, 0], [r, 0, s], [0, u, w]]; the columns of adj(J)
    p, q = 2 * d01 + c12 * L.y, -2 * d01 + c12 * L.x
    r, s = 2 * d02 + c13 * L.z, -2 * d02 + c13 * L.x
    u, w = 2 * d12 + c23 * L.z, -2 * d12 + c23 * L.y
    k0 = Vec3(-(s * u), -(r * w), r * u)
    k1 = Vec3(-(w * q), w * p, -(u * p))
    k2 = Vec3(q * s, -(p * s), -(q * r))
    inv = safe_div(1, p * k0.x + q * k0.y)
    step = Vec3(*((k0[i] * f[0] + k1[i] * f[1] + k2[i] * f[2]) * inv for i in range(3)))
    Ln = sub(L, step)
    fn = _residual(Ln, a, c)
    err_n = _maxabs(fn)
    better = err_n < err
    L = Vec3(*(jnp.where(better, x, y) for x, y in zip(Ln, L, strict=True)))
    f = tuple(jnp.where(better, x, y) for x, y in zip(fn, f, strict=True))
    return L, f, jnp.where(better, err_n, err)


def _polish(L: Vec3, a, c, real, near, steps: int = 3):
    """The polish of `_p3p._depths` (`steps` guarded Newton steps) on the depths `L`
    `(..., 4)`, then its double-root rule and tolerances: the depths and
    `(exact, near, positive)` `(..., 4)`; each residual computed once."""
    dtype = L.x.dtype
    a, c = tuple(_each(v) for v in a), tuple(_each(v) for v in c)
    f = _residual(L, a, c)
    err = _maxabs(f)
    for _ in range(steps):
        L, f, err = _newton(L, f, err, a, c)
    tol = by_precision(dtype, f64=1e-6, f32=1e-3)
    ulps = _DOUBLE_ROOT_ULPS * jnp.finfo(dtype).eps
    biggest = jnp.maximum(jnp.maximum(L.x * L.x, L.y * L.y), L.z * L.z)
    exact = (real | (near & (err <= ulps * biggest))) & (err < tol)
    near = (near | real) & ~exact & (err < _NEAR_RESIDUAL)
    return L, (exact, near, (L.x > 0) & (L.y > 0) & (L.z > 0))


# --------------------------------------------------------------------------- poses


def _frame(e1: Vec3, e2: Vec3):
    """The orthonormal frame `(ex, ey, ez)` on two edges (columns of `_p3p`'s frame)."""
    ex = _unit(e1)
    ez = _unit(cross(e1, e2))
    return ex, cross(ez, ex), ez


def _prepare(bearings: Triple, x: Triple):
    """The unit bearings `y_i = f_i / |f_i|` (`0` at `f_i = 0`); the normalised squared
    edges `a_ij`, the cosines `b_ij = y_i . y_j`, the `c_ij = |y_i - y_j|^2`; the square
    root of the edges' sum; the model's frame and centroid."""
    r = tuple(_rsqrt(norm_sq(f)) for f in bearings)
    y = tuple(scale(f, ri) for f, ri in zip(bearings, r, strict=True))
    d12, d13, d23 = sub(x[0], x[1]), sub(x[0], x[2]), sub(x[1], x[2])
    a12, a13, a23 = dot(d12, d12), dot(d13, d13), dot(d23, d23)
    total = a12 + a13 + a23
    inv = safe_div(1, total)
    a = (a12 * inv, a13 * inv, a23 * inv)
    b = (dot(y[0], y[1]), dot(y[0], y[2]), dot(y[1], y[2]))
    e12, e13, e23 = sub(y[0], y[1]), sub(y[0], y[2]), sub(y[1], y[2])
    c = (dot(e12, e12), dot(e13, e13), dot(e23, e23))
    centroid = Vec3(*((x[0][i] + x[1][i] + x[2][i]) / 3 for i in range(3)))
    return y, a, b, c, safe_sqrt(total), _frame(d12, d13), centroid


def _pose(L: Vec3, y: Triple, root, Fx, centroid: Vec3):
    """The pose of each candidate (depths `L` `(..., 4)`, scaled by `root`): with `Fp`
    the frame on the camera-side triangle `P_i = l_i y_i`, `R = Fp Fx^T` and
    `t = mean(P_i) - R mean(x_i)`; and whether both are finite."""
    L = scale(L, _each(root))
    y = tuple(_lift_each(yi) for yi in y)
    P = tuple(scale(yi, li) for yi, li in zip(y, L, strict=True))
    Fp = _frame(sub(P[0], P[1]), sub(P[0], P[2]))
    Fx = tuple(_lift_each(e) for e in Fx)
    # R = Fp Fx^T = sum_k (Fp e_k)(Fx e_k)^T
    R = Mat3(
        *(
            Fp[0][i] * Fx[0][j] + Fp[1][i] * Fx[1][j] + Fp[2][i] * Fx[2][j]
            for i in range(3)
            for j in range(3)
        )
    )
    xbar = _lift_each(centroid)
    R_rows = rows(R)
    t = Vec3(
        *(
            (P[0][i] + P[1][i] + P[2][i]) / 3
            - (R_rows[i][0] * xbar.x + R_rows[i][1] * xbar.y + R_rows[i][2] * xbar.z)
            for i in range(3)
        )
    )
    # all finite iff the sum of their products with 0 (+-0 or NaN) is
    zeros = [v * 0 for v in (*R, *t)]
    return R, t, jnp.isfinite(functools.reduce(jnp.add, zeros))


def p3p_components(bearings: Triple, points: Triple) -> P3PCandidates:
    r"""Every pose with $\lambda_i f_i = R m_i + t$, in component form.

    **Arguments:**
    - `bearings`: three `Vec3` (`f_0, f_1, f_2`, normalised here), arrays of one batch
      shape `(...)`.
    - `points`: three `Vec3`, the model points `m_0, m_1, m_2`, same batch shape.

    **Returns:** `P3PCandidates`, arrays `(..., 4)`: the slots of `_p3p._p3p` in its
    order and with its flags; its values are those of the reference up to rounding.
    No derivative: the inputs are `stop_gradient`-ed. One pass: over more than a few
    thousand triplets, call it on blocks (`in_chunks`, as `p3p_batch` does).
    """
    bearings, points = jax.tree.map(jax.lax.stop_gradient, (bearings, points))
    y, a, b, c, root, Fx, centroid = _staged(_prepare, bearings, points)
    cb, sb, ca, cb_, cc = _staged(_rotated_cubic, a, b)
    roots = _staged(cubic_start, ca, cb_, cc)
    roots = _staged(cubic_polish, roots, ca, cb_, cc)
    alpha, beta = _staged(_most_indefinite, roots, cb, sb, a, b)
    normals, E, indefinite = _staged(_planes, alpha, beta, a, b)
    bases = _staged(_plane_bases, normals, E)
    lam, real, near = _staged(_on_planes, bases, indefinite, b)
    lam, (exact, near, positive) = _staged(_polish, lam, a, c, real, near)
    R, t, finite = _staged(_pose, lam, y, root, Fx, centroid, group=0)
    return P3PCandidates(R, t, exact & finite, near & finite, positive)


def _triple(a: Array) -> Triple:
    """`(..., 3, 3)` rows to three `Vec3` (contiguous arrays: one transpose)."""
    a = jnp.moveaxis(a, (-2, -1), (0, 1))
    return Vec3(*a[0]), Vec3(*a[1]), Vec3(*a[2])


def _pass_size(T: int, chunk: int) -> int:
    """Passes of at most `chunk` triplets, as equal as can be (the last one padded)."""
    passes = -(-T // chunk) if chunk else 1
    return max(1, -(-T // passes))


def _placeholders(c: P3PCandidates, valid):
    """`R` `(..., 4, 3, 3)` and `t` `(..., 4, 3)`: identity and zeros where not valid."""
    eye = (1, 0, 0, 0, 1, 0, 0, 0, 1)
    R = Mat3(*(jnp.where(valid, v, e) for v, e in zip(c.R, eye, strict=True)))
    t = Vec3(*(jnp.where(valid, v, 0) for v in c.t))
    return mat_to_array(R), vec_to_array(t)


def p3p_batch(
    bearings: Float[Array, "T 3 3"],
    points: Float[Array, "T 3 3"],
    *,
    chunk: int = CHUNK,
) -> tuple[Float[Array, "T 4 3 3"], Float[Array, "T 4 3"], Bool[Array, "T 4"]]:
    """`jax.vmap(p3p)` as one batch-first kernel (no derivative: see the module docstring).

    **Arguments:**
    - `bearings`: `(T, 3, 3)`, row `i` of each the direction `f_i` (normalised here).
    - `points`: `(T, 3, 3)`, row `i` of each the model point `m_i`.
    - `chunk`: triplets per pass; larger batches are solved in passes of this size
      (`in_chunks`), `0`: in one pass.

    **Returns:** `(R, t, valid)`, shapes `(T, 4, 3, 3)`, `(T, 4, 3)`, `(T, 4)`; invalid
    slots hold the identity and zeros (never NaN).
    """
    dtype = jnp.result_type(bearings, points, jnp.float32)

    def solve(f, m):
        c = p3p_components(_triple(f), _triple(m))
        valid = c.real & c.positive
        R, t = _placeholders(c, valid)
        return R, t, valid

    f, m = jnp.asarray(bearings, dtype), jnp.asarray(points, dtype)
    return in_chunks(solve, f, m, size=_pass_size(f.shape[0], chunk))


def three_point_batch(
    camera: Float[Array, "*C 3 4"],
    model: Float[Array, "T 3 3"],
    image: Float[Array, "T 3 2"],
    *,
    min_area: float | Float[Array, ""] = 40.0,
    collinear_tol: float | Float[Array, ""] = 5e-3,
    approximate: bool = False,
    chunk: int = CHUNK,
) -> ThreePointResult:
    """`jax.vmap(three_point)` as one batch-first kernel (no derivative: see the module
    docstring), statuses included.

    **Arguments:**
    - `camera`: `C`, `(3, 4)` for all triplets or `(T, 3, 4)` one each, calibrated in the
      world frame (any scale or sign).
    - `model`: `(T, 3, 3)` model points; `image`: `(T, 3, 2)` their pixels.
    - `min_area`, `collinear_tol`, `approximate`: as in `three_point`.
    - `chunk`: triplets per pass, as in `p3p_batch`.

    **Returns:** a `ThreePointResult` with fields `R` `(T, 4, 3, 3)`, `t` `(T, 4, 3)`,
    `valid` `(T, 4)`, `status` `(T,)`; invalid slots hold the identity and zeros.
    """
    sg = jax.lax.stop_gradient
    shared = jnp.ndim(camera) == 2
    # as_float, then the scale and sign; the reference's own functions, vmapped per triplet
    camera = sg((normalize_camera if shared else jax.vmap(normalize_camera))(camera))
    dtype = camera.dtype
    model, image = sg(jnp.asarray(model, dtype)), sg(jnp.asarray(image, dtype))
    centre = camera_centre(camera) if shared else jax.vmap(camera_centre)(camera)

    def solve(model, image, camera=camera, centre=centre):
        x = _triple(model)
        u, v = jnp.moveaxis(image, (-1, -2), (0, 1))  # (3, ...) each
        u, v = (u[0], u[1], u[2]), (v[0], v[1], v[2])
        c = p3p_components(_bearings(camera, u, v), x)
        kw = dict(min_area=min_area, collinear_tol=collinear_tol, approximate=approximate)
        return _finish(c, x, u, v, camera, centre, **kw)

    size = _pass_size(model.shape[0], chunk)
    if shared:
        return in_chunks(solve, model, image, size=size)
    return in_chunks(solve, model, image, camera, centre, size=size)


def _bearings(camera, u, v) -> Triple:
    """`adj(M) [u_i v_i 1]^T` for the three pixels `(u_i, v_i)`: `backproject`'s
    directions in component form, before its normalising (`p3p_components` normalises).
    `camera` normalised, `(3, 4)` or `(..., 3, 4)`."""
    A = adjugate(Mat3(*(camera[..., i, j] for i in range(3) for j in range(3))))

    def ray(ui, vi):
        return Vec3(
            A.xx * ui + A.xy * vi + A.xz,
            A.yx * ui + A.yy * vi + A.yz,
            A.zx * ui + A.zy * vi + A.zz,
        )

    return ray(u[0], v[0]), ray(u[1], v[1]), ray(u[2], v[2])


def _finish(
    c: P3PCandidates, x: Triple, u, v, camera, centre, *, min_area, collinear_tol, approximate
):
    """`three_point`'s tests, statuses, masks and placeholders on the candidates: the
    tests and the status of each triplet computed in one loop (`together`, the slots'
    flags read there), the masks and the poses' placeholders in the loops that lay out
    the outputs. `centre` `(3,)` or `(..., 3)`."""
    found = c.real | (c.near & approximate)
    slots = range(found.shape[-1])

    def per_triplet():
        finite = jnp.all(jnp.isfinite(camera), axis=(-2, -1))
        for w in (*x[0], *x[1], *x[2], *u, *v):
            finite = finite & jnp.isfinite(w)
        degenerate_image, degenerate_model = degeneracy(u, v, x, min_area, collinear_tol)
        ok = finite & ~degenerate_image & ~degenerate_model
        any_found = functools.reduce(jnp.logical_or, (found[..., k] for k in slots))
        any_valid = functools.reduce(
            jnp.logical_or, (found[..., k] & c.positive[..., k] for k in slots)
        )
        status = jnp.where(any_valid, Status.OK, Status.BEHIND_CAMERA)
        status = jnp.where(any_found, status, Status.NO_SOLUTION)
        status = jnp.where(degenerate_model, Status.DEGENERATE_MODEL, status)
        status = jnp.where(degenerate_image, Status.DEGENERATE_IMAGE, status)
        status = jnp.where(finite, status, Status.NOT_FINITE)
        return ok, status.astype(jnp.int32)

    ok, status = together(per_triplet(), 0)
    valid = found & c.positive & ok[..., None]
    o = jnp.moveaxis(centre, -1, 0)  # (3,) shared, or (3, ...)
    t = Vec3(*(a + (oi if oi.ndim == 0 else _each(oi)) for a, oi in zip(c.t, o, strict=True)))
    R, t = _placeholders(c._replace(t=t), valid)
    return ThreePointResult(R, t, valid, status)
