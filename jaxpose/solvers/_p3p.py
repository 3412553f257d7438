r"""The three-point method (the paper's Section 2.1): perspective-three-point, all real solutions.

Given unit bearings $f_i$ and model points $m_i$ ($i = 1, 2, 3$), find every pose with
$\lambda_i f_i = R m_i + t$, $\lambda_i > 0$. The depths satisfy the three law-of-cosines
equations (Grunert)

$$ \lambda_i^2 + \lambda_j^2 - 2 b_{ij} \lambda_i \lambda_j = a_{ij}, \qquad
   b_{ij} = f_i \cdot f_j, \quad a_{ij} = |m_i - m_j|^2, $$

i.e. $\Lambda^T M_{ij} \Lambda = a_{ij}$. Eliminating the scale gives two homogeneous
conics $D_1 = a_{23} M_{12} - a_{12} M_{23}$ and $D_2 = a_{23} M_{13} - a_{13} M_{23}$
whose (up to four) common points are the solutions. Following Lambda Twist (Persson &
Nordberg, ECCV 2018), one *degenerate* member of their pencil is found from the cubic
$\det(D_1 + \gamma D_2) = 0$ (closed form, then Newton-polished); it is a pair of planes
through the origin, split here without an eigen-solver: if $D_0 = l m^T + m l^T$ then
$\operatorname{adj}(D_0) = -(l \times m)(l \times m)^T$ and $D_0 + [l \times m]_\times
= 2 l m^T$ has rank one. Each plane meets the pencil's member "orthogonal" to $D_0$ in
two lines (a 2x2 quadratic form), giving four candidate depth vectors, scaled by the sum
of the three equations and polished by three Gauss-Newton steps on them. The pose
follows from orthonormal frames built on two edges of each triangle.

Of the cubic's three roots the most indefinite member is used (the most negative product
of its two non-zero eigenvalues, read from the adjugate's trace): it is always a real
pair of planes, even when two of the four intersections are complex. Ties (an
equilateral triangle seen from its axis makes all three members equally indefinite) are
harmless: each real pair of planes carries all four solutions.

Symmetric configurations need two more precautions.
- The cubic is solved in a rotated pencil basis, `det(A + g B)` with `B` the member of
  largest `|det|` among six sampled directions: with the plain `det(D1 + g D2)`, the
  equilateral case puts roots at both `g = 0` and `g = inf` (`D1` and `D2` are both
  degenerate), and dividing by the leading coefficient, pure rounding noise, destroyed
  all three roots.
- A *double* solution (the camera on the "danger cylinder" through the three points,
  e.g. a fronto-parallel triangle seen from straight above one of its vertices: the
  `rays=[0,.5,0,0,.25,0]`, equal-depth case) makes the cubic's roots repeat and one
  plane tangent to the orthogonal member: the on-plane discriminant is zero, and
  rounding makes it negative about half the time. Such a near-real pair is accepted
  as an exact solution when, after polishing, it satisfies the depth equations to
  rounding error (`_DOUBLE_ROOT_ULPS` ulps of the largest squared depth, and within the
  tolerance of real roots); the real part of a genuinely complex pair misses them by
  its squared imaginary part (on 2e4 random instances, by 6.5e9 ulps or more in
  float64).
  A double solution is determined to about `sqrt(eps)` only, a triple one (special
  points of the cylinder) to `eps^(1/3)`: the rounded data have solutions that far
  from it, or none. Measured pose errors up to 2.4e-5 in float64; in float32 it may be
  lost (see `tests/test_three_point.py`).

The polish evaluates the equations in the cancellation-free form
`(l_i - l_j)^2 + |f_i - f_j|^2 l_i l_j = a_ij` (float32 on random instances: the true
pose within 1e-4 in 99.2% of them, within 1e-3 in 99.85%; 95.0% and 99.2% with the
expanded form).

Everything is fixed-shape, elementwise or 3x3 algebra: under `jax.vmap` it becomes wide
vector kernels. Measured on 2e4 random noise-free instances in float64 (see
`benchmarks/p3p_rate.py`): the true pose is among the valid solutions in 100% of them,
99.9th-percentile error 5.2e-13 (OpenCV and PoseLib: 1.0e-10).

`three_point` wraps it for the paper's setting: a camera matrix calibrated in the world
frame, pixel measurements, and the degeneracy tests (the paper's Section 2.1: the
triangle's area in the image; and a collinear-model test), each with a status.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float, Int, Real

from ..geometry._camera import backproject, normalize_camera
from ..geometry._numerics import adjugate3, by_precision, det3, safe_div, safe_sqrt
from ..geometry._rotation import hat
from ._status import Status

__all__ = ["ThreePointResult", "p3p", "three_point"]


def _unit(v):
    """`v / |v|` along the last axis, as `v` times the reciprocal norm; `0` at `v = 0`."""
    return v * safe_div(1, safe_sqrt(jnp.sum(v * v, axis=-1, keepdims=True)))


def depressed_cubic(a, b, c):
    """The closed form's start for `x^3 + a x^2 + b x + c` (any shape): with `x = y - a/3`,
    `y^3 + p y + q`; `(p, q, disc, three, m, arg)`, `disc` the discriminant's sign term,
    `three` whether the three roots are real, `m = sqrt(-p/3)` and `arg` the cosine of
    three times the trigonometric angle."""
    p = b - a * a / 3
    q = 2 * a**3 / 27 - a * b / 3 + c
    disc = (q / 2) ** 2 + (p / 3) ** 3
    three = disc < 0
    m = safe_sqrt(-p / 3)
    arg = jnp.clip(jnp.where(three, safe_div(-q / 2, m**3), 0), -1, 1)
    return p, q, disc, three, m, arg


def _cubic_roots(a, b, c):
    """Real roots of `x^3 + a x^2 + b x + c`, shape (3,): all three when real, else the
    single real root three times. Closed form (trigonometric / Cardano without
    cancellation), then two guarded Newton steps."""
    p, q, disc, three, m, arg = depressed_cubic(a, b, c)
    phi = jnp.arccos(arg) / 3
    k = jnp.arange(3, dtype=a.dtype)
    trig = 2 * m * jnp.cos(phi - 2 * jnp.pi * k / 3)
    s = safe_sqrt(disc)
    u = jnp.cbrt(-q / 2 + jnp.where(q <= 0, s, -s))
    one = u - safe_div(p, 3 * u)
    x = jnp.where(three, trig, one) - a / 3

    def f(x):
        return ((x + a) * x + b) * x + c

    for _ in range(2):
        fx = f(x)
        xn = x - safe_div(fx, (3 * x + 2 * a) * x + b)
        x = jnp.where(jnp.abs(f(xn)) < jnp.abs(fx), xn, x)
    return x


class _Candidates(NamedTuple):
    R: Float[Array, "4 3 3"]
    t: Float[Array, "4 3"]
    real: Bool[Array, " 4"]  # exact solutions
    near: Bool[Array, " 4"]  # approximate: a double root that noise made complex
    positive: Bool[Array, " 4"]


# Relative size of a negative discriminant still taken as a (noisy) double root, and the
# largest residual of the scale-free depth equations such an approximate root may keep.
_NEAR = 0.05
_NEAR_RESIDUAL = 1e-2
# Residual of the scale-free depth equations, in ulps of their largest term, below which
# the real part of a near-real pair counts as an exact (double) solution.
_DOUBLE_ROOT_ULPS = 1024


def _p3p(bearings, points) -> _Candidates:
    """Candidates with exact gradients: the roots are found on stop-gradient inputs, then
    a Newton step with a stop-gradient Jacobian, applied to the derivative only, attaches
    the implicit-function derivative of the depths (the value stays the root)."""
    dtype = jnp.result_type(bearings, points, jnp.float32)
    y = _unit(jnp.asarray(bearings, dtype))
    x = jnp.asarray(points, dtype)
    sg = jax.lax.stop_gradient
    lam0, real, near = _depths(sg(y), sg(x))
    d12, d13, d23 = x[0] - x[1], x[0] - x[2], x[1] - x[2]
    a = jnp.stack([d12 @ d12, d13 @ d13, d23 @ d23])
    total = jnp.sum(a)
    a12, a13, a23 = a * safe_div(1, total)
    b12, b13, b23 = y[0] @ y[1], y[0] @ y[2], y[1] @ y[2]

    def implicit(L):
        f = _equations(L, b12, b13, b23, a12, a13, a23)
        J = sg(_equations_jacobian(L, b12, b13, b23))
        adjJ = adjugate3(J)
        step = adjJ @ f * safe_div(1, J[0] @ adjJ[:, 0])
        return L - (step - sg(step))  # value: the root; derivative: -J^-1 dF

    lam = jax.vmap(implicit)(lam0)
    lam = lam * safe_sqrt(total)
    positive = jnp.all(lam > 0, axis=1)

    def frame(e1, e2):
        ex = _unit(e1)
        ez = _unit(jnp.cross(e1, e2))
        return jnp.stack([ex, jnp.cross(ez, ex), ez], axis=1)

    Fx = frame(d12, d13)

    def pose(L):
        P = L[:, None] * y
        R = frame(P[0] - P[1], P[0] - P[2]) @ Fx.T
        return R, jnp.mean(P - x @ R.T, axis=0)

    R, t = jax.vmap(pose)(lam)
    finite = jnp.all(jnp.isfinite(R), axis=(1, 2)) & jnp.all(jnp.isfinite(t), axis=1)
    return _Candidates(R, t, real & finite, near & finite, positive)


def _equations(L, b12, b13, b23, a12, a13, a23):
    """The three law-of-cosines equations (scale-free), residuals `(3,)`."""
    return jnp.stack(
        [
            L[0] ** 2 + L[1] ** 2 - 2 * b12 * L[0] * L[1] - a12,
            L[0] ** 2 + L[2] ** 2 - 2 * b13 * L[0] * L[2] - a13,
            L[1] ** 2 + L[2] ** 2 - 2 * b23 * L[1] * L[2] - a23,
        ]
    )


def _equations_jacobian(L, b12, b13, b23):
    z = jnp.zeros_like(L[0])
    return jnp.stack(
        [
            jnp.stack([2 * (L[0] - b12 * L[1]), 2 * (L[1] - b12 * L[0]), z]),
            jnp.stack([2 * (L[0] - b13 * L[2]), z, 2 * (L[2] - b13 * L[0])]),
            jnp.stack([z, 2 * (L[1] - b23 * L[2]), 2 * (L[2] - b23 * L[1])]),
        ]
    )


def _depths(y, x):
    """Scale-free depths of the four candidates (normalised so that the `a_ij` sum to 1),
    with masks `real` (exact solutions) and `near` (approximate, see `_NEAR`)."""
    dtype = y.dtype
    d12, d13, d23 = x[0] - x[1], x[0] - x[2], x[1] - x[2]
    a = jnp.stack([d12 @ d12, d13 @ d13, d23 @ d23])
    total = jnp.sum(a)
    a12, a13, a23 = a * safe_div(1, total)  # scale-free
    b12, b13, b23 = y[0] @ y[1], y[0] @ y[2], y[1] @ y[2]
    z, o = jnp.zeros((), dtype), jnp.ones((), dtype)
    M12 = jnp.stack([jnp.stack([o, -b12, z]), jnp.stack([-b12, o, z]), jnp.stack([z, z, z])])
    M13 = jnp.stack([jnp.stack([o, z, -b13]), jnp.stack([z, z, z]), jnp.stack([-b13, z, o])])
    M23 = jnp.stack([jnp.stack([z, z, z]), jnp.stack([z, o, -b23]), jnp.stack([z, -b23, o])])
    D1 = a23 * M12 - a12 * M23
    D2 = a23 * M13 - a13 * M23

    # The degenerate members are the zeros of the binary cubic F(al, be) = det(al D1 + be D2)
    # on the unit circle. Solve it in the variable g of A + g B, where B is the member at
    # the sampled direction with the largest |F| (six directions, 30 degrees apart: some
    # direction lies at least 15 degrees from every zero) and A the member orthogonal to
    # it. Then |g| <= cot(15 deg) for every real zero and the cubic is well scaled even
    # when D1 and D2 are both degenerate (zeros at g = 0 and g = inf of the plain pencil,
    # e.g. an equilateral triangle seen from its axis).
    angles = jnp.arange(6, dtype=dtype) * (jnp.pi / 6)
    cs, sn = jnp.cos(angles), jnp.sin(angles)
    F = jax.vmap(lambda c, s: det3(c * D1 + s * D2))(cs, sn)
    kbest = jnp.argmax(jnp.abs(F))
    cb, sb = cs[kbest], sn[kbest]
    B = cb * D1 + sb * D2
    A = -sb * D1 + cb * D2
    c0, c3 = det3(A), F[kbest]
    c1, c2 = jnp.trace(adjugate3(A) @ B), jnp.trace(A @ adjugate3(B))
    lead = jnp.where(c3 != 0, c3, jnp.finfo(dtype).tiny)
    g = _cubic_roots(c2 / lead, c1 / lead, c0 / lead)
    # A + g B = (g cb - sb) D1 + (g sb + cb) D2, normalised (g is bounded: no overflow)
    alpha, beta = g * cb - sb, g * sb + cb
    norm = jnp.sqrt(alpha**2 + beta**2)
    alpha, beta = alpha / norm, beta / norm
    members = alpha[:, None, None] * D1[None] + beta[:, None, None] * D2[None]
    indefiniteness = jax.vmap(lambda D: jnp.trace(adjugate3(D)) * safe_div(1, jnp.sum(D * D)))
    best = jnp.argmin(indefiniteness(members))
    D0 = members[best]
    E = -beta[best] * D1 + alpha[best] * D2  # the pencil member orthogonal to D0

    # Split D0 into its two planes (see the module docstring).
    adj = adjugate3(D0)
    k = jnp.argmin(jnp.diagonal(adj))
    akk = adj[k, k]
    indefinite = akk < 0
    A = D0 + hat(adj[:, k] * safe_div(1, safe_sqrt(-akk)))
    ij = jnp.argmax(jnp.abs(A).reshape(-1))
    normals = jnp.stack([A[:, ij % 3], A[ij // 3, :]])
    Msum = M12 + M13 + M23

    def on_plane(n):
        n = _unit(n)
        e = jnp.eye(3, dtype=dtype)[jnp.argmin(jnp.abs(n))]
        u = _unit(jnp.cross(n, e))
        v = jnp.cross(n, u)
        g11, g12, g22 = u @ E @ u, u @ E @ v, v @ E @ v
        disc = g12 * g12 - g11 * g22
        sq = safe_sqrt(disc)
        r1 = -g12 - jnp.where(g12 >= 0, sq, -sq)
        dirs = jnp.stack([r1 * u + g11 * v, g22 * u + r1 * v])
        q = jnp.einsum("ki,ij,kj->k", dirs, Msum, dirs)
        lam = dirs * safe_sqrt(safe_div(1, q))[:, None]
        lam = jnp.where(jnp.sum(lam, axis=1, keepdims=True) < 0, -lam, lam)
        # A slightly negative discriminant is a real double root pushed off the real line
        # by noise: keep its real part as an approximate solution. `near` holds every
        # real pair too (the polish sorts them): XLA may compute `disc` once with a
        # fused multiply-add and once without (it copies cheap expressions into each
        # fusion that uses them), and a double root's `disc` is then `0` in one copy and
        # `-ulp` in the other; tested on the sign in both masks, it fell through both.
        near = -disc <= _NEAR * (g12 * g12 + jnp.abs(g11 * g22))
        return (
            lam,
            jnp.broadcast_to((disc >= 0) & indefinite, (2,)),
            jnp.broadcast_to(near & indefinite, (2,)),
        )

    lam, real, near = jax.vmap(on_plane)(normals)
    lam, real, near = lam.reshape(4, 3), real.reshape(4), near.reshape(4)

    # The polish evaluates the equations as (l_i - l_j)^2 + c_ij l_i l_j = a_ij with
    # c_ij = |f_i - f_j|^2 = 2 (1 - b_ij), free of the cancellation of the expanded form
    # (its terms are l^2 ~ 1 / angle^2, much larger than a_ij for narrow triangles): it
    # matters in float32, where 1 - b_ij from a rounded dot product keeps few digits.
    e12, e13, e23 = y[0] - y[1], y[0] - y[2], y[1] - y[2]
    c12, c13, c23 = e12 @ e12, e13 @ e13, e23 @ e23

    def residual(L):
        d = jnp.stack([L[0] - L[1], L[0] - L[2], L[1] - L[2]])
        p = jnp.stack([L[0] * L[1], L[0] * L[2], L[1] * L[2]])
        return d * d + jnp.stack([c12, c13, c23]) * p - jnp.stack([a12, a13, a23])

    def polish(L):
        for _ in range(3):
            f = residual(L)
            d01, d02, d12 = L[0] - L[1], L[0] - L[2], L[1] - L[2]
            J = jnp.stack(
                [
                    jnp.stack([2 * d01 + c12 * L[1], -2 * d01 + c12 * L[0], z]),
                    jnp.stack([2 * d02 + c13 * L[2], z, -2 * d02 + c13 * L[0]]),
                    jnp.stack([z, 2 * d12 + c23 * L[2], -2 * d12 + c23 * L[1]]),
                ]
            )
            adjJ = adjugate3(J)
            step = adjJ @ f * safe_div(1, J[0] @ adjJ[:, 0])
            Ln = L - step
            L = jnp.where(jnp.max(jnp.abs(residual(Ln))) < jnp.max(jnp.abs(f)), Ln, L)
        return L, jnp.max(jnp.abs(residual(L)))

    lam, err = jax.vmap(polish)(lam)
    tol = by_precision(dtype, f64=1e-6, f32=1e-3)
    # A double solution (camera on the danger cylinder: e.g. a fronto-parallel triangle
    # seen from above one of its vertices) is a tangency of the two conics: the quadratic
    # on the plane has a zero discriminant, which rounding makes negative as often as not.
    # The real part of such a pair satisfies the equations to rounding error, while the
    # real part of a genuine complex pair misses them by the square of its imaginary part:
    # a residual within _DOUBLE_ROOT_ULPS ulps of the largest squared depth is a real
    # double root (measured in float64: 1514 of 1528 near-real pairs of symmetric
    # configurations within 64 ulps, 1526 within 1024; the complex pairs of 2e4 random
    # instances at 6.5e9 ulps and more).
    ulps = _DOUBLE_ROOT_ULPS * jnp.finfo(dtype).eps * jnp.max(lam * lam, axis=1)
    exact = (real | (near & (err <= ulps))) & (err < tol)
    near = (near | real) & ~exact & (err < _NEAR_RESIDUAL)
    return lam, exact, near


def p3p(bearings: Float[Array, "3 3"], points: Float[Array, "3 3"]):
    r"""Every pose with $\lambda_i f_i = R m_i + t$, $\lambda_i > 0$ (module docstring).

    **Arguments:**
    - `bearings`: `(3, 3)`, row `i` the direction `f_i` towards point `i` (normalised here).
    - `points`: `(3, 3)`, row `i` the model point `m_i`.

    **Returns:** `(R, t, valid)`, shapes `(4, 3, 3)`, `(4, 3)`, `(4,)`. Invalid slots hold
    the identity and zeros: never NaN. One problem; `jax.vmap` it for many.
    """
    c = _p3p(bearings, points)
    valid = c.real & c.positive
    dtype = c.R.dtype
    R = jnp.where(valid[:, None, None], c.R, jnp.eye(3, dtype=dtype)[None])
    t = jnp.where(valid[:, None], c.t, 0)
    return R, t, valid


class ThreePointResult(NamedTuple):
    """**Fields:** `R` `(4, 3, 3)` and `t` `(4, 3)`: candidate poses mapping model to world
    (`p = R m + t`); `valid` `(4,)`; `status`: `OK`, `DEGENERATE_IMAGE`,
    `DEGENERATE_MODEL`, `NO_SOLUTION`, `BEHIND_CAMERA` or `NOT_FINITE`."""

    R: Float[Array, "4 3 3"]
    t: Float[Array, "4 3"]
    valid: Bool[Array, " 4"]
    status: Int[Array, ""]


def _triangle_area(a, b, c):
    """Area of a triangle in 2D or 3D (half the cross product's norm)."""
    u, v = b - a, c - a
    if u.shape[-1] == 2:
        return 0.5 * jnp.abs(u[0] * v[1] - u[1] * v[0])
    return 0.5 * safe_sqrt(jnp.sum(jnp.cross(u, v) ** 2))


def three_point(
    camera: Real[ArrayLike, "3 4"],
    model: Real[ArrayLike, "3 3"],
    image: Real[ArrayLike, "3 2"],
    *,
    min_area: float | Float[Array, ""] = 40.0,
    collinear_tol: float | Float[Array, ""] = 5e-3,
    approximate: bool = False,
) -> ThreePointResult:
    """The three-point method in the world frame, with the degeneracy tests (the paper's
    Section 2.1: the triangle's area in the image; and a collinear-model test).

    **Arguments:**
    - `camera`: `C` `(3, 4)`, calibrated in the world frame (any scale or sign).
    - `model`: `(3, 3)` model points; `image`: `(3, 2)` their pixels.
    - `min_area`: image-triangle area below which the points count as aligned, in the
      image's units squared (default 40 px^2, the paper's; the pipeline passes a
      scale-free one: `Options.min_area` times the problem's spread,
      `jaxpose.strategy.area_threshold`).
    - `collinear_tol`: model-triangle area over its longest edge squared below which the
      model points count as collinear (scale-free; an equilateral triangle has 0.43).
    - `approximate`: also return near-real roots: a double root that image noise pushed
      into a complex pair, kept as its real part (polished as far as it goes). They are
      starting points, not exact solutions; on noisy data they can be the only root near
      the true pose.

    **Returns:** a `ThreePointResult`: up to four poses `p = R m + t` with a mask.
    """
    C = normalize_camera(camera)
    dtype = C.dtype
    model = jnp.asarray(model, dtype)
    image = jnp.asarray(image, dtype)
    centre, directions = backproject(C, image)
    c = _p3p(directions, model)
    t = c.t + centre[None, :]
    area = _triangle_area(image[0], image[1], image[2])
    edges = jnp.stack([model[0] - model[1], model[0] - model[2], model[1] - model[2]])
    longest = jnp.max(jnp.sum(edges**2, axis=1))
    shape = safe_div(_triangle_area(model[0], model[1], model[2]), longest)
    finite = jnp.all(jnp.isfinite(C)) & jnp.all(jnp.isfinite(model)) & jnp.all(jnp.isfinite(image))
    degenerate_image = ~(area >= min_area)
    degenerate_model = ~(shape >= collinear_tol)
    candidate = (c.real | (c.near & approximate)) & c.positive
    valid = candidate & finite & ~degenerate_image & ~degenerate_model
    status = jnp.select(
        [
            ~finite,
            degenerate_image,
            degenerate_model,
            ~jnp.any(c.real | (c.near & approximate)),
            ~jnp.any(valid),
        ],
        [
            Status.NOT_FINITE,
            Status.DEGENERATE_IMAGE,
            Status.DEGENERATE_MODEL,
            Status.NO_SOLUTION,
            Status.BEHIND_CAMERA,
        ],
        Status.OK,
    ).astype(jnp.int32)
    R = jnp.where(valid[:, None, None], c.R, jnp.eye(3, dtype=dtype)[None])
    t = jnp.where(valid[:, None], t, 0)
    return ThreePointResult(R, t, valid, status)
