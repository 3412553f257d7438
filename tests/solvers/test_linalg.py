"""`positive_definite_solve` (the values-only Newton step's solver, no LAPACK call)
against `symmetric_pinv` and numpy."""

import jax
import numpy as np

from jaxpose.solvers._linalg import jacobi_eigh, positive_definite_solve, symmetric_pinv


def test_positive_definite_solve_matches_the_pseudo_inverse():
    rng = np.random.default_rng(5)
    solve, reference = jax.jit(positive_definite_solve), jax.jit(symmetric_pinv)
    for i in range(200):
        M = rng.normal(size=(6, 6))
        scales = np.exp(rng.uniform(-6, 6, 6))
        A = (M @ M.T + 1e-3 * np.eye(6)) * np.outer(scales, scales)
        b = rng.normal(size=6)
        if i % 4 == 1:  # indefinite
            w, V = np.linalg.eigh(A)
            w[0] = -abs(w[0]) - 1e-2 * w[-1]
            A = (V * w) @ V.T
        if i % 4 == 2:  # singular
            w, V = np.linalg.eigh(A)
            w[0] = 0
            A = (V * w) @ V.T
        x, positive = solve(A, b)
        pinv, _, positive_ref = reference(A)
        assert np.all(np.isfinite(np.asarray(x)))
        if i % 4 == 2:  # singular to rounding: either answer, always finite
            continue
        assert bool(positive) == bool(positive_ref), i
        if positive:
            np.testing.assert_allclose(A @ np.asarray(x), b, rtol=1e-6, atol=1e-9 * np.abs(b).max())
            np.testing.assert_allclose(np.asarray(x), np.asarray(pinv) @ b, rtol=1e-6, atol=1e-12)
        else:
            assert np.all(np.asarray(x) == 0)


def _symmetric(rng, kind: str, B: int) -> np.ndarray:
    X = rng.normal(size=(B, 6, 6))
    if kind == "indefinite":
        return X + X.transpose(0, 2, 1)
    if kind == "rank 4":
        Y = rng.normal(size=(B, 6, 4))
        return Y @ Y.transpose(0, 2, 1)
    if kind == "graded":
        D = np.diag(10.0 ** np.arange(0, 12, 2))
        return D @ (X @ X.transpose(0, 2, 1)) @ D
    Q = np.linalg.qr(X)[0]  # repeated eigenvalues
    return Q @ np.diag([1, 1, 1, 2, 2, 3.0]) @ Q.transpose(0, 2, 1)


def test_jacobi_eigh_matches_numpy():
    """The LAPACK-free eigen-decomposition of `symmetric_pinv`: eigenvalues as numpy's,
    orthonormal eigenvectors that rebuild the matrix, in float64 and float32."""
    rng = np.random.default_rng(7)
    eigh = jax.jit(jax.vmap(jacobi_eigh))
    for kind in ("indefinite", "rank 4", "graded", "repeated"):
        A = _symmetric(rng, kind, 300)
        for dtype, tol, rebuild in ((np.float64, 1e-13, 1e-10), (np.float32, 2e-6, 1e-5)):
            lam, V = (np.asarray(x, np.float64) for x in eigh(A.astype(dtype)))
            A64 = A.astype(dtype).astype(np.float64)
            size = np.max(np.abs(A64), axis=(1, 2))
            ref = np.linalg.eigvalsh(A64)
            err = np.max(np.abs(np.sort(lam, axis=1) - ref), axis=1) / size
            assert err.max() < tol, (kind, dtype)
            np.testing.assert_allclose(
                V.transpose(0, 2, 1) @ V, np.broadcast_to(np.eye(6), V.shape), atol=10 * tol
            )
            built = V @ (lam[:, :, None] * V.transpose(0, 2, 1))
            assert np.max(np.abs(built - A64), axis=(1, 2)).max() / size.max() < rebuild, (
                kind,
                dtype,
            )


def _pinv_reference(A: np.ndarray) -> np.ndarray:
    """`symmetric_pinv`'s definition in numpy (LAPACK's eigh): equilibrated by the
    diagonal, eigenvalues below 64 eps of the largest dropped."""
    d = np.abs(np.diagonal(A, axis1=1, axis2=2))
    d = np.where(d > 0, 1 / np.sqrt(np.where(d > 0, d, 1)), 0)
    lam, V = np.linalg.eigh(A * d[:, :, None] * d[:, None, :])
    keep = np.abs(lam) > 64 * np.finfo(float).eps * np.max(np.abs(lam), axis=1, keepdims=True)
    inv = np.where(keep, 1 / np.where(keep, lam, 1), 0)
    return (V * inv[:, None, :]) @ V.transpose(0, 2, 1) * d[:, :, None] * d[:, None, :]


def test_symmetric_pinv_matches_its_lapack_definition():
    """The pseudo-inverse from `jacobi_eigh` equals the one from LAPACK's eigh that it
    replaced (and, for invertible matrices, the inverse)."""
    rng = np.random.default_rng(8)
    pinv = jax.jit(jax.vmap(lambda A: symmetric_pinv(A)[0]))
    for kind in ("indefinite", "rank 4", "graded"):
        A = _symmetric(rng, kind, 100)
        got, ref = np.asarray(pinv(A)), _pinv_reference(A)
        scale = np.max(np.abs(ref), axis=(1, 2), keepdims=True)
        assert np.max(np.abs(got - ref) / scale) < 1e-8, kind
        if kind != "rank 4":
            inv = np.linalg.inv(A)
            assert np.max(np.abs(got - inv) / scale) < 1e-6, kind
