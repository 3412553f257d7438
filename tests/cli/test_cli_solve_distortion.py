"""`jaxpose solve` with lens distortion: the pose of least pixel error in the image as
observed (what `cv2.solvePnP` + `cv2.solvePnPRefineLM` find on the raw pixels), in the
world frame of a general camera `K [R_wc | t_wc]`, and its RMS image error."""

import json

import cv2
import jax
import numpy as np
import pytest

import jaxpose as jp
from jaxpose.cli._main import main

K = np.array([[800.0, 0.0, 320.0], [0.0, 780.0, 240.0], [0.0, 0.0, 1.0]])
DIST = np.array([-0.3, 0.08, 0.001, -0.0008, 0.0])  # a strong barrel lens


def _run(capsys, *argv):
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


@pytest.fixture(scope="module")
def problem():
    """Ten points seen through the strong lens with 1 px noise, by a camera away from the
    world origin (`x_cam = R_wc p + t_wc`)."""
    rng = np.random.default_rng(11)
    s = jp.apps.random_scene(rng, 10, noise=0.0, world_camera=False)
    R_cam, t_cam = np.asarray(s.R), np.asarray(s.t)  # model -> camera
    R_wc = cv2.Rodrigues(np.array([0.3, -0.2, 0.1]))[0]
    t_wc = np.array([0.5, -1.0, 2.0])
    R, t = R_wc.T @ R_cam, R_wc.T @ (t_cam - t_wc)  # model -> world
    rvec, _ = cv2.Rodrigues(R_cam)
    seen, _ = cv2.projectPoints(s.model_points, rvec, t_cam, K, DIST)
    image = seen.reshape(-1, 2) + rng.normal(scale=1.0, size=(len(seen), 2))
    return {
        "model": np.asarray(s.model_points, np.float64),
        "image": image,
        "R_wc": R_wc,
        "t_wc": t_wc,
        "R": R,
        "t": t,
    }


def _opencv_optimum(model, image):
    """`cv2.solvePnP` (iterative) + `cv2.solvePnPRefineLM` on the raw pixels, to the end."""
    ok, rv, tv = cv2.solvePnP(model, image, K, DIST, flags=cv2.SOLVEPNP_SQPNP)
    assert ok
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 500, 1e-15)
    rv, tv = cv2.solvePnPRefineLM(model, image, K, DIST, rv, tv, criteria=crit)
    return rv.ravel(), tv.ravel()


def _image_rms(model, image, rvec, tvec):
    p, _ = cv2.projectPoints(model, np.asarray(rvec), np.asarray(tvec), K, DIST)
    return float(np.sqrt(np.mean(np.sum((p.reshape(-1, 2) - image) ** 2, axis=1))))


def _solve(tmp_path, capsys, p, method="linear", name="pose.json"):
    path = tmp_path / "problem.json"
    camera = {"K": K.tolist(), "dist": DIST.tolist(), "R": p["R_wc"].tolist()}
    camera["t"] = p["t_wc"].tolist()
    data = {"camera": camera, "model_points": p["model"].tolist()}
    path.write_text(json.dumps(data | {"image_points": p["image"].tolist()}))
    out_path = tmp_path / name
    rc, out, err = _run(capsys, "solve", path, "--method", method, "--out", out_path)
    return rc, out, err, json.loads(out_path.read_text())


def test_solve_with_distortion_is_the_image_space_optimum(tmp_path, capsys, problem):
    """The camera-frame pose equals OpenCV's image-space optimum to 1e-9, the world-frame
    pose is the same pose composed with the camera's motion, and the printed and written
    image error is the RMS pixel error in the image."""
    rc, out, err, res = _solve(tmp_path, capsys, problem)
    assert rc == 0, err
    assert res["refined_in_image"]
    model, image = problem["model"], problem["image"]
    rv, tv = _opencv_optimum(model, image)
    cam = res["camera_frame"]
    np.testing.assert_allclose(cam["rvec"], rv, atol=1e-9)
    np.testing.assert_allclose(cam["tvec"], tv, atol=1e-9)
    # the world frame: x_cam = R_wc (R m + t) + t_wc
    R_cam = cv2.Rodrigues(rv)[0]
    R_wc, t_wc = problem["R_wc"], problem["t_wc"]
    np.testing.assert_allclose(np.asarray(res["R"]), R_wc.T @ R_cam, atol=1e-9)
    np.testing.assert_allclose(res["t"], R_wc.T @ (tv - t_wc), atol=1e-9)
    rms = _image_rms(model, image, rv, tv)
    assert res["image_rms_px"] == pytest.approx(rms, rel=1e-9)
    assert "image error (RMS)" in out and f"{rms:.6g}" in out
    assert np.all(np.isfinite([res["error_px"], res["pose_error"]]))


def test_without_the_refinement_the_pose_differs(tmp_path, capsys, problem):
    """The optimum on the undistorted pixels (what the refinement starts from) is not
    OpenCV's with this lens: its pose differs by 1e4 times the tolerance above and its
    image error is larger. `three_point` keeps its three-point pose (no refinement)."""
    from jaxpose.cli._problem_read import read_problem

    _, _, err, res = _solve(tmp_path, capsys, problem)
    p = read_problem(tmp_path / "problem.json")
    # the command's own solve (a stored program), before its refinement
    with jax.enable_x64(True):
        sol = jp.solve(p.camera, p.model_points, p.image_points, p.mask, method="linear")
    R, t = np.asarray(sol.pose.R), np.asarray(sol.pose.t)
    R_cam, t_cam = p.R_wc @ R, p.R_wc @ t + p.t_wc
    rv, tv = _opencv_optimum(problem["model"], problem["image"])
    # 1e4 times the tolerance the refined pose meets
    assert np.abs(t_cam - tv).max() > 1e-5
    assert np.abs(cv2.Rodrigues(R_cam)[0].ravel() - rv).max() > 1e-5
    unrefined = _image_rms(problem["model"], problem["image"], cv2.Rodrigues(R_cam)[0], t_cam)
    assert unrefined > res["image_rms_px"] + 1e-5
    # three_point: no refinement, the reported image error is the three-point pose's
    rc, _, err, three = _solve(tmp_path, capsys, problem, "three_point", "three.json")
    assert rc == 0, err
    assert not three["refined_in_image"]
    cam = three["camera_frame"]
    assert three["image_rms_px"] == pytest.approx(
        _image_rms(problem["model"], problem["image"], cam["rvec"], cam["tvec"]), rel=1e-9
    )
    assert np.abs(np.asarray(cam["tvec"]) - tv).max() > 1e-5
