"""Small dense linear algebra, written out element by element.

The solvers' inner loops solve many tiny symmetric positive (semi-)definite systems
(6x6 normal equations, one per triplet and iteration). `jnp.linalg.solve` and
`jax.scipy.linalg.cho_solve` lower to one LAPACK call per matrix on the CPU, which
dominates the cost of a vmapped batch (about 1.9 us per 6x6 system here, against 0.08 us
for the unrolled form below: `benchmarks/run.py` times both). Unrolled over the fixed
size, a Cholesky factorisation is a few dozen elementwise operations that XLA fuses into
wide vector kernels under `jax.vmap`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ..geometry._validate import no_type_check

__all__ = [
    "JACOBI_SWEEPS",
    "cholesky_solve",
    "jacobi_eigh",
    "positive_definite_solve",
    "symmetric_pinv",
]


# `cholesky_solve` checks its arguments' shapes itself (a `ValueError` naming it): no
# run-time type check comes before its own.
@no_type_check
def cholesky_solve(A: Float[Array, "n n"], b: Float[Array, " n"]) -> Float[Array, " n"]:
    """Solve `A x = b` for a small symmetric positive semi-definite `A` (Cholesky,
    unrolled over the static size `n`).

    Pivots below `eps * trace(A) / n` (a singular or indefinite direction) are replaced
    by that floor, so the answer is always finite: in a rank-deficient direction the
    solution is damped towards zero instead of blowing up. Differentiable (its
    derivative is that of the unrolled arithmetic). One system; `jax.vmap` it for many.
    """
    n = A.shape[-1]
    if A.shape != (n, n) or b.shape != (n,):
        raise ValueError(f"cholesky_solve needs A (n, n) and b (n,), got {A.shape}, {b.shape}")
    dtype = jnp.result_type(A, b)
    eps = jnp.finfo(dtype).eps
    scale = jnp.trace(A) / n
    floor = jnp.where(scale > 0, eps * scale, jnp.finfo(dtype).tiny)
    L, inv, _ = _factor(A, floor)
    return _substitute(L, inv, b).astype(dtype)


def _factor(A, floor):
    """The unrolled Cholesky factorisation of `A`: `(L, 1 / diag(L), pivots)`, each pivot
    (the square of `L`'s diagonal entry before any flooring) raised to `floor` when below
    it or not finite."""
    n = A.shape[-1]
    L: list[list] = [[None] * n for _ in range(n)]
    inv: list = [None] * n
    pivots: list = [None] * n
    for j in range(n):
        s = A[j, j]
        for k in range(j):
            s = s - L[j][k] * L[j][k]
        pivots[j] = s
        s = jnp.where(jnp.isfinite(s), s, floor)
        d = jnp.sqrt(jnp.maximum(s, floor))
        inv[j] = 1 / d
        L[j][j] = d
        for i in range(j + 1, n):
            s = A[i, j]
            for k in range(j):
                s = s - L[i][k] * L[j][k]
            L[i][j] = s * inv[j]
    return L, inv, pivots


def _substitute(L, inv, b) -> Array:
    """`(L L^T)^-1 b` from `_factor`'s `L` and `inv`: forward, then back substitution."""
    n = len(inv)
    y: list = [None] * n
    for i in range(n):
        s = b[i]
        for k in range(i):
            s = s - L[i][k] * y[k]
        y[i] = s * inv[i]
    x: list = [None] * n
    for i in reversed(range(n)):
        s = y[i]
        for k in range(i + 1, n):
            s = s - L[k][i] * x[k]
        x[i] = s * inv[i]
    return jnp.stack(x)


def _equilibrate(A):
    """`(D A D, diag(D))` symmetrised, `D = diag(|A_ii|)^(-1/2)` (zero where `A_ii = 0`)."""
    diag = jnp.abs(jnp.diagonal(A))
    ok = diag > 0
    d = jnp.where(ok, 1 / jnp.sqrt(jnp.where(ok, diag, 1)), 0)
    Ae = A * d[:, None] * d[None, :]
    return 0.5 * (Ae + Ae.T), d


#: Sweeps of `jacobi_eigh`: each sweep squares the off-diagonal's size (once it is
#: small); ten leave it at rounding in float64 for 6x6 matrices (2,000 each of random,
#: positive, rank 4, graded over 10^10: reconstruction within 6e-15 of the largest entry;
#: with exactly repeated eigenvalues, whose convergence is slower, 3.4e-14).
JACOBI_SWEEPS = 10


def jacobi_eigh(A: Float[Array, "k k"], sweeps: int = JACOBI_SWEEPS):
    """Eigenvalues and eigenvectors `(lam, V)` of a small symmetric matrix, `A = V
    diag(lam) V^T`, by cyclic Jacobi rotations (Golub & Van Loan, Algorithm 8.5.3): no
    LAPACK call (a program holding one must set LAPACK up when it is loaded, a third of a
    second). One loop runs every rotation of every sweep, the pair `(p, q)` read from a
    table, the rotation applied as a `k x k` product: a few operations of code whatever
    `k` (written out rotation by rotation, the default `solve` program grew from 3.2 to
    4.7 MB and took 0.5 s longer to load). Eigenvalues unsorted; values only."""
    A = jax.lax.stop_gradient(A)
    k = A.shape[0]
    dtype = A.dtype
    pairs = [(p, q) for p in range(k) for q in range(p + 1, k)]
    table = jnp.asarray(pairs, jnp.int32)
    eye = jnp.eye(k, dtype=dtype)
    index = jnp.arange(k)

    def rotate(i, carry):
        A, V = carry
        p, q = table[i % len(pairs), 0], table[i % len(pairs), 1]
        app, aqq, apq = A[p, p], A[q, q], A[p, q]
        zero = apq == 0
        tau = (aqq - app) / (2 * jnp.where(zero, 1, apq))
        sign = jnp.where(tau >= 0, 1, -1).astype(dtype)
        t = jnp.where(zero, 0, sign / (jnp.abs(tau) + jnp.hypot(jnp.ones_like(tau), tau)))
        c = 1 / jnp.sqrt(1 + t * t)
        s = t * c
        ep, eq = (index == p).astype(dtype), (index == q).astype(dtype)
        J = (
            eye
            + (c - 1) * (ep[:, None] * ep[None, :] + eq[:, None] * eq[None, :])
            + s * (ep[:, None] * eq[None, :] - eq[:, None] * ep[None, :])
        )
        A = J.T @ A @ J
        A = 0.5 * (A + A.T)
        return A, V @ J

    A, V = jax.lax.fori_loop(0, sweeps * len(pairs), rotate, (A, eye))
    return jnp.diagonal(A), V


def symmetric_pinv(A: Float[Array, "k k"], rcond: float | None = None):
    """Pseudo-inverse of a small symmetric matrix, finite for every input.

    The matrix is equilibrated by its diagonal (`D A D`, `D = diag(|A_ii|)^(-1/2)`), then
    eigen-decomposed (`jacobi_eigh`: no LAPACK call); eigenvalues of magnitude at most
    `rcond` times the largest are dropped. The derivative is `-A^+ dA A^+` (exact where
    `A` is invertible, finite everywhere, unlike the eigen-decomposition's own at repeated
    eigenvalues). Returns `(A^+, rank, positive_definite)`.
    """
    A_in = A
    A = jax.lax.stop_gradient(A)
    dtype = A.dtype
    k = A.shape[0]
    rcond = 64 * float(jnp.finfo(dtype).eps) if rcond is None else rcond
    Ae, d = _equilibrate(A)
    lam, V = jacobi_eigh(Ae)
    cutoff = rcond * jnp.max(jnp.abs(lam))
    keep = (jnp.abs(lam) > cutoff) & (jnp.abs(lam) > jnp.finfo(dtype).tiny)
    inv_lam = jnp.where(keep, 1 / jnp.where(keep, lam, 1), 0)
    pinv = (V * inv_lam[None, :]) @ V.T
    pinv = pinv * d[:, None] * d[None, :]
    pinv = pinv - pinv @ (A_in - A) @ pinv
    rank = jnp.sum(keep).astype(jnp.int32)
    positive = jnp.all(jnp.isfinite(lam)) & (rank == k) & jnp.all(lam > 0)
    return pinv, rank, positive


def positive_definite_solve(
    A: Float[Array, "k k"], b: Float[Array, " k"], rcond: float | None = None
):
    """`A^-1 b` for a small symmetric matrix, and whether `A` is positive definite, by the
    unrolled Cholesky factorisation (no LAPACK call): `A` is equilibrated by its diagonal
    as in `symmetric_pinv`, and counts as positive definite when every pivot exceeds
    `rcond` (default `64 eps`) times the largest diagonal entry: the verdict of
    `symmetric_pinv`'s eigenvalue test, except for matrices singular to rounding, which
    either may call positive. Values only (no derivative flows).
    Returns `(x, positive_definite)`; `x` is finite whatever `A`."""
    A, b = jax.lax.stop_gradient(A), jax.lax.stop_gradient(b)
    dtype = A.dtype
    rcond = 64 * float(jnp.finfo(dtype).eps) if rcond is None else rcond
    Ae, d = _equilibrate(A)
    L, inv, pivots = _factor(Ae, jnp.finfo(dtype).tiny)
    positive = jnp.all(jnp.diagonal(A) > 0) & jnp.all(jnp.stack(pivots) > rcond)
    positive = positive & jnp.all(jnp.isfinite(Ae))
    out = _substitute(L, inv, b * d) * d
    return jnp.where(positive & jnp.all(jnp.isfinite(out)), out, 0), positive
