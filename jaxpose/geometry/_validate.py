"""Validation of user input at the public (numpy) boundary.

Code under `jit` never raises on data (it reports status codes); the public entry points
call these helpers first, so that a wrong shape, a NaN or a singular camera is reported
at once as a `ValueError` whose message names the offending argument.

Every helper takes any value (`object`: arrays, nested lists, tracers, `None`; checking
it is the helper's job) and returns a numpy array in a canonical layout: floating point
(float32 stays float32, float64 stays float64, other real types become float64).

An entry point that checks its arguments itself, whatever their type, is marked
`@no_type_check` (imported from here): run-time type checkers (the test suite runs
jaxtyping's with beartype on the whole package) then leave its arguments to it, so that a
bad one raises the `ValueError` naming it, not a `TypeError`. Static checkers still read
its annotations, which `typing.no_type_check` itself would hide from them.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

__all__ = [
    "as_batched",
    "as_camera",
    "as_dist_coeffs",
    "as_intrinsics",
    "as_matching",
    "as_point_batch",
    "as_points",
    "check_problem",
]

if TYPE_CHECKING:
    _F = TypeVar("_F", bound=Callable[..., Any])

    def no_type_check(arg: _F) -> _F:
        """For static checkers: the annotations of `arg` stand (see the module docstring)."""
        return arg

else:
    # At run time `typing.no_type_check` itself: jaxtyping's import hook skips a function
    # or class decorated with it (by name), and beartype and typeguard skip it too.
    from typing import no_type_check as no_type_check

#: Distortion vector lengths OpenCV accepts.
DIST_COEFF_SIZES = (4, 5, 8, 12, 14)

#: A 3x3 matrix is singular when its smallest singular value is below this fraction of its
#: largest (computed in float64).
SINGULAR_RTOL = 1e-12


def _as_real_array(x: object, name: str) -> np.ndarray:
    """`x` as a numpy array of a real floating dtype, or ValueError naming `name`."""
    if x is None:
        raise ValueError(f"{name} is required, got None")
    try:
        arr = np.asarray(x)
    except Exception as exc:  # ragged lists and the like
        raise ValueError(f"{name} could not be read as an array: {exc}") from exc
    if arr.dtype == np.bool_ or not (
        np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)
    ):
        raise ValueError(f"{name} must hold real numbers, got dtype {arr.dtype}")
    if arr.dtype not in (np.float32, np.float64):
        arr = arr.astype(np.float64)
    return arr


def _check_finite(arr: np.ndarray, name: str) -> None:
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN or infinite values")


def as_points(x: object, name: str, dim: int, *, min_count: int = 1) -> np.ndarray:
    """Validate an array of `dim`-dimensional points.

    **Arguments:**

    - `x`: array-like of shape (n, dim), OpenCV's (n, 1, dim) or (1, n, dim), or the
      transposed (dim, n) where it is unambiguous (`n != dim`); any real dtype, any
      strides (a list, a non-contiguous view).
    - `name`: the argument's name, used in error messages.
    - `dim`: point dimension (2 for pixels, 3 for model points).
    - `min_count`: the fewest points accepted.

    **Returns:**

    numpy array of shape (n, dim): float32 if given float32, else float64.

    **Raises:**

    `ValueError` naming `name` for a wrong shape, non-real dtype, NaN/inf, or fewer than
    `min_count` points.
    """
    arr = _as_real_array(x, name)
    if arr.ndim == 3 and arr.shape[2] == dim and (arr.shape[1] == 1 or arr.shape[0] == 1):
        arr = arr.reshape(-1, dim)
    elif arr.ndim == 2 and arr.shape[0] == dim and arr.shape[1] != dim:
        arr = arr.T  # (dim, n): one point per column
    if arr.ndim != 2 or arr.shape[1] != dim:
        raise ValueError(
            f"{name} must have shape (n, {dim}) (or OpenCV's (n, 1, {dim}) / (1, n, {dim}),"
            f" or ({dim}, n)), got {arr.shape}"
        )
    if arr.shape[0] < min_count:
        raise ValueError(f"{name} needs at least {min_count} points, got {arr.shape[0]}")
    _check_finite(arr, name)
    return arr


def as_point_batch(x: object, name: str, dim: int, *, min_count: int = 1) -> np.ndarray:
    """`as_points` for a batch of problems of equal size: shape `(B, n, dim)`, `B >= 1`,
    `n >= min_count`, checked at once (no loop over the problems). Returns float32 if
    given float32, else float64; `ValueError` naming `name` as `as_points`."""
    arr = _as_real_array(x, name)
    if arr.ndim != 3 or arr.shape[2] != dim:
        raise ValueError(f"{name} must have shape (B, n, {dim}), got {arr.shape}")
    if arr.shape[0] == 0:
        raise ValueError(f"{name} must hold at least one problem, got an empty batch")
    if arr.shape[1] < min_count:
        raise ValueError(f"{name} needs at least {min_count} points, got {arr.shape[1]}")
    _check_finite(arr, name)
    return arr


@functools.lru_cache(maxsize=256)
def _extreme_singular_values(data: bytes) -> tuple[float, float]:
    """The largest and smallest singular values of the 3x3 float64 matrix `data` (its
    bytes): a camera checked once, however many calls pass it again."""
    s = np.linalg.svd(np.frombuffer(data, np.float64).reshape(3, 3), compute_uv=False)
    return float(s[0]), float(s[-1])


def _check_nonsingular(M: np.ndarray, name: str, what: str) -> None:
    M = np.ascontiguousarray(M, dtype=np.float64)
    big, small = _extreme_singular_values(M.tobytes())
    if not big > 0 or small <= SINGULAR_RTOL * big:
        cond = np.inf if small == 0 else big / small
        raise ValueError(f"{name}: {what} is singular (condition number {cond:.3g})")


def as_camera(C: object, name: str = "camera") -> np.ndarray:
    """Validate a 3x4 projection matrix `C = [M | c4]`.

    **Arguments:**

    - `C`: array-like (3, 4).
    - `name`: the argument's name, used in error messages.

    **Returns:**

    numpy (3, 4), float32 if given float32, else float64.

    **Raises:**

    `ValueError` naming `name` for a wrong shape, NaN/inf, or a singular `M`
    (smallest singular value at most `SINGULAR_RTOL` times the largest).
    """
    arr = _as_real_array(C, name)
    if arr.shape != (3, 4):
        raise ValueError(f"{name} must be a 3x4 projection matrix, got shape {arr.shape}")
    _check_finite(arr, name)
    _check_nonsingular(arr[:, :3], name, "its left 3x3 block M")
    return arr


def as_intrinsics(K: object, name: str = "camera_matrix") -> np.ndarray:
    """Validate a pinhole intrinsic matrix `K`.

    Accepted: shape (3, 3), finite, `K[2,2] != 0`, lower triangle zero (up to
    `1e-9 * max|K|`), focal lengths `K[0,0] / K[2,2] > 0` and `K[1,1] / K[2,2] > 0`,
    non-singular.

    **Arguments:**

    - `K`: array-like (3, 3).
    - `name`: the argument's name, used in error messages.

    **Returns:**

    numpy (3, 3), float32 if given float32, else float64 (not rescaled).

    **Raises:**

    `ValueError` naming `name` otherwise.
    """
    arr = _as_real_array(K, name)
    if arr.shape != (3, 3):
        raise ValueError(f"{name} must be a 3x3 intrinsic matrix, got shape {arr.shape}")
    _check_intrinsics(np.ascontiguousarray(arr, dtype=np.float64).tobytes(), name)
    return arr


@functools.lru_cache(maxsize=64)
def _check_intrinsics(data: bytes, name: str) -> None:
    """`as_intrinsics`'s checks of the 3x3 float64 matrix `data` (its bytes): a camera
    matrix passed again and again is checked once (a failed check is not cached)."""
    k = np.frombuffer(data, np.float64).reshape(3, 3)
    _check_finite(k, name)
    if k[2, 2] == 0:
        raise ValueError(f"{name}[2, 2] must be nonzero")
    scale = np.max(np.abs(k))
    lower = np.abs(np.array([k[1, 0], k[2, 0], k[2, 1]]))
    if np.any(lower > 1e-9 * scale):
        raise ValueError(
            f"{name} must be upper triangular (a pinhole camera matrix); "
            f"got lower entries {k[1, 0]}, {k[2, 0]}, {k[2, 1]}"
        )
    fx, fy = k[0, 0] / k[2, 2], k[1, 1] / k[2, 2]
    if not (fx > 0 and fy > 0):
        raise ValueError(f"{name} must have positive focal lengths, got fx={fx}, fy={fy}")
    _check_nonsingular(k, name, "the matrix")


def as_dist_coeffs(d: object, name: str = "dist_coeffs") -> np.ndarray | None:
    """Validate OpenCV distortion coefficients.

    **Arguments:**

    - `d`: None, or array-like of 4, 5, 8, 12 or 14 numbers (any of the shapes (k,),
      (k, 1), (1, k)).
    - `name`: the argument's name, used in error messages.

    **Returns:**

    None when `d` is None, empty or all zero (no distortion); else numpy float64 (k,).

    **Raises:**

    `ValueError` naming `name` for another size, a matrix shape, or NaN/inf.
    """
    if d is None:
        return None
    arr = _as_real_array(d, name)
    if arr.size == 0:
        return None
    if arr.ndim > 2 or (arr.ndim == 2 and 1 not in arr.shape):
        raise ValueError(f"{name} must be a vector, got shape {arr.shape}")
    arr = arr.reshape(-1).astype(np.float64)
    if arr.size not in DIST_COEFF_SIZES:
        raise ValueError(
            f"{name} must have {', '.join(map(str, DIST_COEFF_SIZES))} elements, got {arr.size}"
        )
    _check_finite(arr, name)
    if not np.any(arr):
        return None
    return arr


def as_matching(
    object_points: object, image_points: object, *, min_count: int = 1
) -> tuple[np.ndarray, np.ndarray]:
    """Validate matched model points (n, 3) and image points (n, 2).

    **Arguments:**

    - `object_points`: array-like (n, 3) (or OpenCV layouts, see `as_points`).
    - `image_points`: array-like (n, 2) (or OpenCV layouts).
    - `min_count`: the fewest matches accepted.

    **Returns:**

    `(object_points, image_points)` as numpy arrays (n, 3) and (n, 2).

    **Raises:**

    `ValueError` naming `object_points` or `image_points` for a bad array, or both
    when their counts differ.
    """
    obj = as_points(object_points, "object_points", 3, min_count=min_count)
    img = as_points(image_points, "image_points", 2, min_count=min_count)
    if obj.shape[0] != img.shape[0]:
        raise ValueError(
            f"object_points and image_points must match one to one: object_points has "
            f"{obj.shape[0]} points, image_points has {img.shape[0]}"
        )
    return obj, img


def as_batched(
    x: object,
    name: str,
    tail: int | tuple[int, ...],
    *,
    batch_size: int | None = None,
    count: int | None = None,
    shared: bool = True,
    min_count: int = 3,
) -> np.ndarray:
    """Validate a batch of arrays `(B, *tail)`, or one array `tail` shared by the batch.

    Values are not checked for finiteness: in a batch, a problem with NaN or inf is
    reported by its status (`NOT_FINITE`), not by an exception for all of them.

    **Arguments:**

    - `x`: array-like.
    - `name`: the argument's name, used in error messages.
    - `tail`: the shape of one item: an int `dim` for points `(n, dim)` (any `n >=
      min_count`, or exactly `count`), or a tuple, e.g. `(3, 4)` for a camera.
    - `batch_size`: the batch size `B` the leading axis must have (`None`: any `B >= 1`).
    - `count`: the number of points `n` required (points only).
    - `shared`: whether one unbatched item (`tail` alone) is accepted.
    - `min_count`: the fewest points accepted (points only).

    **Returns:**

    numpy array `(B, *tail)` or `tail`: float32 if given float32, else float64.

    **Raises:**

    `ValueError` naming `name` for a wrong shape or a non-real dtype.
    """
    arr = _as_real_array(x, name)
    points = isinstance(tail, (int, np.integer))
    rank = 2 if points else len(tail)
    if points:
        want = f"(n, {tail})" if count is None else f"({count}, {tail})"
    else:
        want = str(tuple(tail))
    batch = "B" if batch_size is None else str(batch_size)
    expected = f"({batch}, {want[1:]}" + (f" or {want}" if shared else "")
    if arr.ndim == rank + 1:
        item = arr.shape[1:]
        if arr.shape[0] < 1 or (batch_size is not None and arr.shape[0] != batch_size):
            raise ValueError(f"{name} must have shape {expected}, got {arr.shape}")
    elif arr.ndim == rank and shared:
        item = arr.shape
    else:
        raise ValueError(f"{name} must have shape {expected}, got {arr.shape}")
    if points:
        if item[1] != tail or (count is not None and item[0] != count):
            raise ValueError(f"{name} must have shape {expected}, got {arr.shape}")
        if item[0] < min_count:
            raise ValueError(f"{name} needs at least {min_count} points, got {item[0]}")
    elif tuple(item) != tuple(tail):
        raise ValueError(f"{name} must have shape {expected}, got {arr.shape}")
    return arr


def _shape_dtype(x: object, name: str) -> tuple[tuple[int, ...], np.dtype]:
    """Shape and dtype of an array, a tracer or an array-like (values are not read)."""
    if x is None:
        raise ValueError(f"{name} is required, got None")
    shape, dtype = getattr(x, "shape", None), getattr(x, "dtype", None)
    if shape is not None and dtype is not None:
        return tuple(shape), np.dtype(dtype)
    try:
        arr = np.asarray(x)
    except Exception as exc:  # ragged lists and the like
        raise ValueError(f"{name} could not be read as an array: {exc}") from exc
    return arr.shape, arr.dtype


def check_problem(
    camera: object, model: object, image: object, mask: object = None, *, min_count: int = 3
) -> None:
    """Check the shapes and dtypes of one problem of the JAX-native API.

    Only `.shape` and `.dtype` are read, never values, so this runs under `jit`, `vmap`
    and `grad` too (on tracers, at trace time); values (NaN, a singular camera) are
    reported by the solvers' status codes instead.

    **Arguments:**

    - `camera`: `(3, 4)`, real.
    - `model`: `(n, 3)`, real, `n >= min_count`.
    - `image`: `(n, 2)`, real, the same `n`.
    - `mask`: `None` or `(n,)`, bool or integer.
    - `min_count`: the fewest matches accepted.

    **Raises:**

    `ValueError` naming the argument.
    """

    def real(name: str, x: object) -> tuple[int, ...]:
        shape, dtype = _shape_dtype(x, name)
        if dtype == np.bool_ or not (
            np.issubdtype(dtype, np.integer) or np.issubdtype(dtype, np.floating)
        ):
            raise ValueError(f"{name} must hold real numbers, got dtype {dtype}")
        return shape

    shape = real("camera", camera)
    if shape != (3, 4):
        raise ValueError(f"camera must be a 3x4 projection matrix, got shape {shape}")
    shape = real("model", model)
    if len(shape) != 2 or shape[1] != 3:
        raise ValueError(f"model must have shape (n, 3), got {shape}")
    n = shape[0]
    shape = real("image", image)
    if len(shape) != 2 or shape[1] != 2:
        raise ValueError(f"image must have shape (n, 2), got {shape}")
    if shape[0] != n:
        raise ValueError(
            f"model and image must match one to one: model has {n} points, image has {shape[0]}"
        )
    if n < min_count:
        raise ValueError(f"model and image need at least {min_count} points, got {n}")
    if mask is not None:
        shape, dtype = _shape_dtype(mask, "mask")
        if shape != (n,):
            raise ValueError(f"mask must have shape ({n},), got {shape}")
        if not (dtype == np.bool_ or np.issubdtype(dtype, np.integer)):
            raise ValueError(f"mask must be bool (or integer 0/1), got dtype {dtype}")
