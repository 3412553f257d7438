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

__all__ = ["cholesky_solve", "positive_definite_solve", "symmetric_pinv"]


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
    L: list[list] = [[None] * n for _ in range(n)]
    inv: list = [None] * n
    for j in range(n):
        s = A[j, j]
        for k in range(j):
            s = s - L[j][k] * L[j][k]
        s = jnp.where(jnp.isfinite(s), s, floor)
        d = jnp.sqrt(jnp.maximum(s, floor))
        inv[j] = 1 / d
        L[j][j] = d
        for i in range(j + 1, n):
            s = A[i, j]
            for k in range(j):
                s = s - L[i][k] * L[j][k]
            L[i][j] = s * inv[j]
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
    return jnp.stack(x).astype(dtype)


def symmetric_pinv(A: Float[Array, "k k"], rcond: float | None = None):
    """Pseudo-inverse of a small symmetric matrix, finite for every input.

    The matrix is equilibrated by its diagonal (`D A D`, `D = diag(|A_ii|)^(-1/2)`), then
    eigen-decomposed; eigenvalues of magnitude at most `rcond` times the largest are
    dropped. The derivative is `-A^+ dA A^+` (exact where `A` is invertible, finite
    everywhere, unlike the eigen-decomposition's own at repeated eigenvalues).
    Returns `(A^+, rank, positive_definite)`.
    """
    A_in = A
    A = jax.lax.stop_gradient(A)
    dtype = A.dtype
    k = A.shape[0]
    rcond = 64 * float(jnp.finfo(dtype).eps) if rcond is None else rcond
    diag = jnp.abs(jnp.diagonal(A))
    ok = diag > 0
    d = jnp.where(ok, 1 / jnp.sqrt(jnp.where(ok, diag, 1)), 0)
    Ae = A * d[:, None] * d[None, :]
    Ae = 0.5 * (Ae + Ae.T)
    lam, V = jnp.linalg.eigh(Ae)
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
    k = A.shape[0]
    rcond = 64 * float(jnp.finfo(dtype).eps) if rcond is None else rcond
    diag = jnp.diagonal(A)
    ok = diag > 0
    d = jnp.where(ok, 1 / jnp.sqrt(jnp.where(ok, diag, 1)), 0)
    Ae = A * d[:, None] * d[None, :]
    Ae = 0.5 * (Ae + Ae.T)
    pivots = []
    L: list[list] = [[None] * k for _ in range(k)]
    for j in range(k):
        s = Ae[j, j]
        for m in range(j):
            s = s - L[j][m] * L[j][m]
        pivots.append(s)
        root = jnp.sqrt(jnp.where(s > 0, s, 1))
        L[j][j] = root
        for i in range(j + 1, k):
            s_ij = Ae[i, j]
            for m in range(j):
                s_ij = s_ij - L[i][m] * L[j][m]
            L[i][j] = s_ij / root
    positive = jnp.all(ok) & jnp.all(jnp.stack(pivots) > rcond) & jnp.all(jnp.isfinite(Ae))
    y: list = [None] * k
    be = b * d
    for i in range(k):
        s = be[i]
        for m in range(i):
            s = s - L[i][m] * y[m]
        y[i] = s / L[i][i]
    x: list = [None] * k
    for i in reversed(range(k)):
        s = y[i]
        for m in range(i + 1, k):
            s = s - L[m][i] * x[m]
        x[i] = s / L[i][i]
    out = jnp.stack(x) * d
    return jnp.where(positive & jnp.all(jnp.isfinite(out)), out, 0), positive
