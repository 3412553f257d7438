"""Tests of the status enumerations: the solvers' `Status` and the applications' own."""

import jax
import jax.numpy as jnp
import numpy as np

from jaxpose.apps import CalibrationStatus, PointingStatus, RobotStatus
from jaxpose.solvers._status import Status, StatusCode, describe

APP_STATUSES = (PointingStatus, RobotStatus, CalibrationStatus)


def test_solver_codes_keep_their_values():
    expected = {
        "OK": 0,
        "ACCEPTED_LINEAR": 1,
        "ACCEPTED_AFTER_NONLINEAR": 2,
        "REJECTED": 3,
        "NONLINEAR_NOT_CONVERGED": 4,
        "LINEAR_NOT_CONVERGED": 5,
        "NO_SOLUTION": 6,
        "BEHIND_CAMERA": 7,
        "DEGENERATE_IMAGE": 8,
        "DEGENERATE_MODEL": 9,
        "TOO_FEW_POINTS": 10,
        "NOT_FINITE": 11,
        "NOT_ATTEMPTED": 12,
    }
    assert {s.name: int(s) for s in Status} == expected
    assert all(isinstance(s.message, str) and s.message for s in Status)


def test_success_is_an_explicit_set():
    accepted = {Status.OK, Status.ACCEPTED_LINEAR, Status.ACCEPTED_AFTER_NONLINEAR}
    assert {s for s in Status if s.succeeded} == accepted
    codes = np.arange(-2, 20)
    expected = np.isin(codes, [int(s) for s in accepted])
    np.testing.assert_array_equal(Status.is_success(codes), expected)
    np.testing.assert_array_equal(jax.jit(Status.is_success)(jnp.asarray(codes)), expected)
    for cls in APP_STATUSES:
        assert [s for s in cls if s.succeeded] == [cls.OK]
        np.testing.assert_array_equal(cls.is_success(codes), codes == 0)


def test_application_codes_are_their_own():
    for cls in APP_STATUSES:
        assert issubclass(cls, StatusCode) and not issubclass(cls, Status)
        assert all(isinstance(s.message, str) and s.message for s in cls)
        # A code shared with the solvers has the solvers' value.
        for s in cls:
            if s.name in Status.__members__:
                assert int(s) == int(Status[s.name])
            else:
                assert int(s) not in {int(c) for c in Status}
    assert "none of the object's faces" in PointingStatus.NO_FACE.message
    assert not hasattr(Status, "NO_FACE") and not hasattr(Status, "JOINT_LIMITS")


def test_codes_work_in_arrays_and_describe():
    status = jnp.where(jnp.asarray([True, False]), RobotStatus.OK, RobotStatus.UNREACHABLE)
    assert status.tolist() == [0, 14]
    assert np.asarray(PointingStatus.NO_FACE, dtype=np.int32) == 13
    assert RobotStatus(14) is RobotStatus.UNREACHABLE
    assert describe(3) == Status.REJECTED.message
    assert describe([0, 13], PointingStatus) == [
        PointingStatus.OK.message,
        PointingStatus.NO_FACE.message,
    ]
