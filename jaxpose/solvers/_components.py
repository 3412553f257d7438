"""Vectors and 3x3 matrices in component form, for the batch-first kernels.

A batch of 3-vectors is held as three arrays `x, y, z` of one shape (a `Vec3`), a batch
of 3x3 matrices as nine arrays (a `Mat3`, row-major). Every operation below is a handful
of elementwise expressions on those arrays: under `jit` they fuse into wide vector
loops, where the same algebra on `(..., 3)` / `(..., 3, 3)` arrays (`@`, `jnp.cross`,
`jnp.linalg`) becomes one small batched kernel per element. The kernels built on these
(`_kernel_*.py`) are checked against the readable single-problem solvers in the tests.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array

from ..geometry._numerics import safe_div, safe_sqrt
from ..geometry._rotation import _sinc_of_sq

__all__ = [
    "image_spread",
    "Mat3",
    "Vec3",
    "add",
    "adjugate",
    "cross",
    "degeneracy",
    "det",
    "dot",
    "matmul",
    "matvec",
    "mat_from_array",
    "mat_to_array",
    "rotvec_matrix",
    "scale",
    "stacked",
    "sub",
    "take_along",
    "transpose",
    "transpose_matvec",
    "vec_from_array",
    "vec_to_array",
    "norm_sq",
    "combine",
    "first_extreme",
    "quadratic_form",
    "rows",
    "symmetric",
    "together",
    "trace_product",
]


class Vec3(NamedTuple):
    """A batch of 3-vectors: three arrays of one shape."""

    x: Array
    y: Array
    z: Array


class Mat3(NamedTuple):
    """A batch of 3x3 matrices: nine arrays of one shape, row-major (`xy` is row 0,
    column 1)."""

    xx: Array
    xy: Array
    xz: Array
    yx: Array
    yy: Array
    yz: Array
    zx: Array
    zy: Array
    zz: Array


def vec_from_array(a: Array) -> Vec3:
    """`(..., 3)` array to a `Vec3` of `(...)` arrays."""
    return Vec3(a[..., 0], a[..., 1], a[..., 2])


def vec_to_array(v: Vec3) -> Array:
    """A `Vec3` to one `(..., 3)` array."""
    return jnp.stack([v.x, v.y, v.z], axis=-1)


def mat_from_array(a: Array) -> Mat3:
    """`(..., 3, 3)` array to a `Mat3` of `(...)` arrays."""
    return Mat3(*(a[..., i, j] for i in range(3) for j in range(3)))


def mat_to_array(m: Mat3) -> Array:
    """A `Mat3` to one `(..., 3, 3)` array."""
    rows = [jnp.stack(m[3 * i : 3 * i + 3], axis=-1) for i in range(3)]
    return jnp.stack(rows, axis=-2)


def add(a: Vec3, b: Vec3) -> Vec3:
    return Vec3(a.x + b.x, a.y + b.y, a.z + b.z)


def sub(a: Vec3, b: Vec3) -> Vec3:
    return Vec3(a.x - b.x, a.y - b.y, a.z - b.z)


def scale(a: Vec3, s) -> Vec3:
    return Vec3(a.x * s, a.y * s, a.z * s)


def dot(a: Vec3, b: Vec3) -> Array:
    return a.x * b.x + a.y * b.y + a.z * b.z


def cross(a: Vec3, b: Vec3) -> Vec3:
    return Vec3(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x)


def matvec(m: Mat3, v: Vec3) -> Vec3:
    """`M v`."""
    return Vec3(
        m.xx * v.x + m.xy * v.y + m.xz * v.z,
        m.yx * v.x + m.yy * v.y + m.yz * v.z,
        m.zx * v.x + m.zy * v.y + m.zz * v.z,
    )


def transpose_matvec(m: Mat3, v: Vec3) -> Vec3:
    """`M^T v`."""
    return Vec3(
        m.xx * v.x + m.yx * v.y + m.zx * v.z,
        m.xy * v.x + m.yy * v.y + m.zy * v.z,
        m.xz * v.x + m.yz * v.y + m.zz * v.z,
    )


def transpose(m: Mat3) -> Mat3:
    return Mat3(m.xx, m.yx, m.zx, m.xy, m.yy, m.zy, m.xz, m.yz, m.zz)


def matmul(a: Mat3, b: Mat3) -> Mat3:
    """`A B`."""
    rows = ((a.xx, a.xy, a.xz), (a.yx, a.yy, a.yz), (a.zx, a.zy, a.zz))
    cols = ((b.xx, b.yx, b.zx), (b.xy, b.yy, b.zy), (b.xz, b.yz, b.zz))
    return Mat3(*(r[0] * c[0] + r[1] * c[1] + r[2] * c[2] for r in rows for c in cols))


def rotvec_matrix(r: Vec3) -> Mat3:
    """Rodrigues in component form: `R = (1 - b theta^2) I + a [r]x + b r r^T` with
    `a = sinc(theta)`, `b = (1 - cos theta) / theta^2`, accurate at and near `r = 0`
    (the same expressions as `jaxpose.geometry.rotvec_to_matrix`)."""
    theta2 = dot(r, r)
    a = _sinc_of_sq(theta2)
    b = 0.5 * _sinc_of_sq(0.25 * theta2) ** 2
    d = 1.0 - b * theta2
    bx, by, bz = b * r.x, b * r.y, b * r.z
    ax, ay, az = a * r.x, a * r.y, a * r.z
    return Mat3(
        d + bx * r.x,
        bx * r.y - az,
        bx * r.z + ay,
        by * r.x + az,
        d + by * r.y,
        by * r.z - ax,
        bz * r.x - ay,
        bz * r.y + ax,
        d + bz * r.z,
    )


def det(m: Mat3) -> Array:
    """`det M` as the triple product of its rows, `m0 . (m1 x m2)` (the order of
    `jaxpose.geometry.det3`)."""
    return (
        m.xx * (m.yy * m.zz - m.yz * m.zy)
        + m.xy * (m.yz * m.zx - m.yx * m.zz)
        + m.xz * (m.yx * m.zy - m.yy * m.zx)
    )


def adjugate(m: Mat3) -> Mat3:
    """`adj M`, `M adj(M) = det(M) I`: its columns are `m1 x m2, m2 x m0, m0 x m1` (rows
    `m0, m1, m2`; as `jaxpose.geometry.adjugate3`)."""
    return Mat3(
        m.yy * m.zz - m.yz * m.zy,
        m.zy * m.xz - m.zz * m.xy,
        m.xy * m.yz - m.xz * m.yy,
        m.yz * m.zx - m.yx * m.zz,
        m.zz * m.xx - m.zx * m.xz,
        m.xz * m.yx - m.xx * m.yz,
        m.yx * m.zy - m.yy * m.zx,
        m.zx * m.xy - m.zy * m.xx,
        m.xx * m.yy - m.xy * m.yx,
    )


def norm_sq(a: Vec3) -> Array:
    """`|a|^2`."""
    return a.x * a.x + a.y * a.y + a.z * a.z


def rows(m: Mat3) -> tuple[tuple[Array, Array, Array], ...]:
    """The rows of `M` as nested tuples (`rows(m)[i][j]` is entry `(i, j)`)."""
    return ((m.xx, m.xy, m.xz), (m.yx, m.yy, m.yz), (m.zx, m.zy, m.zz))


def symmetric(xx, xy, xz, yy, yz, zz) -> Mat3:
    """A symmetric `Mat3` from its six distinct entries (shared, not copied)."""
    return Mat3(xx, xy, xz, xy, yy, yz, xz, yz, zz)


def combine(a, m: Mat3, b, n: Mat3) -> Mat3:
    """`a M + b N`, entrywise (`a`, `b` arrays or scalars)."""
    return Mat3(*(a * u + b * v for u, v in zip(m, n, strict=True)))


def quadratic_form(u: Vec3, m: Mat3, v: Vec3) -> Array:
    """`u^T M v`, evaluated as `(u^T M) v`."""
    return dot(transpose_matvec(m, u), v)


def trace_product(a: Mat3, b: Mat3) -> Array:
    """`trace(A B)`, as the sum of the diagonal of the product."""
    ra, rb = rows(a), rows(b)
    diag = [ra[i][0] * rb[0][i] + ra[i][1] * rb[1][i] + ra[i][2] * rb[2][i] for i in range(3)]
    return diag[0] + diag[1] + diag[2]


def first_extreme(keys, values, *, smallest: bool = False):
    """`jnp.argmax` (`smallest`: `jnp.argmin`) over a list of arrays, as a chain of
    `jnp.where`: the extreme key and the `values[k]` (any pytree) of the first `k` that
    attains it (ties: the first, as `argmax` picks)."""
    best, out = keys[0], values[0]
    for key, val in zip(keys[1:], values[1:], strict=True):
        better = key < best if smallest else key > best
        best = jnp.where(better, key, best)
        out = jax.tree.map(lambda a, b, c=better: jnp.where(c, a, b), val, out)
    return best, out


def together(tree, group: int = 8):
    """The arrays of `tree` unchanged, computed together: for each shape, variadic
    reductions of `group` arrays each (all at once when `0`) over a trailing axis of
    length 2 padded with `-0` (`x + -0 = x` exactly; `or` with `False` for masks).

    XLA:CPU writes every output of a fused graph with a loop of its own, which
    recomputes the output's whole cone of operations, and it drops optimisation barriers
    before fusing. A variadic reduction is the one loop with several outputs that it
    forms: the shared operations are computed once per element, the outputs written
    once, and what follows starts from them. Loops of a few outputs vectorise best (8
    measured best for the three-point kernel's stages). No derivative rule: for values
    computed without gradient (`stop_gradient`), or see `_kernel_linear._together`.
    """
    leaves, treedef = jax.tree.flatten(tree)
    by_shape: dict = {}
    for k, leaf in enumerate(leaves):
        by_shape.setdefault(leaf.shape, []).append(k)
    out = list(leaves)
    for ks in by_shape.values():
        loops = -(-len(ks) // group) if group else 1  # of near-equal sizes
        for i in range(loops):
            part = ks[i * len(ks) // loops : (i + 1) * len(ks) // loops]
            arrays = [leaves[k] for k in part]
            ndim = arrays[0].ndim
            if len(arrays) == 1:  # a lone reduction leaves XLA's loops: give it company
                arrays.append(jnp.zeros_like(arrays[0]))
            pads = tuple(
                jnp.zeros((), a.dtype) if a.dtype == jnp.bool_ else -jnp.zeros((), a.dtype)
                for a in arrays
            )
            padded = tuple(
                jax.lax.pad(a[..., None], v, [(0, 0, 0)] * ndim + [(0, 1, 0)])
                for a, v in zip(arrays, pads, strict=True)
            )
            results = jax.lax.reduce(padded, pads, _or_add, (ndim,))
            for k, r in zip(part, results[: len(part)], strict=True):
                out[k] = r
    return jax.tree.unflatten(treedef, out)


def stacked(fn, arrays):
    """`[fn(a) for a in arrays]` as one `fn` per dtype and shape: the arrays of one dtype
    and shape stacked on a new trailing axis, `fn` applied once (it must act on the
    leading axes alone, e.g. a gather or a repeat), the results sliced apart. One
    operation instead of one per component: fewer loops to compile and to run."""
    arrays = list(arrays)
    out: list = [None] * len(arrays)
    groups: dict = {}
    for k, a in enumerate(arrays):
        groups.setdefault((a.dtype, a.shape), []).append(k)
    for ks in groups.values():
        if len(ks) == 1:
            out[ks[0]] = fn(arrays[ks[0]][..., None])[..., 0]
            continue
        got = fn(jnp.stack([arrays[k] for k in ks], axis=-1))
        for j, k in enumerate(ks):
            out[k] = got[..., j]
    return out


def take_along(arrays, index: Array, axis: int) -> list[Array]:
    """`[jnp.take_along_axis(a, index, axis) for a in arrays]` (arrays of one shape, `axis`
    counted from the front), as one gather per dtype (`stacked`)."""
    return stacked(lambda a: jnp.take_along_axis(a, index[..., None], axis=axis), arrays)


def _or_add(x, y):
    return tuple(u | w if u.dtype == jnp.bool_ else u + w for u, w in zip(x, y, strict=True))


def image_spread(u: Array, v: Array, mask: Array) -> Array:
    """The spread of a problem's image points, an area: `sqrt(det S)`, `S` the 2x2
    covariance of the used points (`u`, `v`, `mask` of shape `(..., n)`; the result
    `(...)`). Any affine map of the image (a focal length, a principal point, pixels that
    are not square, `K^-1` itself) multiplies it and every triangle's area by the same
    factor: their ratio is the scale-free measure of alignment of the degeneracy test
    (`Options.min_area`). Never below `sqrt(eps)` times `trace S` (the similarity-invariant
    spread): used points on one image line (`det S = 0` up to rounding) still have a
    positive spread, beside which their triangles are flat (an anisotropy of the pixels'
    scales up to `1 / sqrt(eps)`, 6.7e7 in float64, keeps the affine measure). Zero only
    for fewer than two distinct used points."""
    w = mask.astype(u.dtype)
    count = jnp.maximum(jnp.sum(w, axis=-1), 1)
    du = jnp.where(mask, u, 0) - (jnp.sum(jnp.where(mask, u, 0), axis=-1) / count)[..., None]
    dv = jnp.where(mask, v, 0) - (jnp.sum(jnp.where(mask, v, 0), axis=-1) / count)[..., None]
    suu, svv, suv = (jnp.sum(w * a * b, axis=-1) / count for a, b in ((du, du), (dv, dv), (du, dv)))
    floor = jnp.sqrt(jnp.finfo(u.dtype).eps) * (suu + svv)
    return jnp.maximum(safe_sqrt(jnp.maximum(suu * svv - suv * suv, 0)), floor)


def degeneracy(
    u: tuple[Array, Array, Array], v: tuple[Array, Array, Array], x, min_area, collinear_tol
):
    """The three-point method's degeneracy tests (`three_point`; the paper's Section 2.1)
    in component form: `u`, `v` the three pixels' coordinates, `x` the three model
    points, `min_area` an area in the image's units (the pipeline passes
    `Options.min_area` times the problem's `image_spread`). Returns
    `(degenerate_image, degenerate_model)`."""
    area = 0.5 * jnp.abs((u[1] - u[0]) * (v[2] - v[0]) - (v[1] - v[0]) * (u[2] - u[0]))
    e12, e13, e23 = sub(x[0], x[1]), sub(x[0], x[2]), sub(x[1], x[2])
    longest = jnp.maximum(jnp.maximum(norm_sq(e12), norm_sq(e13)), norm_sq(e23))
    n = cross(sub(x[1], x[0]), sub(x[2], x[0]))
    shape = safe_div(0.5 * safe_sqrt(norm_sq(n)), longest)
    return ~(area >= min_area), ~(shape >= collinear_tol)
