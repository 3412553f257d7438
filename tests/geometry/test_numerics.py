"""Tests of jaxpose.geometry._numerics: values and derivatives of the safe operations at
their singular points and at ordinary ones, in float32 and float64; masked means; the
precision switch and the floating-dtype rules.

Each test computes its values and derivatives in one jitted function (one small program
per test and dtype, rather than one per eager operation) and checks them with numpy."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxpose.geometry._numerics import (
    adjugate3,
    as_float,
    by_precision,
    det3,
    float_dtype,
    masked_centroid,
    masked_mean,
    safe_atan2,
    safe_div,
    safe_norm,
    safe_normalize,
    safe_sqrt,
)

DTYPES = [jnp.float32, jnp.float64]


def tol(dtype):
    return {"rtol": 1e-6, "atol": 1e-7} if dtype == jnp.float32 else {"rtol": 1e-13, "atol": 0}


def finite(tree):
    return all(bool(np.all(np.isfinite(np.asarray(leaf)))) for leaf in jax.tree.leaves(tree))


def jitted(fn, *args):
    """`fn(*args)` as one jitted program, its outputs as numpy arrays (dtypes kept)."""
    return jax.tree.map(np.asarray, jax.jit(fn)(*args))


@pytest.mark.parametrize("dtype", DTYPES)
def test_safe_sqrt(dtype):
    x = np.asarray([0.0, -2.0, 4.0, 2.0], dtype)
    value, grad = jitted(lambda x: (safe_sqrt(x), jax.vmap(jax.grad(safe_sqrt))(x)), x)
    assert value.dtype == grad.dtype == dtype
    np.testing.assert_allclose(value, [0, 0, 2, np.sqrt(2)], **tol(dtype))
    np.testing.assert_allclose(grad, [0, 0, 0.25, 0.5 / np.sqrt(2)], **tol(dtype))


@pytest.mark.parametrize("dtype", DTYPES)
def test_safe_div(dtype):
    num = np.asarray([3.0, 3.0, 0.0], dtype)
    den = np.asarray([0.0, 2.0, 0.0], dtype)
    value, (d_num, d_den) = jitted(
        lambda n, d: (safe_div(n, d), jax.vmap(jax.grad(safe_div, argnums=(0, 1)))(n, d)),
        num,
        den,
    )
    assert value.dtype == dtype
    np.testing.assert_allclose(value, [0, 1.5, 0], **tol(dtype))
    np.testing.assert_allclose(d_num, [0, 0.5, 0], **tol(dtype))
    np.testing.assert_allclose(d_den, [0, -0.75, 0], **tol(dtype))


@pytest.mark.parametrize("dtype", DTYPES)
def test_safe_norm(dtype):
    zero = np.zeros(3, dtype)
    x = np.asarray([3.0, 0.0, -4.0], dtype)

    def run(zero, x):
        rows = jnp.stack([x, zero])
        return {
            "zero": safe_norm(zero),
            "grad_zero": jax.grad(safe_norm)(zero),
            "jacfwd_zero": jax.jacfwd(safe_norm)(zero),
            "x": safe_norm(x),
            "grad_x": jax.grad(safe_norm)(x),
            "rows": safe_norm(rows, axis=1),
            "rows_kept": safe_norm(rows, axis=1, keepdims=True),
            "columns": safe_norm(rows.T, axis=0),
            "jac": jax.jacrev(lambda r: safe_norm(r, axis=1))(rows),
        }

    out = jitted(run, zero, x)
    assert out["zero"] == 0 and out["zero"].dtype == dtype
    np.testing.assert_array_equal(out["grad_zero"], np.zeros(3))
    np.testing.assert_array_equal(out["jacfwd_zero"], np.zeros(3))
    np.testing.assert_allclose(out["x"], 5, **tol(dtype))
    np.testing.assert_allclose(out["grad_x"], [0.6, 0, -0.8], **tol(dtype))
    # Along any axis, with or without the reduced axis kept.
    np.testing.assert_allclose(out["rows"], [5, 0], **tol(dtype))
    assert out["rows_kept"].shape == (2, 1)
    np.testing.assert_allclose(out["columns"], [5, 0], **tol(dtype))
    jac = out["jac"]
    assert finite(jac)
    np.testing.assert_allclose(jac[0, 0], [0.6, 0, -0.8], **tol(dtype))
    np.testing.assert_array_equal(jac[1, 1], np.zeros(3))


@pytest.mark.parametrize("dtype", DTYPES)
def test_safe_normalize(dtype):
    zero = np.zeros(3, dtype)
    x = np.asarray([0.0, 3.0, 4.0], dtype)
    e = np.asarray([1.0, 0.0, 0.0], dtype)
    u = x / 5

    def run(zero, x, e):
        rows = jnp.stack([x, zero])
        return {
            "unit": safe_normalize(x),
            "jacfwd": jax.jacfwd(safe_normalize)(x),
            "jacrev": jax.jacrev(safe_normalize)(x),
            "zero": safe_normalize(zero),
            "jac_zero": jax.jacrev(safe_normalize)(zero),
            "fallback": safe_normalize(zero, fallback=e),
            "jac_fallback": jax.jacrev(lambda v: safe_normalize(v, fallback=e))(zero),
            "fallback_0": safe_normalize(zero, fallback=0),
            "rows": safe_normalize(rows, fallback=0),
            "columns": safe_normalize(rows.T, axis=0).T,
        }

    out = jitted(run, zero, x, e)
    np.testing.assert_allclose(out["unit"], u, **tol(dtype))
    projector = (np.eye(3) - np.outer(u, u)) / 5
    np.testing.assert_allclose(out["jacfwd"], projector, **tol(dtype))
    np.testing.assert_allclose(out["jacrev"], projector, **tol(dtype))
    # Default fallback: the zero vector stays zero, its derivative passes through.
    np.testing.assert_array_equal(out["zero"], zero)
    np.testing.assert_array_equal(out["jac_zero"], np.eye(3))
    # An explicit fallback: its value, and a zero derivative.
    np.testing.assert_array_equal(out["fallback"], e)
    np.testing.assert_array_equal(out["jac_fallback"], np.zeros((3, 3)))
    assert out["fallback_0"].dtype == dtype
    # Rows of a batch, one of them zero.
    np.testing.assert_allclose(out["rows"], [u, np.zeros(3)], **tol(dtype))
    np.testing.assert_allclose(out["columns"], [u, np.zeros(3)], **tol(dtype))


@pytest.mark.parametrize("dtype", DTYPES)
def test_safe_atan2(dtype):
    zero = np.zeros((), dtype)
    y, x = np.asarray(1.0, dtype), np.asarray(-2.0, dtype)

    def run(zero, y, x):
        grad = jax.grad(safe_atan2, argnums=(0, 1))
        return safe_atan2(zero, zero), grad(zero, zero), safe_atan2(y, x), grad(y, x)

    at_zero, grads, value, (dy, dx) = jitted(run, zero, y, x)
    assert at_zero == 0
    assert [float(g) for g in grads] == [0.0, 0.0]
    np.testing.assert_allclose(value, np.arctan2(1.0, -2.0), **tol(dtype))
    np.testing.assert_allclose([dy, dx], [-2.0 / 5, -1.0 / 5], **tol(dtype))


@pytest.mark.parametrize("dtype", DTYPES)
def test_det3_and_adjugate3(dtype):
    M = np.random.default_rng(0).normal(size=(3, 3))
    singular = np.asarray([[1.0, 2.0, 3.0], [2.0, 4.0, 6.0], [0.0, 1.0, 1.0]], dtype)
    zero = np.zeros((3, 3), dtype)

    def run(Mj, singular, zero):
        return {
            "det": det3(Mj),
            "adj": adjugate3(Mj),
            "grad": jax.grad(det3)(Mj),
            "det_singular": det3(singular),
            "adj_singular": adjugate3(singular),
            "adj_zero": adjugate3(zero),
            "grad_zero": jax.grad(det3)(zero),
            "jac_zero": jax.jacrev(adjugate3)(zero),
        }

    out = jitted(run, np.asarray(M, dtype), singular, zero)
    det, adj = out["det"], out["adj"]
    assert det.dtype == adj.dtype == dtype
    np.testing.assert_allclose(det, np.linalg.det(M), rtol=1e-5 if dtype == jnp.float32 else 1e-12)
    np.testing.assert_allclose(
        adj, np.linalg.det(M) * np.linalg.inv(M), rtol=1e-5 if dtype == jnp.float32 else 1e-12
    )
    # Jacobi's formula: d det(M) / dM = adj(M)^T.
    np.testing.assert_allclose(out["grad"], adj.T, **tol(dtype))
    # Singular and zero matrices: finite, M adj(M) = det(M) I = 0, zero gradient at zero.
    assert out["det_singular"] == 0
    np.testing.assert_array_equal(singular @ out["adj_singular"], np.zeros((3, 3)))
    np.testing.assert_array_equal(out["adj_zero"], np.zeros((3, 3)))
    np.testing.assert_array_equal(out["grad_zero"], np.zeros((3, 3)))
    assert finite(out["jac_zero"])


@pytest.mark.parametrize("dtype", DTYPES)
def test_masked_mean(dtype):
    values = np.asarray([1.0, 2.0, 6.0, 100.0], dtype)
    mask = np.asarray([True, False, True, False])
    empty = np.zeros(4, bool)

    def run(values, mask, empty):
        return {
            "masked": masked_mean(values, mask),
            "all": masked_mean(values),
            "grad_masked": jax.grad(masked_mean)(values, mask),
            "grad_all": jax.grad(masked_mean)(values),
            "weights": masked_mean(values, mask.astype(dtype)),
            "empty": masked_mean(values, empty),
            "grad_empty": jax.grad(masked_mean)(values, empty),
            "no_rows": masked_mean(jnp.zeros(0, dtype)),
            "no_rows_masked": masked_mean(jnp.zeros(0, dtype), jnp.zeros(0, bool)),
        }

    out = jitted(run, values, mask, empty)
    assert out["masked"] == 3.5 and out["masked"].dtype == dtype
    assert out["all"] == 27.25
    np.testing.assert_allclose(out["grad_masked"], [0.5, 0, 0.5, 0])
    np.testing.assert_allclose(out["grad_all"], [0.25] * 4)
    # Weights 0/1 work as the mask does.
    np.testing.assert_allclose(out["weights"], 3.5)
    # Nothing selected: 0, with a zero gradient; no rows at all: 0.
    assert out["empty"] == 0
    np.testing.assert_array_equal(out["grad_empty"], np.zeros(4))
    assert out["no_rows"] == 0
    assert out["no_rows_masked"] == 0


@pytest.mark.parametrize("dtype", DTYPES)
def test_masked_centroid(dtype):
    points = np.asarray([[0.0, 0.0, 0.0], [2.0, 4.0, 6.0], [9.0, 9.0, 9.0]], dtype)
    mask = np.asarray([True, True, False])
    empty = np.zeros(3, bool)

    def run(points, mask, empty):
        return {
            "masked": masked_centroid(points, mask),
            "all": masked_centroid(points),
            "jac": jax.jacrev(masked_centroid)(points, mask),  # (3, 3 points, 3)
            "empty": masked_centroid(points, empty),
            "jac_empty": jax.jacrev(masked_centroid)(points, empty),
        }

    out = jitted(run, points, mask, empty)
    c = out["masked"]
    assert c.shape == (3,) and c.dtype == dtype
    np.testing.assert_allclose(c, [1.0, 2.0, 3.0])
    np.testing.assert_allclose(out["all"], [11 / 3, 13 / 3, 5.0], **tol(dtype))
    jac = out["jac"]
    np.testing.assert_allclose(jac[:, 0, :], 0.5 * np.eye(3))
    np.testing.assert_array_equal(jac[:, 2, :], np.zeros((3, 3)))
    # Empty mask: the origin, with a zero derivative.
    np.testing.assert_array_equal(out["empty"], np.zeros(3))
    np.testing.assert_array_equal(out["jac_empty"], np.zeros((3, 3, 3)))
    # Under jit and vmap.
    batch = np.stack([points, 2 * points])
    masks = np.stack([mask, empty])
    out = jax.jit(jax.vmap(masked_centroid))(batch, masks)
    np.testing.assert_allclose(out, [[1.0, 2.0, 3.0], [0.0, 0.0, 0.0]])


def test_by_precision():
    assert by_precision(jnp.float64, f64=1e-8, f32=1e-5) == 1e-8
    assert by_precision(np.dtype("float64"), f64="wide", f32="narrow") == "wide"
    assert by_precision(jnp.zeros(2, jnp.float64).dtype, f64=1, f32=2) == 1
    for dtype in (jnp.float32, jnp.float16, jnp.bfloat16):
        assert by_precision(dtype, f64=1e-8, f32=1e-5) == 1e-5
    with pytest.raises(TypeError):
        by_precision(jnp.float32, 1e-8, 1e-5)  # keyword-only


def test_float_dtype_and_as_float():
    default = jnp.result_type(float)
    assert float_dtype(np.arange(3)) == default
    assert float_dtype(np.ones(2, np.float32)) == jnp.float32
    assert float_dtype(np.ones(2, np.float32), jnp.ones(2, jnp.float64)) == jnp.float64
    assert float_dtype(True) == default
    one = as_float(np.arange(3))
    assert isinstance(one, jax.Array) and one.dtype == default
    a, b = as_float(np.ones(2, np.float32), np.ones(3, np.float32))
    assert a.dtype == b.dtype == jnp.float32 and b.shape == (3,)
    a, b = as_float(np.ones(2, np.float32), np.arange(2))
    assert a.dtype == b.dtype and jnp.issubdtype(a.dtype, jnp.floating)
