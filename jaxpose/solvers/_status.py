"""Status codes reported by every solver, under `jit` and `vmap`.

Code under `jit` never raises on data: it returns an `int32` status array beside a
finite placeholder result. `Status(code).message` turns a code into a sentence, and
`describe` does it for whole arrays at the public boundary.
"""

from __future__ import annotations

import enum

import jax.numpy as jnp
import numpy as np

__all__ = ["Status", "describe"]


class Status(enum.IntEnum):
    """Why a pose was (or was not) produced. Lower-valued failures never mask success."""

    OK = 0
    ACCEPTED_LINEAR = 1
    ACCEPTED_AFTER_NONLINEAR = 2
    REJECTED = 3
    NONLINEAR_NOT_CONVERGED = 4
    LINEAR_NOT_CONVERGED = 5
    NO_SOLUTION = 6
    BEHIND_CAMERA = 7
    DEGENERATE_IMAGE = 8
    DEGENERATE_MODEL = 9
    TOO_FEW_POINTS = 10
    NOT_FINITE = 11
    NOT_ATTEMPTED = 12
    NO_FACE = 13
    UNREACHABLE = 14
    JOINT_LIMITS = 15
    COPLANAR_POINTS = 16
    UNDETERMINED_CAMERA = 17

    @property
    def message(self) -> str:
        return _MESSAGES[self]

    @property
    def succeeded(self) -> bool:
        return self in (Status.OK, Status.ACCEPTED_LINEAR, Status.ACCEPTED_AFTER_NONLINEAR)

    def __array__(self, dtype=None, copy=None):
        return np.asarray(int(self), dtype=dtype or np.int32)

    @staticmethod
    def is_success(code):
        """Elementwise: does `code` (an int array, traced or not) mean a pose was accepted?"""
        code = jnp.asarray(code)
        return code <= Status.ACCEPTED_AFTER_NONLINEAR


_MESSAGES = {
    Status.OK: "solved",
    Status.ACCEPTED_LINEAR: "accepted after the linear method (mixed step 2)",
    Status.ACCEPTED_AFTER_NONLINEAR: "accepted after Levenberg-Marquardt and linear (mixed step 4)",
    Status.REJECTED: "converged, but the error is above the acceptance threshold",
    Status.NONLINEAR_NOT_CONVERGED: "Levenberg-Marquardt did not converge",
    Status.LINEAR_NOT_CONVERGED: "the small-movement linear method did not converge",
    Status.NO_SOLUTION: "the three-point method found no real solution",
    Status.BEHIND_CAMERA: "every candidate pose puts points behind the camera",
    Status.DEGENERATE_IMAGE: "image points are aligned (triangle area below threshold)",
    Status.DEGENERATE_MODEL: "model points are (nearly) collinear",
    Status.TOO_FEW_POINTS: "fewer valid matches than the method needs",
    Status.NOT_FINITE: "non-finite values in the input or during solving",
    Status.NOT_ATTEMPTED: "needed Levenberg-Marquardt but was outside the non-linear budget",
    Status.NO_FACE: "the visual ray of the pixel meets none of the object's faces",
    Status.UNREACHABLE: "the target is outside the robot's workspace: no joint values put "
    "the shank tip there",
    Status.JOINT_LIMITS: "the shank tip reaches the target only with joints outside their limits",
    Status.COPLANAR_POINTS: "the 3D points are (nearly) coplanar: they do not determine a 3x4 "
    "camera matrix",
    Status.UNDETERMINED_CAMERA: "the 3D-2D pairs do not determine the camera matrix (the DLT "
    "system has more than one null direction)",
}


def describe(code) -> str | list:
    """Human-readable message(s) for a status code or an array of them."""
    arr = np.asarray(code)
    if arr.ndim == 0:
        return Status(int(arr)).message
    return [describe(c) for c in arr]
