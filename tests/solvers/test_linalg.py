"""`positive_definite_solve` (the values-only Newton step's solver, no LAPACK call)
against `symmetric_pinv` and numpy."""

import jax
import numpy as np

from jaxpose.solvers._linalg import positive_definite_solve, symmetric_pinv


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
