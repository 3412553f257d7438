"""Tests of `jaxpose point`: click -> 3D point, face, uncertainty, robot joints."""

import math
import re

import numpy as np
import pytest
from helpers import verify_recording

import jaxpose as jp
import jaxpose.apps._robot as robot_module
from jaxpose.apps._robot import default_robot, forward_kinematics
from jaxpose.cli._main import main

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


def test_the_solve_is_jaxpose_solve_and_its_stored_program(capsys, monkeypatch):
    """`jaxpose point` solves the bench with a plain `jaxpose.solve` (the stored program
    `jaxpose solve` and the README's `jp.solve` load, with its escalation when the best
    roots find no pose), then runs its own program on that answer: the printed point is
    the one picked from `jaxpose.solve`'s pose."""
    import jaxpose.api._solve as solve_module
    from jaxpose.api import _programs

    calls = []
    real = solve_module.solve

    def solve(*args, **kwargs):
        calls.append(kwargs)
        return real(*args, **kwargs)

    monkeypatch.setattr(solve_module, "solve", solve)
    uv, _ = _middle_pixel()
    rc = main(["point", "--pixel", f"{uv[0]:.3f}", f"{uv[1]:.3f}"])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert calls == [{}]  # the default options: jaxpose.solve's own program
    names = [p.name for p in _programs._PROGRAMS.values()]
    assert any(name.startswith("jaxpose.api._stored._stored_program(") for name in names)
    assert any(name.startswith("jaxpose.cli._point._point_run(") for name in names)
    # the point printed is the pick from jaxpose.solve's answer
    sol = real(BENCH.camera, BENCH.model_points, BENCH.image_points)
    pose = jp.Pose(np.asarray(sol.pose.R), np.asarray(sol.pose.t))
    np.testing.assert_allclose(_vector(out, r"3D point \(world\)"), _picked(uv, pose), atol=0.01)


def _picked(uv, pose):
    """The surface point under `uv` seen from `pose` (the bench's polyhedron)."""
    from jaxpose.apps._pointing import pick, polyhedron_faces

    hit = pick(BENCH.camera, polyhedron_faces(BENCH.model), pose, np.asarray(uv, float))
    return np.asarray(hit.point)


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


# --------------------------------------------------------------------------- rerun recording


def _static(path):
    """Entity path -> its static row (the pointing recording has no timeline)."""
    from rerun.chunk import RrdReader

    rows = {}
    for chunk in RrdReader(path).stream():
        for row in chunk.to_record_batch().to_pylist():
            rows.setdefault(chunk.entity_path, {}).update(
                {k: v for k, v in row.items() if v is not None}
            )
    return rows


def _quaternion_matrix(x, y, z, w):
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def test_point_recording(capsys, tmp_path):
    """`--rrd`: the camera and image, the wireframe, the click and its ray, the point with
    its covariance ellipsoid, the face and the robot reaching the point, as printed."""
    uv, truth = _middle_pixel()
    path = tmp_path / "sub" / "point.rrd"
    rc = main(["point", "--pixel", f"{uv[0]:.3f}", f"{uv[1]:.3f}", "--rrd", str(path)])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert f"wrote {path}" in out
    verify_recording(path)
    rows = _static(path)
    expected = {
        "/world/camera",
        "/world/camera/image",
        "/world/camera/image/click",
        "/world/camera/image/face",
        "/world/camera/image/recovered/wireframe",
        "/world/model/recovered",
        "/world/pointing/ray",
        "/world/pointing/point",
        "/world/pointing/covariance",
        "/world/pointing/face",
        "/world/pointing/normal",
        "/world/pointing/true_point",
        "/world/robot/links",
        "/world/robot/joints",
        "/world/robot/travel",
        "/world/robot/frames",
        "/summary",
    }
    assert expected <= set(rows), expected - set(rows)
    assert rows["/world/camera/image"].get("Image:buffer") is not None  # the bench image

    point = _vector(out, r"3D point \(world\)")
    np.testing.assert_allclose(
        rows["/world/camera/image/click"]["Points2D:positions"][0], uv, atol=1e-3
    )
    hit = np.array(rows["/world/pointing/point"]["Points3D:positions"][0])
    np.testing.assert_allclose(hit, point, atol=0.006)  # printed to 0.01 mm
    np.testing.assert_allclose(
        rows["/world/pointing/true_point"]["Points3D:positions"][0], truth, atol=0.01
    )
    # The ray runs from the camera centre through the point (and a little past it).
    centre = BENCH.R_wc.T @ -BENCH.t_wc
    start, end = np.array(rows["/world/pointing/ray"]["LineStrips3D:strips"][0])
    np.testing.assert_allclose(start, centre, atol=1e-3)
    d = (end - start) / np.linalg.norm(end - start)
    along = (hit - start) @ d
    assert 0 < along < np.linalg.norm(end - start)
    assert np.linalg.norm(hit - start - along * d) < 1e-2
    # The 3-sigma ellipsoid: its covariance has the printed sigma along the ray.
    e = rows["/world/pointing/covariance"]
    np.testing.assert_allclose(e["Ellipsoids3D:centers"][0], hit, atol=1e-3)
    Q = _quaternion_matrix(*e["Ellipsoids3D:quaternions"][0])
    S = Q @ np.diag((np.array(e["Ellipsoids3D:half_sizes"][0]) / 3) ** 2) @ Q.T
    sigma = float(re.search(rf"{FLOAT} mm along the ray", out).group(1))
    assert math.sqrt(d @ S @ d) == pytest.approx(sigma, abs=0.006)
    # The face hit: the top face's outline (12 corners, closed), the point in its plane.
    outline = np.array(rows["/world/pointing/face"]["LineStrips3D:strips"][0])
    assert len(outline) == 13 and np.allclose(outline[0], outline[-1])
    normal = np.array(rows["/world/pointing/normal"]["Arrows3D:vectors"][0])
    assert np.abs((outline - hit) @ normal / np.linalg.norm(normal)).max() < 1e-2
    # The robot: its shank (from forward kinematics) ends at the point; shank length kept.
    strips = rows["/world/robot/links"]["LineStrips3D:strips"]
    labels = rows["/world/robot/links"]["LineStrips3D:labels"]
    wrist, tip = np.array(strips[labels.index("shank")])
    np.testing.assert_allclose(tip, hit, atol=1e-3)
    assert np.linalg.norm(tip - wrist) == pytest.approx(float(default_robot().shank), rel=1e-6)
    np.testing.assert_allclose(rows["/world/robot/joints"]["Points3D:positions"][1], hit, atol=1e-3)
    summary = rows["/summary"]["TextDocument:text"][0]
    assert "face 0 (top)" in summary and "robot joints" in summary


def test_point_recording_no_face(capsys, tmp_path):
    """No face under the click: the one line, and a recording of the ray alone."""
    path = tmp_path / "miss.rrd"
    rc = main(["point", "--pixel", "5", "5", "--rrd", str(path)])
    out = capsys.readouterr().out
    assert rc == 1
    assert out.splitlines()[0].startswith("jaxpose point: no face at pixel (5, 5)")
    verify_recording(path)
    rows = _static(path)
    assert {"/world/pointing/ray", "/world/camera/image/click", "/world/model/recovered"} <= set(
        rows
    )
    assert not any(p.startswith(("/world/robot", "/world/pointing/point")) for p in rows)
    assert "no face" in rows["/summary"]["TextDocument:text"][0]


def test_point_recording_bad_path_fails_fast(capsys, tmp_path):
    rc = main(["point", "--pixel", "10", "10", "--rrd", str(tmp_path / "x.txt")])
    err = capsys.readouterr().err
    assert rc == 2
    assert "--rrd must name a .rrd file" in err and err.strip().count("\n") == 0
