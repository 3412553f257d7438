"""Tests of jaxpose.geometry._numerics: values and derivatives of the safe operations at
their singular points and at ordinary ones, in float32 and float64; masked means; the
precision switch and the floating-dtype rules."""

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
    return all(bool(jnp.all(jnp.isfinite(leaf))) for leaf in jax.tree.leaves(tree))


@pytest.mark.parametrize("dtype", DTYPES)
def test_safe_sqrt(dtype):
    x = jnp.asarray([0.0, -2.0, 4.0, 2.0], dtype)
    value = safe_sqrt(x)
    grad = jax.vmap(jax.grad(safe_sqrt))(x)
    assert value.dtype == grad.dtype == dtype
    np.testing.assert_allclose(value, [0, 0, 2, np.sqrt(2)], **tol(dtype))
    np.testing.assert_allclose(grad, [0, 0, 0.25, 0.5 / np.sqrt(2)], **tol(dtype))


@pytest.mark.parametrize("dtype", DTYPES)
def test_safe_div(dtype):
    num = jnp.asarray([3.0, 3.0, 0.0], dtype)
    den = jnp.asarray([0.0, 2.0, 0.0], dtype)
    value = safe_div(num, den)
    d_num, d_den = jax.vmap(jax.grad(safe_div, argnums=(0, 1)))(num, den)
    assert value.dtype == dtype
    np.testing.assert_allclose(value, [0, 1.5, 0], **tol(dtype))
    np.testing.assert_allclose(d_num, [0, 0.5, 0], **tol(dtype))
    np.testing.assert_allclose(d_den, [0, -0.75, 0], **tol(dtype))


@pytest.mark.parametrize("dtype", DTYPES)
def test_safe_norm(dtype):
    zero = jnp.zeros(3, dtype)
    x = jnp.asarray([3.0, 0.0, -4.0], dtype)
    assert safe_norm(zero) == 0 and safe_norm(zero).dtype == dtype
    np.testing.assert_array_equal(jax.grad(safe_norm)(zero), np.zeros(3))
    np.testing.assert_array_equal(jax.jacfwd(safe_norm)(zero), np.zeros(3))
    np.testing.assert_allclose(safe_norm(x), 5, **tol(dtype))
    np.testing.assert_allclose(jax.grad(safe_norm)(x), [0.6, 0, -0.8], **tol(dtype))
    # Along any axis, with or without the reduced axis kept.
    rows = jnp.stack([x, zero])
    np.testing.assert_allclose(safe_norm(rows, axis=1), [5, 0], **tol(dtype))
    assert safe_norm(rows, axis=1, keepdims=True).shape == (2, 1)
    np.testing.assert_allclose(safe_norm(rows.T, axis=0), [5, 0], **tol(dtype))
    jac = jax.jacrev(lambda r: safe_norm(r, axis=1))(rows)
    assert finite(jac)
    np.testing.assert_allclose(jac[0, 0], [0.6, 0, -0.8], **tol(dtype))
    np.testing.assert_array_equal(jac[1, 1], np.zeros(3))


@pytest.mark.parametrize("dtype", DTYPES)
def test_safe_normalize(dtype):
    zero = jnp.zeros(3, dtype)
    x = jnp.asarray([0.0, 3.0, 4.0], dtype)
    u = x / 5
    np.testing.assert_allclose(safe_normalize(x), u, **tol(dtype))
    projector = (np.eye(3) - np.outer(u, u)) / 5
    np.testing.assert_allclose(jax.jacfwd(safe_normalize)(x), projector, **tol(dtype))
    np.testing.assert_allclose(jax.jacrev(safe_normalize)(x), projector, **tol(dtype))
    # Default fallback: the zero vector stays zero, its derivative passes through.
    np.testing.assert_array_equal(safe_normalize(zero), zero)
    np.testing.assert_array_equal(jax.jacrev(safe_normalize)(zero), np.eye(3))
    # An explicit fallback: its value, and a zero derivative.
    e = jnp.asarray([1.0, 0.0, 0.0], dtype)
    np.testing.assert_array_equal(safe_normalize(zero, fallback=e), e)
    jac = jax.jacrev(lambda v: safe_normalize(v, fallback=e))(zero)
    np.testing.assert_array_equal(jac, np.zeros((3, 3)))
    assert safe_normalize(zero, fallback=0).dtype == dtype
    # Rows of a batch, one of them zero.
    rows = jnp.stack([x, zero])
    np.testing.assert_allclose(safe_normalize(rows, fallback=0), [u, np.zeros(3)], **tol(dtype))
    np.testing.assert_allclose(safe_normalize(rows.T, axis=0).T, [u, np.zeros(3)], **tol(dtype))


@pytest.mark.parametrize("dtype", DTYPES)
def test_safe_atan2(dtype):
    zero = jnp.zeros((), dtype)
    assert safe_atan2(zero, zero) == 0
    grads = jax.grad(safe_atan2, argnums=(0, 1))(zero, zero)
    assert [float(g) for g in grads] == [0.0, 0.0]
    y, x = jnp.asarray(1.0, dtype), jnp.asarray(-2.0, dtype)
    np.testing.assert_allclose(safe_atan2(y, x), np.arctan2(1.0, -2.0), **tol(dtype))
    dy, dx = jax.grad(safe_atan2, argnums=(0, 1))(y, x)
    np.testing.assert_allclose([dy, dx], [-2.0 / 5, -1.0 / 5], **tol(dtype))


@pytest.mark.parametrize("dtype", DTYPES)
def test_det3_and_adjugate3(dtype):
    M = np.random.default_rng(0).normal(size=(3, 3))
    Mj = jnp.asarray(M, dtype)
    det, adj = det3(Mj), adjugate3(Mj)
    assert det.dtype == adj.dtype == dtype
    np.testing.assert_allclose(det, np.linalg.det(M), rtol=1e-5 if dtype == jnp.float32 else 1e-12)
    np.testing.assert_allclose(
        adj, np.linalg.det(M) * np.linalg.inv(M), rtol=1e-5 if dtype == jnp.float32 else 1e-12
    )
    # Jacobi's formula: d det(M) / dM = adj(M)^T.
    np.testing.assert_allclose(jax.grad(det3)(Mj), adj.T, **tol(dtype))
    # Singular and zero matrices: finite, M adj(M) = det(M) I = 0, zero gradient at zero.
    singular = jnp.asarray([[1.0, 2.0, 3.0], [2.0, 4.0, 6.0], [0.0, 1.0, 1.0]], dtype)
    assert det3(singular) == 0
    np.testing.assert_array_equal(singular @ adjugate3(singular), np.zeros((3, 3)))
    zero = jnp.zeros((3, 3), dtype)
    np.testing.assert_array_equal(adjugate3(zero), np.zeros((3, 3)))
    np.testing.assert_array_equal(jax.grad(det3)(zero), np.zeros((3, 3)))
    assert finite(jax.jacrev(adjugate3)(zero))


@pytest.mark.parametrize("dtype", DTYPES)
def test_masked_mean(dtype):
    values = jnp.asarray([1.0, 2.0, 6.0, 100.0], dtype)
    mask = jnp.asarray([True, False, True, False])
    assert masked_mean(values, mask) == 3.5 and masked_mean(values, mask).dtype == dtype
    assert masked_mean(values) == 27.25
    np.testing.assert_allclose(jax.grad(masked_mean)(values, mask), [0.5, 0, 0.5, 0])
    np.testing.assert_allclose(jax.grad(masked_mean)(values), [0.25] * 4)
    # Weights 0/1 work as the mask does.
    np.testing.assert_allclose(masked_mean(values, mask.astype(dtype)), 3.5)
    # Nothing selected: 0, with a zero gradient; no rows at all: 0.
    empty = jnp.zeros(4, bool)
    assert masked_mean(values, empty) == 0
    np.testing.assert_array_equal(jax.grad(masked_mean)(values, empty), np.zeros(4))
    assert masked_mean(jnp.zeros(0, dtype)) == 0
    assert masked_mean(jnp.zeros(0, dtype), jnp.zeros(0, bool)) == 0


@pytest.mark.parametrize("dtype", DTYPES)
def test_masked_centroid(dtype):
    points = jnp.asarray([[0.0, 0.0, 0.0], [2.0, 4.0, 6.0], [9.0, 9.0, 9.0]], dtype)
    mask = jnp.asarray([True, True, False])
    c = masked_centroid(points, mask)
    assert c.shape == (3,) and c.dtype == dtype
    np.testing.assert_allclose(c, [1.0, 2.0, 3.0])
    np.testing.assert_allclose(masked_centroid(points), [11 / 3, 13 / 3, 5.0], **tol(dtype))
    jac = jax.jacrev(masked_centroid)(points, mask)  # (3, 3 points, 3)
    np.testing.assert_allclose(jac[:, 0, :], 0.5 * np.eye(3))
    np.testing.assert_array_equal(jac[:, 2, :], np.zeros((3, 3)))
    # Empty mask: the origin, with a zero derivative.
    empty = jnp.zeros(3, bool)
    np.testing.assert_array_equal(masked_centroid(points, empty), np.zeros(3))
    np.testing.assert_array_equal(jax.jacrev(masked_centroid)(points, empty), np.zeros((3, 3, 3)))
    # Under jit and vmap.
    batch = jnp.stack([points, 2 * points])
    masks = jnp.stack([mask, empty])
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
