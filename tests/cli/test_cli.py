"""The command line, run in-process: `jaxpose solve` from JSON, OpenCV YAML and CSV files
against `jaxpose.solve_pnp` and OpenCV (on OpenCV's own chessboard photographs and
calibration file), recordings, one-line errors, `--help`."""

import argparse
import json
import sys

import cv2
import numpy as np
import pytest
from helpers import chessboard_corners

import jaxpose as jp
from jaxpose.apps import sample_path
from jaxpose.cli._main import build_parser, main
from jaxpose.cli._problem_read import read_problem
from jaxpose.cli._problem_write import bench_problem

DATA = sample_path("chessboard")


def _run(capsys, *argv):
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


def _assert_one_line_error(rc, err, command="solve"):
    assert rc == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith(f"jaxpose {command}: error: "), err
    assert "Traceback" not in err


@pytest.fixture(scope="module")
def problem():
    """A noisy problem with a general world camera `K [R | t]` and lens distortion: the
    image points are what a distorting lens shows (cv2.projectPoints), plus noise."""
    rng = np.random.default_rng(3)
    s = jp.apps.random_scene(rng, 8, noise=0.0, world_camera=True)
    C = np.asarray(s.camera)
    K = np.array([[800.0, 0.0, 320.0], [0.0, 800.0, 240.0], [0.0, 0.0, 1.0]])
    R_wc, t_wc = np.linalg.solve(K, C[:, :3]), np.linalg.solve(K, C[:, 3])
    dist = np.array([-0.12, 0.05, 0.001, -0.0005, 0.0])
    R_cam, t_cam = R_wc @ s.R, R_wc @ s.t + t_wc  # model -> camera
    rvec, _ = cv2.Rodrigues(R_cam)
    seen, _ = cv2.projectPoints(s.model_points, rvec, t_cam, K, dist)
    image = seen.reshape(-1, 2) + rng.normal(scale=0.5, size=(len(seen), 2))
    return {
        "K": K,
        "R_wc": R_wc,
        "t_wc": t_wc,
        "dist": dist,
        "model": np.asarray(s.model_points),
        "image": image,
        "R": np.asarray(s.R),
        "t": np.asarray(s.t),
    }


def _write_json(path, p, **extra):
    camera = {"K": p["K"].tolist(), "dist": p["dist"].tolist()}
    camera |= {"R": p["R_wc"].tolist(), "t": p["t_wc"].tolist()}
    data = {
        "camera": camera,
        "model_points": p["model"].tolist(),
        "image_points": p["image"].tolist(),
    }
    path.write_text(json.dumps(data | extra))
    return path


def _write_yaml(path, nodes: dict):
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in nodes.items():
        fs.write(key, value)
    fs.release()
    return path


def test_help_lists_every_command(capsys):
    rc, out, _ = _run(capsys, "--help")
    assert rc == 0
    parser = build_parser()
    (commands,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    assert {"reproduce", "bench", "solve"} <= set(commands.choices)
    for choice in commands._choices_actions:
        assert choice.help, f"{choice.dest} has no one-line purpose"
        assert choice.dest in out
        assert " ".join(choice.help.split()[:3]) in " ".join(out.split())
    for name in commands.choices:
        rc, out, _ = _run(capsys, name, "--help")
        assert rc == 0 and f"jaxpose {name}" in out
    rc, out, _ = _run(capsys, "solve", "--help")
    assert all(opt in out for opt in ("--model", "--image", "--camera", "--rrd", "--out"))


def test_solve_json_and_yaml_agree_with_solve_pnp(tmp_path, capsys, problem):
    """The file formats, the camera's extrinsics and the distortion are read right: the
    pose in the camera frame is `jaxpose.solve_pnp`'s, the world pose follows from it."""
    p = problem
    ok, rv_ref, tv_ref = jp.solve_pnp(
        p["model"], p["image"], p["K"], p["dist"], method="three_point"
    )
    assert ok
    results = {}
    json_path = _write_json(tmp_path / "problem.json", p)
    yaml_path = _write_yaml(
        tmp_path / "problem.yaml",
        {
            "camera_matrix": p["K"],
            "distortion_coefficients": p["dist"].reshape(-1, 1),
            "camera_rotation": cv2.Rodrigues(p["R_wc"])[0],  # as a rotation vector
            "camera_translation": p["t_wc"].reshape(3, 1),
            "object_points": p["model"],
            "image_points": p["image"].reshape(-1, 1, 2).astype(np.float32),
        },
    )
    # The same problem split over three files: model CSV, image text table, camera YAML.
    np.savetxt(tmp_path / "model.csv", p["model"], delimiter=",", header="x,y,z")
    np.savetxt(tmp_path / "image.txt", p["image"])
    camera_yaml = _write_yaml(
        tmp_path / "camera.yml",
        {
            "camera_matrix": p["K"],
            "distortion_coefficients": p["dist"].reshape(1, -1),
            "camera_rotation": p["R_wc"],
            "camera_translation": p["t_wc"].reshape(3, 1),
            "image_width": 640,
            "image_height": 480,
        },
    )
    runs = {
        "json": [json_path],
        "yaml": [yaml_path],
        "split": [
            "--model",
            tmp_path / "model.csv",
            "--image",
            tmp_path / "image.txt",
            "--camera",
            camera_yaml,
        ],
    }
    for name, args in runs.items():
        out_path = tmp_path / f"pose_{name}.json"
        rc, out, err = _run(capsys, "solve", *args, "--method", "three_point", "--out", out_path)
        assert rc == 0, err
        assert "accepted" in out and "rotation vector" in out
        results[name] = json.loads(out_path.read_text())
    # the command's programs listed, for its next process to load ahead (`prefetch`)
    from jaxpose.api import _programs

    folder = _programs._folder()
    assert folder is not None
    listed = (folder / "used-solve.txt").read_text().split()
    assert listed and all((folder / name).is_file() for name in listed)
    for name, res in results.items():
        assert res["accepted"] and res["status"] == "OK", name
        cam = res["camera_frame"]
        # The image points of the YAML file were stored as float32.
        tol = 1e-9 if name != "yaml" else 1e-4
        np.testing.assert_allclose(cam["rvec"], rv_ref.ravel(), atol=tol, err_msg=name)
        np.testing.assert_allclose(cam["tvec"], tv_ref.ravel(), atol=tol * 10, err_msg=name)
        # The world pose: camera frame = R_wc (R m + t) + t_wc.
        R, t = np.asarray(res["R"]), np.asarray(res["t"])
        R_cam, _ = cv2.Rodrigues(np.asarray(cam["rvec"]))
        np.testing.assert_allclose(p["R_wc"] @ R, R_cam, atol=1e-9)
        np.testing.assert_allclose(p["R_wc"] @ t + p["t_wc"], cam["tvec"], atol=1e-9)
        np.testing.assert_allclose(cv2.Rodrigues(R)[0].ravel(), res["rvec"], atol=1e-9)
        # Close to the truth (0.5 px noise, three points: loosely).
        assert np.degrees(np.linalg.norm(cv2.Rodrigues(R @ p["R"].T)[0])) < 5.0, name


def test_solve_writes_a_recording(tmp_path, capsys, problem):
    json_path = _write_json(tmp_path / "problem.json", problem, image_size=[640, 480])
    rrd = tmp_path / "rec" / "solve.rrd"
    rc, out, err = _run(capsys, "solve", json_path, "--method", "three_point", "--rrd", rrd)
    assert rc == 0, err
    assert f"wrote {rrd}" in " ".join(out.split())
    from rerun.chunk import RrdReader

    entities = {chunk.entity_path for chunk in RrdReader(rrd).stream()}
    wanted = {
        "/world/camera",
        "/world/camera/image",
        "/world/camera/image/observed",
        "/world/camera/image/recovered",
        "/world/triplets/hypothesis",
        "/triplets/status",
        "/metrics/error_px/three_point",
        "/summary",
    }
    assert wanted <= entities


def test_no_accepted_pose_exits_1(tmp_path, capsys, problem):
    """Every image triangle aligned: no pose, exit code 1, finite placeholders written."""
    p = dict(problem)
    p["dist"] = np.zeros(5)  # undistortion would bend the line
    p["image"] = np.column_stack([np.linspace(100, 500, 8), np.linspace(100, 300, 8)])
    path = _write_json(tmp_path / "aligned.json", p)
    out_path = tmp_path / "pose.json"
    rc, out, _ = _run(capsys, "solve", path, "--method", "three_point", "--out", out_path)
    assert rc == 1
    assert "NO POSE ACCEPTED" in out
    res = json.loads(out_path.read_text())
    assert not res["accepted"] and res["status"] == "DEGENERATE_IMAGE"
    assert np.all(np.isfinite(res["R"])) and np.all(np.isfinite(res["t"]))


@pytest.mark.parametrize("photo", ["left01.jpg", "left12.jpg"])
def test_solve_chessboard_with_opencv_calibration_file(tmp_path, capsys, photo):
    """A user's flow on real data: OpenCV's own calibration file (k1 = -0.27) as
    --camera, the detected corners and the board as CSV files. Same image-space optimum
    as OpenCV's SQPnP + Levenberg-Marquardt on the same corners. (The linear method: it
    compiles in a third of the mixed one's time; the mixed one is checked on these
    photographs in test_api.)"""
    found = chessboard_corners(DATA / photo)
    assert found is not None
    board, corners = found
    np.savetxt(tmp_path / "board.csv", board, delimiter=",")
    np.savetxt(tmp_path / "corners.csv", corners, delimiter=",")
    out_path = tmp_path / "pose.json"
    rc, out, err = _run(
        capsys,
        "solve",
        "--model",
        tmp_path / "board.csv",
        "--image",
        tmp_path / "corners.csv",
        "--camera",
        DATA / "left_intrinsics.yml",
        "--method",
        "linear",
        "--out",
        out_path,
    )
    assert rc == 0, err
    res = json.loads(out_path.read_text())
    assert res["accepted"] and res["matches"] == 54
    fs = cv2.FileStorage(str(DATA / "left_intrinsics.yml"), cv2.FILE_STORAGE_READ)
    K, dist = fs.getNode("camera_matrix").mat(), fs.getNode("distortion_coefficients").mat()
    fs.release()
    ok, rv, tv = cv2.solvePnP(board, corners, K, dist, flags=cv2.SOLVEPNP_SQPNP)
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 200, 1e-15)
    rv, tv = cv2.solvePnPRefineLM(board, corners, K, dist, rv, tv, criteria=crit)

    def reproj(rvec, tvec):
        p, _ = cv2.projectPoints(board, np.asarray(rvec), np.asarray(tvec), K, dist)
        return float(np.sqrt(np.mean(np.sum((p.reshape(-1, 2) - corners) ** 2, axis=1))))

    cam = res["camera_frame"]
    # Both minimise the error in the distorted image: the same optimum.
    assert reproj(cam["rvec"], cam["tvec"]) <= reproj(rv, tv) * (1 + 1e-9)
    np.testing.assert_allclose(cam["tvec"], tv.ravel(), atol=1e-7)  # metres
    np.testing.assert_allclose(cam["rvec"], rv.ravel(), atol=1e-7)
    # The world frame is the camera frame here (no extrinsics in the file).
    np.testing.assert_allclose(res["t"], cam["tvec"], atol=1e-12)


def test_write_example_round_trip(tmp_path, capsys):
    bench = jp.default_bench()
    want = bench_problem(bench)
    for name in ("bench.json", "bench.yaml"):
        rc, out, err = _run(capsys, "solve", "--write-example", tmp_path / name)
        assert rc == 0, err
        got = read_problem(tmp_path / name)
        np.testing.assert_allclose(got.camera, want.camera, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(got.model_points, want.model_points)
        np.testing.assert_allclose(got.image_points, want.image_points, rtol=1e-12)
        np.testing.assert_array_equal(got.polyhedron.edges, bench.model.edges)
        assert got.image_size == tuple(bench.image_size)
    got = read_problem(tmp_path / "bench.json")
    np.testing.assert_allclose(got.true_pose[0], bench.R)
    assert got.polyhedron.faces == bench.model.faces


def _bad_files(tmp, p):
    good = _write_json(tmp / "good.json", p)
    (tmp / "syntax.json").write_text('{"camera": {"K": [[1, 0, 0]]')
    _write_json(tmp / "typo.json", p, model_point=[1, 2, 3])
    wrong = json.loads(good.read_text())
    wrong["image_points"] = [[1.0, 2.0, 3.0]] * 8
    (tmp / "shape.json").write_text(json.dumps(wrong))
    fewer = json.loads(good.read_text())
    fewer["image_points"] = fewer["image_points"][:5]
    (tmp / "count.json").write_text(json.dumps(fewer))
    no_camera = json.loads(good.read_text())
    del no_camera["camera"]
    (tmp / "nocam.json").write_text(json.dumps(no_camera))
    singular = json.loads(good.read_text())
    singular["camera"] = {"K": [[0, 0, 0], [0, 0, 0], [0, 0, 1]]}
    (tmp / "singular.json").write_text(json.dumps(singular))
    mask = json.loads(good.read_text()) | {"mask": [True, False]}
    (tmp / "mask.json").write_text(json.dumps(mask))
    (tmp / "garbage.yaml").write_text("%YAML:1.0\n---\ncamera_matrix: [1, 2\n  : : {")
    (tmp / "points.txt").write_text("1 2 3\n4 5 6\n7 8 9\n")
    (tmp / "words.csv").write_text("a,b,c\n")
    (tmp / "bin.json").write_bytes(b"\xff\xfe\x00\x81")
    return {
        "missing file": ([tmp / "missing.json"], "no such file"),
        "directory": ([tmp], "not a file"),
        "JSON syntax": ([tmp / "syntax.json"], "invalid JSON"),
        "not text": ([tmp / "bin.json"], "not a text file"),
        "unknown key": ([tmp / "typo.json"], "model_point"),
        "image point shape": ([tmp / "shape.json"], "image_points"),
        "point counts": ([tmp / "count.json"], "5 image points but 8 model points"),
        "no camera": ([tmp / "nocam.json"], "no camera"),
        "singular K": ([tmp / "singular.json"], "camera.K"),
        "mask length": ([tmp / "mask.json"], "mask must have 8 entries"),
        "bad YAML": ([tmp / "garbage.yaml"], "invalid OpenCV YAML"),
        "text problem": ([tmp / "points.txt"], "model or image points"),
        "text not numbers": (
            ["--model", tmp / "words.csv", "--image", good, "--camera", good],
            "not a table of numbers",
        ),
        "no input": ([], "give a problem file"),
        "missing photo": ([good, "--photo", tmp / "nope.jpg"], "--photo"),
        "rrd suffix": ([good, "--rrd", tmp / "out.txt"], ".rrd"),
        "threshold": ([good, "--threshold", "-1"], "--threshold"),
        "bad method": ([good, "--method", "epnp"], "invalid choice"),
        "bad number": ([good, "--threshold", "abc"], "invalid float"),
    }


def test_bad_input_is_one_line(tmp_path, capsys, problem):
    for case, (args, needle) in _bad_files(tmp_path, problem).items():
        rc, out, err = _run(capsys, "solve", *args)
        _assert_one_line_error(rc, err)
        assert needle in err, f"{case}: {err}"


def test_unknown_suffix_and_viewer_guards(tmp_path, capsys, problem, monkeypatch):
    (tmp_path / "problem.toml").write_text("camera = 1")
    rc, _, err = _run(capsys, "solve", tmp_path / "problem.toml")
    _assert_one_line_error(rc, err)
    assert "unknown format '.toml'" in err
    # No display: --spawn is refused at once, before any computation.
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    good = _write_json(tmp_path / "good.json", problem)
    rc, _, err = _run(capsys, "solve", good, "--spawn")
    if sys.platform.startswith("linux"):
        _assert_one_line_error(rc, err)
        assert "display" in err
    rc, _, err = _run(capsys, "reproduce", "--rrd", tmp_path / "x.rrd", "--port", "0")
    _assert_one_line_error(rc, err, "reproduce")
    assert "--port" in err


def test_polyhedron_with_matched_vertices_and_mask(tmp_path):
    """A model given as a polyhedron plus the vertex index of each image point, in a
    separate --model file; the mask is read as booleans (JSON) or 0/1 (YAML)."""
    bench = jp.default_bench()
    model = {
        "polyhedron": {
            "vertices": bench.model.vertices.tolist(),
            "edges": bench.model.edges.tolist(),
        },
        "matched_vertices": bench.visible.tolist(),
    }
    (tmp_path / "model.json").write_text(json.dumps(model))
    mask = np.ones(len(bench.visible), bool)
    mask[3] = False
    (tmp_path / "image.json").write_text(
        json.dumps({"image_points": bench.image_points.tolist(), "mask": mask.tolist()})
    )
    _write_yaml(tmp_path / "camera.yaml", {"projection_matrix": bench.camera})
    got = read_problem(
        model=tmp_path / "model.json",
        image=tmp_path / "image.json",
        camera=tmp_path / "camera.yaml",
    )
    np.testing.assert_array_equal(got.model_points, bench.model_points)
    np.testing.assert_array_equal(got.mask, mask)
    np.testing.assert_allclose(got.camera, bench.camera)
    assert got.K is None and len(got.polyhedron.edges) == 36
    _write_yaml(
        tmp_path / "mask.yaml", {"image_points": bench.image_points, "mask": mask.astype(np.int32)}
    )
    got = read_problem(
        model=tmp_path / "model.json", image=tmp_path / "mask.yaml", camera=tmp_path / "camera.yaml"
    )
    np.testing.assert_array_equal(got.mask, mask)


def test_the_command_ends_with_its_code_and_whole_outputs(tmp_path):
    """The `jaxpose` executable (`jaxpose.cli.run`) ends its process at once after the
    command (no interpreter teardown): its exit code, everything it printed and wrote
    (a recording verified by rerun) are whole."""
    import subprocess

    from helpers import verify_recording

    def jaxpose(*argv):
        code = "from jaxpose.cli import run; run()"  # (sys.argv[1:]: the arguments)
        cmd = [sys.executable, "-c", code, *map(str, argv)]
        return subprocess.run(cmd, capture_output=True, text=True, cwd=tmp_path, timeout=600)

    made = jaxpose("solve", "--write-example", "bench.json")
    assert made.returncode == 0, made.stderr
    out = jaxpose("solve", "bench.json", "--out", "pose.json", "--rrd", "solve.rrd")
    assert out.returncode == 0, out.stderr
    assert "wrote" in out.stdout and "accepted" in out.stdout
    assert json.loads((tmp_path / "pose.json").read_text())["accepted"]
    verify_recording(tmp_path / "solve.rrd")
    bad = jaxpose("solve", "missing.json")
    assert bad.returncode == 2
    assert bad.stderr.strip() == "jaxpose solve: error: missing.json: no such file"
