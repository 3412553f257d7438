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

import jax.numpy as jnp
from jaxtyping import Array

from ..geometry._rotation import _sinc_of_sq

__all__ = [
    "Mat3",
    "Vec3",
    "add",
    "adjugate",
    "cross",
    "det",
    "dot",
    "matmul",
    "matvec",
    "mat_from_array",
    "mat_to_array",
    "rotvec_matrix",
    "scale",
    "sub",
    "transpose",
    "transpose_matvec",
    "vec_from_array",
    "vec_to_array",
    "norm_sq",
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
