"""Tests of `jaxpose point`: click -> 3D point, face, uncertainty, robot joints."""

import math
import re

import numpy as np
import pytest

import jaxpose as jp
import jaxpose._robot as robot_module
from jaxpose._cli import main
from jaxpose._robot import default_robot, forward_kinematics

BENCH = jp.default_bench()
FLOAT = r"(-?\d+\.\d+)"


def _middle_pixel():
    """The pixel of the top face's middle (model point (0, 0, 10))."""
    p = np.array([0.0, 0.0, 10.0]) @ BENCH.R.T + BENCH.t
    h = BENCH.camera @ np.append(p, 1.0)
    return h[:2] / h[2], p


def _vector(text, label):
    m = re.search(label + r"\s*│\s*\(" + r",\s*".join([FLOAT] * 3) + r"\)", text)
    assert m, f"no {label!r} in:\n{text}"
    return np.array([float(x) for x in m.groups()])


def test_point_in_the_middle_hits_the_top_face(capsys):
    uv, truth = _middle_pixel()
    rc = main(["point", "--pixel", f"{uv[0]:.3f}", f"{uv[1]:.3f}"])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert re.search(r"face\s*│\s*0 \(top\)", out)
    point = _vector(out, r"3D point \(world\)")
    m = re.search(rf"{FLOAT} mm along the ray", out)
    sigma = float(m.group(1))
    assert 0 < sigma < 20
    # The true surface point under the click, within 4 sigma (the error is along the ray).
    assert np.linalg.norm(point - truth) < 4 * sigma + 0.02
    np.testing.assert_allclose(_vector(out, "true surface point"), truth, atol=0.01)
    # The printed joints bring the robot's tip to the printed point (up to their rounding).
    m = re.search(rf"x {FLOAT} mm, y {FLOAT} mm, pan {FLOAT} deg, tilt {FLOAT} deg", out)
    x, y, pan, tilt = (float(g) for g in m.groups())
    tip = forward_kinematics(
        default_robot(), np.array([x, y, math.radians(pan), math.radians(tilt)])
    )
    np.testing.assert_allclose(np.asarray(tip.tip), point, atol=0.2)


def test_no_face_there_is_one_line(capsys):
    rc = main(["point", "--pixel", "5", "5"])
    out = capsys.readouterr().out
    assert rc == 1
    assert out.strip().count("\n") == 0
    assert "no face at pixel (5, 5)" in out


def test_unreachable_is_one_line(capsys, monkeypatch):
    """A robot whose shank cannot come down to the object: one clear line."""
    tall = default_robot()._replace(height=np.asarray(500.0))  # tip at z >= 180 mm
    monkeypatch.setattr(robot_module, "default_robot", lambda *a, **k: tall)
    uv, _ = _middle_pixel()
    rc = main(["point", "--pixel", f"{uv[0]:.3f}", f"{uv[1]:.3f}"])
    out = capsys.readouterr().out
    assert rc == 1
    assert out.strip().count("\n") == 0
    assert "out of the robot's reach (UNREACHABLE)" in out
    assert "face 0 (top)" in out


@pytest.mark.parametrize(
    "argv, message",
    [
        (["point", "--pixel", "900", "10"], "outside the 768x576 image"),
        (["point", "--pixel", "nan", "10"], "--pixel must be finite"),
        (["point", "--pixel", "10", "10", "--noise", "-1"], "must be >= 0"),
    ],
)
def test_bad_input_is_one_line(capsys, argv, message):
    rc = main(argv)
    err = capsys.readouterr().err
    assert rc == 2
    assert message in err
    assert err.strip().count("\n") == 0


def test_missing_pixel(capsys):
    assert main(["point"]) == 2
    assert "--pixel" in capsys.readouterr().err
