"""The accuracy benchmark (`benchmarks/accuracy.py`, its protocol in
`benchmarks/_protocol.py`) on a tiny grid: its JSON, its tables, and jaxpose's mixed
method at the ML optimum that the benchmark computes with OpenCV."""

import json

import cv2
import numpy as np
import pytest

from benchmarks import _protocol as protocol
from benchmarks import accuracy


def test_rotation_and_translation_errors():
    rng = np.random.default_rng(0)
    rv = rng.normal(size=(20, 3))
    R = protocol.rotvec_to_matrix(rv)
    for r, M in zip(rv, R, strict=True):
        np.testing.assert_allclose(M, cv2.Rodrigues(r)[0], atol=1e-12)
    # A rotation by a about z moves the x and y axes by a and leaves z: largest axis angle a.
    a = np.radians(0.37)
    Rz = protocol.rotvec_to_matrix(np.array([[0.0, 0.0, a]]))
    err = protocol.rotation_error_deg(R[:1], R[:1] @ Rz)
    np.testing.assert_allclose(err, [0.37], rtol=1e-9)
    np.testing.assert_allclose(protocol.rotation_angle_deg(R[:1], R[:1] @ Rz), [0.37], rtol=1e-9)
    t = np.array([[3.0, 0.0, 4.0]])
    np.testing.assert_allclose(protocol.translation_error_pct(t, t + [0, 0.05, 0]), [1.0])


def test_reprojection_rms_matches_opencv():
    rng = np.random.default_rng(1)
    cell = protocol.make_cell("ordinary", 7, 1.5, 3)
    rv = rng.normal(scale=0.01, size=(3, 3))
    R = cell.R @ protocol.rotvec_to_matrix(rv)
    ours = protocol.reprojection_rms(cell.obj, cell.img, cell.K, R, cell.t)
    for b in range(3):
        p, _ = cv2.projectPoints(cell.obj[b], cv2.Rodrigues(R[b])[0], cell.t[b], cell.K, None)
        ref = np.sqrt(np.mean(np.sum((p.reshape(-1, 2) - cell.img[b]) ** 2, axis=1)))
        assert ours[b] == pytest.approx(ref, rel=1e-12)


def test_cells_are_seeded_prefixes():
    long = protocol.make_cell("planar", 6, 2.0, 5)
    short = protocol.make_cell("planar", 6, 2.0, 3)
    np.testing.assert_array_equal(long.img[:3], short.img)
    other = protocol.make_cell("planar", 6, 3.0, 3)
    assert not np.allclose(other.obj, short.obj)


def test_ml_optimum_is_no_worse_than_its_starts():
    cell = protocol.make_cell("quasi_singular", 10, 2.0, 6)
    ml, err, won = protocol.ml_optimum(cell, 6)
    assert ml.ok.all() and len(won) == 6
    for name in ("EPNP", "SQPNP", "ITERATIVE"):
        other = protocol.solve_opencv(cell, protocol.OPENCV_FLAGS[name], 6)
        rms = protocol.reprojection_rms(cell.obj, cell.img, cell.K, other.R, other.t)
        assert np.all(err <= rms + 1e-9), name


@pytest.mark.slow
def test_run_on_a_tiny_grid(tmp_path):
    # One cell per kind (n = 10, sigma = 2 px: both sweeps share it), mixed only: one
    # compilation of solve_pnp_batch (most of this test's time).
    schedule = accuracy.Schedule(trials=6, large_n={}, ablation={})
    result = accuracy.run(
        True,
        tmp_path,
        schedule=schedule,
        kinds=("quasi_singular", "planar"),
        sigmas=(2.0,),
        ns=(10,),
        jax_methods=("mixed",),
        real_images=False,
        chunk=6,
    )
    saved = json.loads((tmp_path / "accuracy_quick.json").read_text())
    assert saved["at_optimum"] == result["at_optimum"]
    assert {"machine", "versions", "protocol", "schedule", "synthetic"} <= set(saved)
    assert saved["versions"]["opencv"] == cv2.__version__
    for kind in ("quasi_singular", "planar"):
        assert (tmp_path / f"accuracy_quick_{kind}.png").stat().st_size > 0
        cell = saved["synthetic"][kind]["sigma"]["cells"][0]
        assert saved["synthetic"][kind]["n"]["cells"][0] == cell
        methods = cell["methods"]
        assert ("cv2 IPPE" in methods) == (kind == "planar")
        ml = methods[protocol.ML]
        assert ml["trials"] == 6 and ml["at_optimum_abs"] == 6
        assert 0 < ml["rotation_deg"]["median"] < 10
        mixed = saved["at_optimum"][kind]["jaxpose mixed"]
        assert mixed["trials"] == 6 and mixed["failed"] == 0
        assert mixed["at_optimum_abs"] == 6 and mixed["local_minima"] == 0
    text = accuracy.markdown(saved)
    assert "| jaxpose mixed |" in text and "100.00% (6/6)" in text
