"""rerun recordings, read back for real: the written `.rrd` files pass `rerun rrd verify`,
hold the expected entities, and their geometry is the solver's (projections, wireframes,
camera) to float32 precision."""

import subprocess
import sys
from collections import defaultdict

import jax
import numpy as np
import pytest
from helpers import verify_recording
from rerun.chunk import RrdReader

import jaxpose as jp
from jaxpose.apps._experiment import METHOD_NAMES, ExperimentResult, run_experiment
from jaxpose.solvers._status import Status


def _rows(path):
    """Entity path -> list of rows (one dict per logged row, all chunks of the recording)."""
    rows = defaultdict(list)
    for chunk in RrdReader(path).stream():
        for row in chunk.to_record_batch().to_pylist():
            row["static"] = chunk.is_static
            rows[chunk.entity_path].append(row)
    return rows


def _recorded(path, log, *args, name=None, **kwargs):
    """The rows of a new recording at `path` filled by `log(rec, *args, **kwargs)`, once
    the file passes `rerun rrd verify`."""
    rec = jp.viz.rerun_recording(path, name=name)
    log(rec, *args, **kwargs)
    jp.viz.close_recording(rec)
    verify_recording(path)
    return _rows(path)


def _series(rows, entity):
    """Triplet index -> scalar of a time series."""
    return {r["triplet"]: r["Scalars:scalars"][0] for r in rows[entity] if not r["static"]}


def _only(rows, entity, column):
    """The single static value of `column` at `entity`."""
    values = [r[column] for r in rows[entity] if r["static"] and r.get(column) is not None]
    assert len(values) == 1, (entity, column, len(values))
    return values[0]


@pytest.fixture(scope="module")
def bench():
    return jp.default_bench()


@pytest.fixture(scope="module")
def mixed_result(bench):
    """The mixed algorithm over every triplet of the bench: the experiment's own (its
    stored program, which `tests/strategy/test_mixed.py` and `jaxpose reproduce` run on the
    same bench: compiled once for the suite, not once more here)."""
    return run_experiment(bench).mixed


def _answer(bench, res) -> jp.Solution:
    """The mixed algorithm's answer: its accepted triplet of lowest error."""
    ok = np.array([Status(int(s)).succeeded for s in res.status])
    k = int(np.argmin(np.where(ok, res.error, np.inf)))
    R, t = res.pose.R[k], res.pose.t[k]
    e = jax.jit(jp.geometry.pose_error)(bench.camera, R, t, bench.model_points, bench.image_points)
    return jp.Solution(jp.Pose(R, t), res.error[k], np.asarray(e), res.status[k], True, k)


def test_solution_recording(tmp_path, bench, mixed_result):
    sol = _answer(bench, mixed_result)
    picture = np.full((bench.image_size[1], bench.image_size[0], 3), 40, np.uint8)
    path = tmp_path / "solve.rrd"
    rows = _recorded(
        path,
        jp.viz.log_solution,
        bench.camera,
        bench.model_points,
        bench.image_points,
        sol,
        triplets=mixed_result,
        polyhedron=bench.model,
        true_pose=(bench.R, bench.t),
        image=picture,
        image_size=bench.image_size,
        name="bench",
    )
    expected = {
        "/world",
        "/world/camera",
        "/world/camera/image",
        "/world/camera/image/observed",
        "/world/camera/image/recovered",
        "/world/camera/image/recovered/wireframe",
        "/world/camera/image/true",
        "/world/camera/image/triplets/hypothesis",
        "/world/camera/image/triplets/points",
        "/world/model/recovered",
        "/world/model/true",
        "/world/points/recovered",
        "/world/rays",
        "/world/triplets/hypothesis",
        "/world/triplets/three_point",
        "/triplets/status",
        "/metrics/error_px/mixed",
        "/metrics/error_px/three_point",
        "/summary",
    }
    assert expected <= set(rows)
    assert RrdReader(path).blueprints(), "the default blueprint is stored with the recording"

    # The camera: centre and orientation in the world, intrinsics and image size.
    centre = np.asarray(jax.jit(jp.geometry.camera_centre)(bench.camera))
    np.testing.assert_allclose(
        _only(rows, "/world/camera", "Transform3D:translation")[0], centre, rtol=1e-6
    )
    # rerun stores 3x3 matrices column-major. The camera-to-world rotation is R_wc^T.
    R_cw = np.reshape(_only(rows, "/world/camera", "Transform3D:mat3x3")[0], (3, 3)).T
    np.testing.assert_allclose(R_cw, bench.R_wc.T, atol=1e-6)
    K = np.reshape(_only(rows, "/world/camera/image", "Pinhole:image_from_camera")[0], (3, 3)).T
    np.testing.assert_allclose(K, bench.K, rtol=1e-6, atol=1e-6)
    res = _only(rows, "/world/camera/image", "Pinhole:resolution")[0]
    assert res == list(bench.image_size)
    assert _only(rows, "/world/camera/image", "Image:buffer") is not None

    # 2D: observed points as given, reprojections are jaxpose.project of the answer.
    observed = np.asarray(_only(rows, "/world/camera/image/observed", "Points2D:positions"))
    np.testing.assert_allclose(observed, bench.image_points, atol=1e-3)
    world = np.asarray(bench.model_points) @ np.asarray(sol.pose.R).T + np.asarray(sol.pose.t)
    uv = np.asarray(jax.jit(jp.project)(bench.camera, world))
    reproj = np.asarray(_only(rows, "/world/camera/image/recovered", "Points2D:positions"))
    np.testing.assert_allclose(reproj, uv, atol=1e-3)
    # The accepted answer reprojects close to the observations (0.8 px noise).
    assert float(np.sqrt(np.mean(np.sum((reproj - observed) ** 2, axis=1)))) < 2.0

    # 3D: wireframes are the polyhedron's edges at the recovered and the true pose.
    poses = {"recovered": (sol.pose.R, sol.pose.t), "true": (bench.R, bench.t)}
    for name, (R, t) in poses.items():
        strips = np.asarray(_only(rows, f"/world/model/{name}", "LineStrips3D:strips"))
        vertices = bench.model.vertices @ np.asarray(R).T + np.asarray(t)
        np.testing.assert_allclose(strips, vertices[bench.model.edges], atol=1e-3)
        assert len(strips) == 36

    # Every triplet on the timeline: one status line each; a hypothesis for each usable one.
    T = len(mixed_result.status)
    log = rows["/triplets/status"]
    assert sorted(r["triplet"] for r in log) == list(range(T))
    usable = np.asarray(mixed_result.initial.status) == Status.OK
    hypotheses = {
        r["triplet"]: r["LineStrips3D:strips"]
        for r in rows["/world/triplets/hypothesis"]
        if r.get("LineStrips3D:strips") is not None
    }
    assert set(hypotheses) == set(np.flatnonzero(usable).tolist())
    cleared = {
        r["triplet"] for r in rows["/world/triplets/hypothesis"] if r.get("Clear:is_recursive")
    }
    assert cleared == set(np.flatnonzero(~usable).tolist())
    for k in list(hypotheses)[::97]:
        vertices = bench.model.vertices @ mixed_result.pose.R[k].T + mixed_result.pose.t[k]
        np.testing.assert_allclose(hypotheses[k], vertices[bench.model.edges], atol=1e-3)
    # Scalars: the per-triplet Eq. 8 error of the mixed algorithm.
    series = _series(rows, "/metrics/error_px/mixed")
    assert set(series) == set(np.flatnonzero(usable).tolist())
    for k, v in series.items():
        assert v == pytest.approx(float(mixed_result.error[k]), rel=1e-12)
    summary = _only(rows, "/summary", "TextDocument:text")[0]
    assert Status(int(sol.status)).name in summary


def test_experiment_recording(tmp_path, bench, mixed_result):
    """The experiment's recording holds all four methods' per-triplet results."""
    res = mixed_result
    T = len(res.status)
    rng = np.random.default_rng(0)
    errors = {m: np.asarray(res.error) for m in METHOD_NAMES}
    errors["three_point"] = np.asarray(res.initial.error)
    errors["linear"] = np.asarray(res.linear_error)
    result = ExperimentResult(
        triplets=np.asarray(res.initial.triplets),
        used=np.asarray(res.initial.status) == Status.OK,
        initial_status=np.asarray(res.initial.status),
        pose_error={m: rng.uniform(0.4, 2.0, T) for m in METHOD_NAMES},
        error=errors,
        status={m: np.asarray(res.status) for m in METHOD_NAMES},
        threshold=float(res.threshold),
    )
    rows = _recorded(tmp_path / "experiment.rrd", jp.viz.log_experiment, bench, result, res)
    used = set(np.flatnonzero(result.used).tolist())
    for m in METHOD_NAMES:
        for kind, values in (
            ("error_px", result.error[m]),
            ("pose_error_mm", result.pose_error[m]),
        ):
            got = _series(rows, f"/metrics/{kind}/{m}")
            assert set(got) == used
            k = min(used)
            assert got[k] == pytest.approx(float(values[k]), rel=1e-12)
    assert {"/world/model/true", "/world/model/recovered", "/world/triplets/hypothesis"} <= set(
        rows
    )
    summary = _only(rows, "/summary", "TextDocument:text")[0]
    assert "at the optimum" in summary and "paper" in summary


def test_three_point_only_and_points_only(tmp_path, bench, mixed_result):
    """An `Initial` (the three-point method alone) and a model without edges: no
    three-point ghost, hypotheses drawn as points; the camera pose decomposed from C."""
    sol = jp.Solution(
        jp.Pose(bench.R, bench.t), np.float64(0.0), np.float64(0.0), np.int32(0), True, 0
    )
    rows = _recorded(
        tmp_path / "points.rrd",
        jp.viz.log_solution,
        bench.camera,
        bench.model_points,
        bench.image_points,
        sol,
        triplets=mixed_result.initial,
    )
    assert "/world/model/recovered" not in rows and "/world/triplets/three_point" not in rows
    assert "/world/points/recovered" in rows and "/world/triplets/hypothesis" in rows
    hypotheses = {
        r["triplet"]: r["Points3D:positions"]
        for r in rows["/world/triplets/hypothesis"]
        if r.get("Points3D:positions") is not None
    }
    usable = np.flatnonzero(np.asarray(mixed_result.initial.status) == Status.OK)
    assert set(hypotheses) == set(usable.tolist())
    k = int(usable[0])
    R0, t0 = mixed_result.initial.pose.R[k], mixed_result.initial.pose.t[k]
    np.testing.assert_allclose(hypotheses[k], bench.model_points @ R0.T + t0, atol=1e-3)
    # The camera pose decomposed from C: its centre is C's null vector.
    centre = _only(rows, "/world/camera", "Transform3D:translation")[0]
    C = np.asarray(bench.camera)
    np.testing.assert_allclose(C @ np.append(centre, 1.0), 0.0, atol=1e-5 * np.abs(C).max())
    # The true pose reprojects onto the noise-free image points.
    reproj = np.asarray(_only(rows, "/world/camera/image/recovered", "Points2D:positions"))
    np.testing.assert_allclose(reproj, bench.clean_points, atol=1e-3)


def test_import_stays_light():
    code = "import sys, jaxpose; assert 'rerun' not in sys.modules, 'rerun imported eagerly'"
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)


def test_pointing_recording(tmp_path, bench):
    """`log_pointing` from the public API: a hit with its ellipsoid, the face outline, and
    a robot whose base is moved and turned (forward kinematics in the world)."""
    point = np.array([1.0, 2.0, 10.0]) @ bench.R.T + bench.t
    axes = np.linalg.qr(np.random.default_rng(1).normal(size=(3, 3)))[0]
    S = axes @ np.diag([4.0, 1.0, 0.25]) @ axes.T
    hit = jp.apps.Hit(point, np.int32(0), np.float64(2000.0), bench.R[:, 2], S, np.int32(0))
    turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    robot = jp.apps.default_robot()._replace(base_R=turn, base_t=np.array([10.0, -5.0, 2.0]))
    joints = np.array([30.0, -40.0, 0.5, 0.3])
    rows = _recorded(
        tmp_path / "point.rrd",
        jp.viz.log_pointing,
        bench.camera,
        (400.0, 250.0),
        hit,
        (bench.R, bench.t),
        polyhedron=bench.model,
        robot=robot,
        joints=joints,
        n_sigma=2.0,
    )
    e = {
        k: _only(rows, "/world/pointing/covariance", f"Ellipsoids3D:{k}")[0]
        for k in ("half_sizes", "quaternions")
    }
    np.testing.assert_allclose(sorted(e["half_sizes"]), [1.0, 2.0, 4.0], rtol=1e-6)
    x, y, z, w = e["quaternions"]
    Q = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    np.testing.assert_allclose(
        Q @ np.diag((np.array(e["half_sizes"]) / 2) ** 2) @ Q.T, S, atol=1e-5
    )
    outline = np.asarray(_only(rows, "/world/pointing/face", "LineStrips3D:strips")[0])
    top = bench.model.vertices[list(bench.model.faces[0])] @ bench.R.T + bench.t
    np.testing.assert_allclose(outline[:-1], top, atol=1e-3)
    state = jax.jit(jp.apps.forward_kinematics)(robot, joints)
    strips = _only(rows, "/world/robot/links", "LineStrips3D:strips")
    np.testing.assert_allclose(strips[-1], [state.wrist, state.tip], atol=1e-3)
    # Without a hit nor a robot: the click and its ray only.
    rec = jp.viz.rerun_recording(tmp_path / "miss.rrd")
    jp.viz.log_pointing(
        rec, bench.camera, (5.0, 5.0), None, (bench.R, bench.t), model_points=bench.model_points
    )
    jp.viz.close_recording(rec)
    rows = _rows(tmp_path / "miss.rrd")
    assert "/world/pointing/ray" in rows and "/world/camera/image/click" in rows
    assert not any(p.startswith(("/world/robot", "/world/pointing/point")) for p in rows)
    with pytest.raises(ValueError, match="model_points or a polyhedron"):
        jp.viz.log_pointing(rec, bench.camera, (5.0, 5.0), None, (bench.R, bench.t))
