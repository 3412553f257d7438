r"""Three-point (analytic) pose: perspective-three-point (P3P) with every real solution.

SPEC 3.1. Given three unit bearings $f_i$ (rows of `bearings`) and three model points
$m_i$ (rows of `points`), find every rigid motion $(R, t)$ with

$$\lambda_i f_i = R m_i + t, \qquad \lambda_i > 0, \qquad i = 1, 2, 3.$$

**Formulation** (a degenerate-conic solver in the spirit of Lambda Twist, Persson and
Nordberg, ECCV 2018; the code is written from the maths, not from any implementation):

1. Distances are invariant under the motion, so with $a_{ij} = |m_i - m_j|^2$ and
   $c_{ij} = f_i \cdot f_j$ the depths $\Lambda = (\lambda_1, \lambda_2, \lambda_3)$ solve
   $\lambda_i^2 + \lambda_j^2 - 2 c_{ij} \lambda_i \lambda_j = a_{ij}$, i.e.
   $\Lambda^T M_{ij} \Lambda = a_{ij}$ (distances normalised so that $\sum a_{ij} = 1$).
2. Eliminating the right-hand sides gives two homogeneous conics
   $D_1 = a_{23} M_{12} - a_{12} M_{23}$, $D_2 = a_{23} M_{13} - a_{13} M_{23}$, whose
   (at most four) common points are the directions of the solutions.
3. A degenerate member $D_0 = \delta D_1 + \gamma D_2$ of their pencil is a root of the
   homogeneous cubic $\det(\delta D_1 + \gamma D_2) = 0$. All three roots are found in
   closed form (trigonometric / Cardano, on whichever of $\gamma/\delta$, $\delta/\gamma$
   keeps the roots bounded) and polished by Newton's method. The root kept is the one
   whose two non-zero eigenvalues have the most opposite signs, the largest
   $-\sigma_1\sigma_2/(\sigma_1^2+\sigma_2^2)$ (read from the trace and the principal
   minors, no eigen-solver): a real pair of planes, as well separated as possible. When
   the true pose exists, such a root exists: with two real common points exactly one
   root is real and it is a real pair; with four, all three are.
4. The pair is split without eigenvectors: $\operatorname{adj}(D_0) = -p p^T$ gives the
   planes' common line $p$, and $D_0 + [p]_\times = 2 l m^T$ is of rank one.
5. On each plane the pencil member $\gamma D_1 - \delta D_2$ (never zero there) is a
   homogeneous quadratic in a basis $(p, l \times p)$, solved in the cancellation-free
   form; the scale comes from $\sum_{ij} \Lambda^T M_{ij} \Lambda = \sum_{ij} a_{ij}$, the
   sign from $\sum_i \lambda_i > 0$: four candidates.
6. Each candidate is polished by Newton's method on the three distance equations
   written as $(\lambda_i - \lambda_j)^2 + 2 s_{ij} \lambda_i \lambda_j = a_{ij}$ with
   $s_{ij} = 1 - c_{ij} = |f_i - f_j|^2 / 2$ taken from the bearings' differences (no
   cancellation for nearby bearings: this is what makes float32 usable), the 3x3 solve by
   its adjugate; it is kept when the residual is at rounding level and every
   $\lambda_i > 0$. The pose aligns orthonormal frames built from
   $(m_1 - m_2, m_1 - m_3)$ and $(\lambda_1 f_1 - \lambda_2 f_2, \lambda_1 f_1 - \lambda_3 f_3)$
   ($R$ is a rotation to rounding error by construction); $t$ maps the centroids.

Everything is scalar arithmetic on fixed shapes with `jnp.where` selection (no LAPACK, no
eigen-decomposition); candidates live on a trailing axis of 4. Gradients: the closed-form
part sits behind `stop_gradient`, the Newton polish carries the implicit-function
derivative of the depths, and every division, square root and normalisation is guarded
(a guarded denominator becomes `inf`, so the quotient and its derivative are 0), so
neither values nor gradients are ever NaN.

**XLA:CPU notes** (measured with jax 0.10.2). XLA re-fuses cheap element-wise producers
into every consumer fusion and materialises only "expensive" ops (divide, sqrt, ...)
that have several users, and its fused `concatenate` can be exponentially slow on deep
operands. Hence: normalisations divide (instead of multiplying by `rsqrt`), guards sit
inside the division, and arrays are assembled with in-place updates (`_cat`), which took
the vmapped float64 cost from milliseconds to about 2 us per triplet on 2 cores.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from .._status import Status

__all__ = ["ThreePointResult", "p3p", "three_point"]

_PAIRS = ((0, 1), (0, 2), (1, 2))
_NEWTON_CUBIC = 2
_GAUSS_NEWTON = 3


# --------------------------------------------------------------------------------------
# Scalar helpers: a vector is a 3-tuple of arrays, a symmetric matrix a 6-tuple
# (xx, yy, zz, xy, xz, yz). Under vmap every entry is one wide array.


def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _cross(a, b):
    return (
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    )


def _sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def _axpy(s, a, b):
    """s * a + b."""
    return (s * a[0] + b[0], s * a[1] + b[1], s * a[2] + b[2])


def _scale(s, a):
    return (s * a[0], s * a[1], s * a[2])


def _safe_div(num, den, tiny):
    """num / den, and 0 where |den| <= tiny (values and gradients finite).

    The guard sits inside the division (den -> inf), so the result is one expensive op:
    XLA then computes it once and shares it instead of re-fusing the guard's inputs into
    every consumer.
    """
    return num / jnp.where(jnp.abs(den) > tiny, den, jnp.inf)


def _safe_sqrt(x):
    ok = x > 0
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, x, 1)), 0)


def _div_sqrt(a, x, tiny):
    """Components of `a` divided by sqrt(x), zero where x <= tiny.

    Division, not multiplication by `rsqrt`: XLA materialises an expensive op that has
    several users instead of re-fusing its inputs into every consumer, so dividing each
    component makes the normalised vector a cheap, shared value.
    """
    n = jnp.sqrt(jnp.where(x > tiny, x, jnp.inf))
    return tuple(c / n for c in a)


def _unit(a, tiny):
    return _div_sqrt(a, _dot(a, a), tiny)


def _sym_adj(s):
    xx, yy, zz, xy, xz, yz = s
    return (
        yy * zz - yz * yz,
        xx * zz - xz * xz,
        xx * yy - xy * xy,
        xz * yz - xy * zz,
        xy * yz - xz * yy,
        xy * xz - xx * yz,
    )


def _sym_inner(a, b):
    """tr(A B) for symmetric A, B."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + 2 * (a[3] * b[3] + a[4] * b[4] + a[5] * b[5])


def _sym_comb(alpha, a, beta, b):
    return tuple(alpha * x + beta * y for x, y in zip(a, b, strict=True))


def _sym_quad(s, u, v):
    """u^T S v."""
    xx, yy, zz, xy, xz, yz = s
    return (
        u[0] * (xx * v[0] + xy * v[1] + xz * v[2])
        + u[1] * (xy * v[0] + yy * v[1] + yz * v[2])
        + u[2] * (xz * v[0] + yz * v[1] + zz * v[2])
    )


def _select(conds, options):
    """options[k] where conds[k] first holds (conds[-1] may be None for the default)."""
    out = options[-1]
    for cond, opt in zip(conds[-2::-1], options[-2::-1], strict=True):
        out = jax.tree.map(lambda o, x, c=cond: jnp.where(c, o, x), opt, out)
    return out


# --------------------------------------------------------------------------------------
# Polynomials


def _monic_cubic_roots(a, b, c, tiny):
    """Real roots of x^3 + a x^2 + b x + c as a `(3,)` array (a single real root repeated).

    Closed form (trigonometric for three real roots, Cardano's cancellation-free form for
    one), then Newton polishing.
    """
    a3 = a / 3
    p = b - a * a3
    q = c - a3 * b + 2 * a3 * a3 * a3
    half_q = q / 2
    p3 = p / 3
    h = half_q * half_q + p3 * p3 * p3
    one_real = h > 0

    # One real root: u^3 = -q/2 - sign(q) sqrt(h), t = u - p / (3u).
    sqrt_h = _safe_sqrt(jnp.where(one_real, h, 0))
    w = jnp.where(half_q >= 0, -half_q - sqrt_h, -half_q + sqrt_h)
    u = jnp.cbrt(jnp.where(one_real, w, 1))
    t_one = u - _safe_div(p3, u, tiny)

    # Three real roots: t_k = 2 rho cos((phi - 2 pi k) / 3), cos(phi) = -q / (2 rho^3).
    rho = _safe_sqrt(-p3)
    cos_phi = jnp.clip(_safe_div(-half_q, rho * rho * rho, tiny), -1, 1)
    phi = jnp.arccos(jnp.where(one_real, 0, cos_phi))
    k = jnp.arange(3, dtype=a.dtype)
    t_three = 2 * rho * jnp.cos((phi - 2 * jnp.pi * k) / 3)
    x = jnp.where(one_real, t_one, t_three) - a3
    for _ in range(_NEWTON_CUBIC):
        f = ((x + a) * x + b) * x + c
        df = (3 * x + 2 * a) * x + b
        x = x - _safe_div(f, df, tiny)
    return x


def _depth_candidates(c12, c13, c23, a12, a13, a23, eps):
    """The (up to four) depth vectors of the normalised problem, a12 + a13 + a23 = 1.

    Returns `(lambda, real)`: `lambda` a 3-tuple of `(4,)` arrays, `real` `(4,)` whether
    each candidate is a real solution of the distance equations (any depth sign).
    """
    tiny = jnp.finfo(eps.dtype).tiny * 1e8
    zero = jnp.zeros_like(c12)

    # D1 = a23 M12 - a12 M23, D2 = a23 M13 - a13 M23 (symmetric 6-tuples).
    d1 = (a23, a23 - a12, -a12, -a23 * c12, zero, a12 * c23)
    d2 = (a23, -a13, a23 - a13, zero, -a23 * c13, a13 * c23)
    adj1, adj2 = _sym_adj(d1), _sym_adj(d2)
    k0 = d1[0] * adj1[0] + d1[3] * adj1[3] + d1[4] * adj1[4]  # det D1
    k3 = d2[0] * adj2[0] + d2[3] * adj2[3] + d2[4] * adj2[4]  # det D2
    k1 = _sym_inner(adj1, d2)
    k2 = _sym_inner(adj2, d1)
    # det(delta D1 + gamma D2) = k3 g^3 + k2 g^2 d + k1 g d^2 + k0 d^3.
    flip = jnp.abs(k0) > jnp.abs(k3)
    lead = jnp.where(flip, k0, k3)
    ca = _safe_div(jnp.where(flip, k1, k2), lead, tiny)
    cb = _safe_div(jnp.where(flip, k2, k1), lead, tiny)
    cc = _safe_div(jnp.where(flip, k3, k0), lead, tiny)
    roots = _monic_cubic_roots(ca, cb, cc, tiny)  # (3,)

    # Score each root: D0 must be a real line pair (sigma1 sigma2 < 0), best separated.
    g = jnp.where(flip, 1, roots)
    d = jnp.where(flip, roots, 1)
    g, d = _div_sqrt((g, d), g * g + d * d, tiny)
    d0 = _sym_comb(d, d1, g, d2)
    adj0 = _sym_adj(d0)
    minors = adj0[0] + adj0[1] + adj0[2]  # sigma1 sigma2
    trace = d0[0] + d0[1] + d0[2]  # sigma1 + sigma2
    # -sigma1 sigma2 / (sigma1^2 + sigma2^2): in (0, 1/2] for a real pair, 1/2 at right angles.
    score = _safe_div(-minors, trace * trace - 2 * minors, tiny)
    first = (score[0] >= score[1]) & (score[0] >= score[2])
    second = ~first & (score[1] >= score[2])
    g, d = (_select([first, second, None], [x[0], x[1], x[2]]) for x in (g, d))
    g, d = _div_sqrt((g, d), g * g + d * d, tiny)  # unit already; the division shares it
    d0 = _sym_comb(d, d1, g, d2)
    adj0 = _sym_adj(d0)

    # adj(D0) = -p p^T: p is the lines' common point, from the best-conditioned column.
    bxx, byy, bzz, bxy, bxz, byz = adj0
    use_x = (bxx <= byy) & (bxx <= bzz)
    use_y = ~use_x & (byy <= bzz)
    col = _select([use_x, use_y, None], [(bxx, bxy, bxz), (bxy, byy, byz), (bxz, byz, bzz)])
    diag = _select([use_x, use_y, None], [bxx, byy, bzz])
    # A pair that should be real but rounds to a hair on the wrong side is still split
    # (hence |diag|); the Gauss-Newton residual test rejects whatever is not a solution.
    p = _div_sqrt(col, jnp.abs(diag), tiny)

    # N = D0 + [p]_x = 2 l m^T: the largest column is l, the largest row is m.
    xx, yy, zz, xy, xz, yz = d0
    n_rows = (
        (xx, xy - p[2], xz + p[1]),
        (xy + p[2], yy, yz - p[0]),
        (xz - p[1], yz + p[0], zz),
    )
    n_cols = tuple(tuple(n_rows[i][j] for i in range(3)) for j in range(3))

    def largest(vs):
        norms = [_dot(v, v) for v in vs]
        first = (norms[0] >= norms[1]) & (norms[0] >= norms[2])
        second = ~first & (norms[1] >= norms[2])
        return _select([first, second, None], list(vs))

    l_col, l_row = largest(n_cols), largest(n_rows)
    lines = tuple(_cat([a, b]) for a, b in zip(l_col, l_row, strict=True))  # (2,) each

    # On each line: Lambda = alpha p^ + beta v^, with v^ = l^ x p^ in the line's plane;
    # the complementary conic restricted there is a homogeneous quadratic.
    d_perp = _sym_comb(g, d1, -d, d2)
    p_hat = _unit(p, tiny)
    v_hat = _unit(_cross(lines, p_hat), tiny)
    qa = _sym_quad(d_perp, p_hat, p_hat)
    qb = 2 * _sym_quad(d_perp, p_hat, v_hat)
    qc = _sym_quad(d_perp, v_hat, v_hat)
    disc = qb * qb - 4 * qa * qc
    # A tangency (double solution) can come out a little negative, by more than rounding
    # in qa, qb, qc when the cubic's root is itself inexact: accept it (at the vertex) and
    # let the Newton residual and the geometric check decide.
    norm2 = _sym_inner(d_perp, d_perp)
    disc_ok = disc >= -jnp.sqrt(eps) * norm2
    sq = _safe_sqrt(disc)
    qq = jnp.where(qb >= 0, -(qb + sq) / 2, -(qb - sq) / 2)
    # Roots (alpha, beta) ~ (qq, qa) and (qc, qq): four candidates, two per line.
    alpha = _cat([qq, qc])
    beta = _cat([qa, qa, qq])
    v4 = tuple(_cat([x, x]) for x in v_hat)
    dvec = _axpy(alpha, p_hat, _scale(beta, v4))
    quad = 2 * _dot(dvec, dvec) - 2 * (
        c12 * dvec[0] * dvec[1] + c13 * dvec[0] * dvec[2] + c23 * dvec[1] * dvec[2]
    )
    sign = jnp.where(dvec[0] + dvec[1] + dvec[2] < 0, -1, 1)
    real = _cat([disc_ok, disc_ok]) & (quad > tiny)
    return _div_sqrt(_scale(sign, dvec), quad, tiny), real


def _jacobian(l1, l2, l3, s12, s13, s23):
    """J = [[ja, jb, 0], [jc, 0, jd], [0, je, jf]] of the distance equations, and det J."""
    ja, jb = 2 * (l1 - l2 + s12 * l2), 2 * (l2 - l1 + s12 * l1)
    jc, jd = 2 * (l1 - l3 + s13 * l3), 2 * (l3 - l1 + s13 * l1)
    je, jf = 2 * (l2 - l3 + s23 * l3), 2 * (l3 - l2 + s23 * l2)
    return (ja, jb, jc, jd, je, jf), -ja * jd * je - jb * jc * jf


def _solve(jac, r):
    """adj(J) r (divide by det J for J^-1 r)."""
    ja, jb, jc, jd, je, jf = jac
    return (
        -jd * je * r[0] - jb * jf * r[1] + jb * jd * r[2],
        -jc * jf * r[0] + ja * jf * r[1] - ja * jd * r[2],
        jc * je * r[0] - ja * je * r[1] - jb * jc * r[2],
    )


@jax.custom_jvp
def _implicit_depths(lam, s12, s13, s23, a12, a13, a23, tiny):
    """The converged depths `lam`, with their derivative from the implicit function theorem.

    The value is `lam` itself (computed under `stop_gradient`); the JVP is
    `-J^-1 (dF/ds ds + dF/da da)` for the distance equations F at `lam`, exact at a
    solution. This keeps the reverse pass one 3x3 solve deep instead of differentiating
    the root finding and every Newton step.
    """
    return lam


@_implicit_depths.defjvp
def _implicit_depths_jvp(primals, tangents):
    lam, s12, s13, s23, a12, a13, a23, tiny = primals
    _, ds12, ds13, ds23, da12, da13, da23, _ = tangents
    l1, l2, l3 = lam
    jac, det = _jacobian(l1, l2, l3, s12, s13, s23)
    df = (
        2 * l1 * l2 * ds12 - da12,
        2 * l1 * l3 * ds13 - da13,
        2 * l2 * l3 * ds23 - da23,
    )
    step = _solve(jac, df)
    dlam = tuple(-_safe_div(x, det, tiny) for x in step)
    return lam, dlam


def _gauss_newton(lam, s12, s13, s23, a12, a13, a23, tiny):
    """Polish the depths on (lambda_i - lambda_j)^2 + 2 s_ij lambda_i lambda_j = a_ij.

    With `s_ij = 1 - c_ij` computed from the difference of the bearings, the residual has
    no cancellation when bearings are close (narrow fields of view).

    Newton steps (the system is square), the 3x3 solve by its adjugate; the iterate with
    the smallest residual is returned. Returns `(lambda, residual)`, the residual the
    largest absolute equation error (the caller rejects candidates that did not converge).
    """

    def residual(l1, l2, l3):
        d12, d13, d23 = l1 - l2, l1 - l3, l2 - l3
        return (
            d12 * d12 + 2 * s12 * l1 * l2 - a12,
            d13 * d13 + 2 * s13 * l1 * l3 - a13,
            d23 * d23 + 2 * s23 * l2 * l3 - a23,
        )

    def size(r):
        return jnp.maximum(jnp.maximum(jnp.abs(r[0]), jnp.abs(r[1])), jnp.abs(r[2]))

    l1, l2, l3 = lam
    best, best_err = lam, size(residual(*lam))
    for _ in range(_GAUSS_NEWTON):
        jac, det = _jacobian(l1, l2, l3, s12, s13, s23)
        s1, s2, s3 = _solve(jac, residual(l1, l2, l3))
        l1 = l1 - _safe_div(s1, det, tiny)
        l2 = l2 - _safe_div(s2, det, tiny)
        l3 = l3 - _safe_div(s3, det, tiny)
        # Keep the best iterate: near a double root the Jacobian is nearly singular and a
        # full step can throw a good start away.
        err = size(residual(l1, l2, l3))
        better = err < best_err
        best = tuple(jnp.where(better, n, o) for n, o in zip((l1, l2, l3), best, strict=True))
        best_err = jnp.where(better, err, best_err)
    return best, best_err


class _P3PFull(NamedTuple):
    R: Float[Array, "4 3 3"]
    t: Float[Array, "4 3"]
    valid: Bool[Array, "4"]
    real: Bool[Array, "4"]


def _cat(parts):
    """Concatenate along the last axis by in-place updates, not `concatenate`.

    XLA's CPU fusion emitter can recompute the operands of a fused concatenate once per
    operand and nesting level (exponentially slow on deep element-wise graphs); a chain of
    dynamic-update-slices materialises each part once.
    """
    parts = [jnp.asarray(x) for x in parts]
    parts = [x[..., None] if x.ndim == 0 else x for x in parts]
    lead = jnp.broadcast_shapes(*(x.shape[:-1] for x in parts))
    size = sum(x.shape[-1] for x in parts)
    dtype = jnp.result_type(*parts)
    out = jnp.zeros((*lead, size), dtype)
    k = 0
    for x in parts:
        out = out.at[..., k : k + x.shape[-1]].set(jnp.broadcast_to(x, (*lead, x.shape[-1])))
        k += x.shape[-1]
    return out


def _rows(x):
    """A (3, k) array as a 3-tuple of k-tuples of scalars."""
    return [tuple(x[i, k] for k in range(x.shape[1])) for i in range(3)]


def _p3p_full(f, m, offset, usable, dtype) -> _P3PFull:
    """P3P on scalar tuples: `f`, `m` three 3-tuples each; `t` is shifted by `offset`.

    `usable` (bool scalar) masks every slot; `real` in the result marks candidates that
    solve the distance equations whatever their depth signs (for `BEHIND_CAMERA`).
    """
    eps = jnp.asarray(jnp.finfo(dtype).eps, dtype)
    tiny = jnp.finfo(dtype).tiny * 1e8

    bearings_ok = (_dot(f[0], f[0]) > tiny) & (_dot(f[1], f[1]) > tiny) & (_dot(f[2], f[2]) > tiny)
    f = [_unit(fi, tiny) for fi in f]
    x12, x13, x23 = _sub(m[0], m[1]), _sub(m[0], m[2]), _sub(m[1], m[2])
    a12, a13, a23 = _dot(x12, x12), _dot(x13, x13), _dot(x23, x23)
    total = a12 + a13 + a23
    inv_total = _safe_div(1, total, tiny)
    n12, n13, n23 = a12 * inv_total, a13 * inv_total, a23 * inv_total
    # s_ij = 1 - f_i . f_j = |f_i - f_j|^2 / (|f_i|^2 + |f_j|^2), from the differences
    # (accurate for nearby bearings; a true division also makes XLA share the value).
    s12, s13, s23 = (
        _safe_div(_dot(dij, dij), _dot(f[i], f[i]) + _dot(f[j], f[j]), tiny)
        for i, j in _PAIRS
        for dij in (_sub(f[i], f[j]),)
    )
    c12, c13, c23 = 1 - s12, 1 - s13, 1 - s23

    sg = jax.lax.stop_gradient
    scale = _safe_sqrt(total)

    # Orthonormal frames from two edges, model side and camera side: R = Fy Fx^T.
    def frame(e1, e2):
        ex = _unit(e1, tiny)
        normal = _cross(e1, e2)
        ez = _unit(normal, tiny)
        return (ex, _cross(ez, ex), ez), _dot(normal, normal)

    fx, model_area2 = frame(x12, x13)
    # A (numerically) collinear model leaves a rotation about its line free: no solution.
    model_ok = model_area2 > eps * a12 * a13
    coeffs = (s12, s13, s23, n12, n13, n23)
    lam, real = _depth_candidates(*map(sg, (c12, c13, c23, n12, n13, n23)), eps)
    lam, _ = _gauss_newton(lam, *map(sg, coeffs), tiny)
    # Converged: each equation holds to a small multiple of its own terms' rounding
    # (all terms are <= a_ij <= 1 on a positive solution, so this is strict there).
    for (i, j), s, a in zip(_PAIRS, coeffs[:3], coeffs[3:], strict=True):
        d = lam[i] - lam[j]
        sq, cross = d * d, 2 * sg(s) * lam[i] * lam[j]
        res = sq + cross - sg(a)
        real = real & (jnp.abs(res) <= 8 * jnp.sqrt(eps) * (sq + jnp.abs(cross) + sg(a)))
    lam = _implicit_depths(lam, *coeffs, tiny)
    positive = (lam[0] > 0) & (lam[1] > 0) & (lam[2] > 0)
    lam = _scale(scale, lam)
    p1 = _scale(lam[0], f[0])
    fy, image_area2 = frame(_sub(p1, _scale(lam[1], f[1])), _sub(p1, _scale(lam[2], f[2])))
    rot = [sum(fy[k][i] * fx[k][j] for k in range(3)) for i in range(3) for j in range(3)]
    # t = mean_n (lambda_n f_n) - R mean_n (m_n)   (offset added below)
    m_mean = [(m[0][j] + m[1][j] + m[2][j]) / 3 for j in range(3)]
    trans = [
        (lam[0] * f[0][i] + lam[1] * f[1][i] + lam[2] * f[2][i]) / 3
        - sum(rot[3 * i + j] * m_mean[j] for j in range(3))
        for i in range(3)
    ]
    finite = jnp.isfinite(lam[0] + lam[1] + lam[2]) & jnp.isfinite(sum(m_mean))
    # On a solution the camera-side triangle is the model's: same area (a degenerate
    # camera-side frame would make R singular).
    same_area = image_area2 >= model_area2 / 4
    real = real & finite & bearings_ok & model_ok & same_area
    trans = [x + o for x, o in zip(trans, offset, strict=True)]
    valid = real & positive & usable
    # One shared copy of the mask: a division is "expensive" to XLA, so it is computed
    # once rather than re-fused (with everything it depends on) into all 48 outputs.
    keep = _safe_div(1, jnp.where(valid, 1, 0).astype(dtype), tiny) > 0
    eye = (1, 0, 0, 0, 1, 0, 0, 0, 1)
    rot = [jnp.where(keep, x, e) for x, e in zip(rot, eye, strict=True)]
    trans = [jnp.where(keep, x, 0) for x in trans]
    return _P3PFull(
        R=_cat([x[:, None] for x in rot]).reshape(4, 3, 3).astype(dtype),
        t=_cat([x[:, None] for x in trans]).astype(dtype),
        valid=valid,
        real=real,
    )


def p3p(
    bearings: Float[ArrayLike, "3 3"], points: Float[ArrayLike, "3 3"]
) -> tuple[Float[Array, "4 3 3"], Float[Array, "4 3"], Bool[Array, "4"]]:
    r"""Every pose with $\lambda_i f_i = R m_i + t$, $\lambda_i > 0$ (see the module docstring).

    **Arguments:**

    - `bearings`: `(3, 3)`, row $i$ the unit direction $f_i$ towards point $i$ (normalised
      again here).
    - `points`: `(3, 3)`, row $i$ the model point $m_i$.

    **Returns:** `(R, t, valid)`: `R` `(4, 3, 3)` rotations, `t` `(4, 3)` translations and
    `valid` `(4,)` bool. Invalid slots hold the identity and zeros: never NaN. One problem
    at a time; `jax.vmap` it for many.
    """
    dtype = jnp.promote_types(jnp.result_type(bearings, points), jnp.float32)
    bearings = jnp.asarray(bearings, dtype)
    points = jnp.asarray(points, dtype)
    zero = jnp.zeros((), dtype)
    out = _p3p_full(_rows(bearings), _rows(points), (zero, zero, zero), True, dtype)
    return out.R, out.t, out.valid


class ThreePointResult(NamedTuple):
    """Output of [`three_point`][]."""

    R: Float[Array, "4 3 3"]
    """Rotations (model to world), invalid slots the identity."""
    t: Float[Array, "4 3"]
    """Translations (model to world), invalid slots zero: world point `p = R m + t`."""
    valid: Bool[Array, "4"]
    """Which slots hold a solution."""
    status: Int[Array, ""]
    """An `int32` [`Status`][]: `OK`, `DEGENERATE_IMAGE`, `DEGENERATE_MODEL`, `NO_SOLUTION`
    (no real root), `BEHIND_CAMERA` (real roots, all with some negative depth) or
    `NOT_FINITE`."""


def three_point(
    camera: Float[ArrayLike, "3 4"],
    model: Float[ArrayLike, "3 3"],
    image: Float[ArrayLike, "3 2"],
    *,
    min_area: float = 40.0,
    collinear_tol: float = 1e-3,
) -> ThreePointResult:
    r"""Three-segment method of SPEC 3.1: all poses from three 2D-3D matches.

    The camera is the paper's projection matrix, $s [u, v, 1]^T = C [p, 1]^T$, known up to
    any non-zero scale (of either sign). With $M = C_{:, :3}$, the centre is
    $c = -M^{-1} C_{:, 3}$ and the world-frame bearing of pixel $(u, v)$ is
    $\operatorname{sign}(\det M) M^{-1} [u, v, 1]^T = \operatorname{adj}(M) [u, v, 1]^T / |\det M|$,
    normalised, so that positive depth is in front of the camera. Then [`p3p`][] gives
    $(R, t')$ and $t = t' + c$.

    **Arguments:**

    - `camera`: `(3, 4)` projection matrix $C$ (world frame).
    - `model`: `(3, 3)` model points $m_i$ (rows).
    - `image`: `(3, 2)` pixels $(u_i, v_i)$ (rows).
    - `min_area`: smallest accepted image triangle area, pixel^2 (the paper: 40).
    - `collinear_tol`: smallest accepted model triangle area / (longest edge)^2
      (scale invariant; an equilateral triangle has 0.433).

    **Returns:** a [`ThreePointResult`][]. Degenerate or non-finite triplets get
    `valid` all False and finite placeholders. One triplet at a time; vmap for many.
    """
    camera = jnp.asarray(camera)
    model = jnp.asarray(model)
    image = jnp.asarray(image)
    dtype = jnp.promote_types(jnp.result_type(camera, model, image), jnp.float32)
    camera, model, image = (jnp.asarray(x, dtype) for x in (camera, model, image))
    tiny = jnp.finfo(dtype).tiny * 1e8

    finite = jnp.all(jnp.isfinite(camera)) & jnp.all(jnp.isfinite(model))
    finite = finite & jnp.all(jnp.isfinite(image))
    camera = jnp.where(finite, camera, jnp.eye(3, 4, dtype=dtype))
    model = jnp.where(finite, model, jnp.eye(3, dtype=dtype))
    image = jnp.where(finite, image, jnp.zeros((3, 2), dtype))

    # Image triangle area (pixel^2).
    e1 = image[1] - image[0]
    e2 = image[2] - image[0]
    area_img = jnp.abs(e1[0] * e2[1] - e1[1] * e2[0]) / 2
    image_ok = area_img >= min_area

    # Model collinearity: area / longest edge^2.
    m = _rows(model)
    x12, x13, x23 = _sub(m[1], m[0]), _sub(m[2], m[0]), _sub(m[2], m[1])
    cr = _cross(x12, x13)
    area_model = _safe_sqrt(_dot(cr, cr)) / 2
    longest = jnp.maximum(jnp.maximum(_dot(x12, x12), _dot(x13, x13)), _dot(x23, x23))
    model_ok = area_model >= collinear_tol * longest
    model_ok = model_ok & (longest > tiny)

    # Centre and world-frame bearings via the adjugate of M.
    M = [tuple(camera[i, k] for k in range(3)) for i in range(3)]
    # adj(M) columns are cross products of rows: adj(M) = [M1 x M2, M2 x M0, M0 x M1].
    cols = (_cross(M[1], M[2]), _cross(M[2], M[0]), _cross(M[0], M[1]))
    det = _dot(M[0], cols[0])
    c4 = tuple(camera[i, 3] for i in range(3))

    def adj_mul(v):  # adj(M) v
        return tuple(cols[0][i] * v[0] + cols[1][i] * v[1] + cols[2][i] * v[2] for i in range(3))

    centre = _scale(-_safe_div(1, det, tiny), adj_mul(c4))
    one = jnp.ones((), dtype)
    bearings = [adj_mul((image[i, 0], image[i, 1], one)) for i in range(3)]
    camera_ok = jnp.abs(det) > tiny

    usable = finite & image_ok & model_ok & camera_ok
    sol = _p3p_full(bearings, m, centre, usable, dtype)
    R, t, valid = sol.R, sol.t, sol.valid

    status = jnp.where(
        jnp.any(valid),
        int(Status.OK),
        jnp.where(
            jnp.any(sol.real & camera_ok), int(Status.BEHIND_CAMERA), int(Status.NO_SOLUTION)
        ),
    )
    status = jnp.where(model_ok, status, int(Status.DEGENERATE_MODEL))
    status = jnp.where(image_ok, status, int(Status.DEGENERATE_IMAGE))
    status = jnp.where(finite, status, int(Status.NOT_FINITE))
    return ThreePointResult(R=R, t=t, valid=valid, status=status.astype(jnp.int32))
