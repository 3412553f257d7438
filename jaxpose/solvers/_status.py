"""Status codes reported by every solver, under `jit` and `vmap`.

Code under `jit` never raises on data: it returns an `int32` status array beside a
finite placeholder result. `Status(code).message` turns a code into a sentence, and
`describe` does it for whole arrays at the public boundary.

`StatusCode` is the base of every such enumeration: the pose solvers' `Status` here, and
the applications' own (pointing, robot, calibration), which keep the solvers' integer
value for a code they share with them (`OK = 0`, `NOT_FINITE = 11`, ...).
"""

from __future__ import annotations

import enum
import functools

import jax.numpy as jnp
import numpy as np

__all__ = ["Status", "StatusCode", "describe"]


class StatusCode(enum.IntEnum):
    """Base of the status enumerations: each member is an `int` code (what `int32` status
    arrays hold) and a human-readable `message`.

    A subclass lists its members as `NAME = code, "message"`, and the members that mean
    success in `successes` (default: `OK` alone).
    """

    _message: str  # set per member by `__new__`; an annotation alone is not a member

    def __new__(cls, code: int, message: str):
        member = int.__new__(cls, code)
        member._value_ = code
        member._message = message
        return member

    @property
    def message(self) -> str:
        """What the code means, in words."""
        return self._message

    @classmethod
    def successes(cls) -> tuple[StatusCode, ...]:
        """The members that mean success."""
        return (cls["OK"],)

    @property
    def succeeded(self) -> bool:
        return self in self.successes()

    @classmethod
    def is_success(cls, code):
        """Elementwise: is `code` (an int array, traced or not) one of the `successes`?"""
        code = jnp.asarray(code)
        return functools.reduce(jnp.logical_or, [code == int(s) for s in cls.successes()])

    def __array__(self, dtype=None, copy=None):
        return np.asarray(int(self), dtype=dtype or np.int32)


class Status(StatusCode):
    """Why a pose was (or was not) produced by a solver or the mixed strategy."""

    OK = 0, "solved"
    ACCEPTED_LINEAR = 1, "accepted after the linear method (mixed step 2)"
    ACCEPTED_AFTER_NONLINEAR = (
        2,
        "accepted after Levenberg-Marquardt and linear (mixed step 4)",
    )
    REJECTED = 3, "converged, but the error is above the acceptance threshold"
    NONLINEAR_NOT_CONVERGED = 4, "Levenberg-Marquardt did not converge"
    LINEAR_NOT_CONVERGED = 5, "the small-movement linear method did not converge"
    NO_SOLUTION = 6, "the three-point method found no real solution"
    BEHIND_CAMERA = 7, "every candidate pose puts points behind the camera"
    DEGENERATE_IMAGE = 8, "image points are aligned (triangle area below threshold)"
    DEGENERATE_MODEL = 9, "model points are (nearly) collinear"
    TOO_FEW_POINTS = 10, "fewer valid matches than the method needs"
    NOT_FINITE = 11, "non-finite values in the input or during solving"
    NOT_ATTEMPTED = (
        12,
        "needed Levenberg-Marquardt but was outside the non-linear budget",
    )

    @classmethod
    def successes(cls) -> tuple[Status, ...]:
        """A pose was accepted: `OK`, `ACCEPTED_LINEAR`, `ACCEPTED_AFTER_NONLINEAR`."""
        return (cls.OK, cls.ACCEPTED_LINEAR, cls.ACCEPTED_AFTER_NONLINEAR)


def describe(code, codes: type[StatusCode] = Status) -> str | list:
    """Human-readable message(s) for a status code or an array of them.

    **Arguments:**

    - `code`: an int or an int array of codes.
    - `codes`: the enumeration they belong to (default the solvers' `Status`).

    **Returns:** the message, or nested lists of messages for an array.
    """
    arr = np.asarray(code)
    if arr.ndim == 0:
        return codes(int(arr)).message
    return [describe(c, codes) for c in arr]
