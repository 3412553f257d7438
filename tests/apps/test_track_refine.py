"""Offline joint refinement of a tracked sequence (`jaxpose.apps.refine_track`) on a
rendered sequence with known poses: the error does not grow and the jitter drops."""

import cv2
import numpy as np
import pytest
from test_track import GEO, K, _errors, _sequence

from jaxpose.apps import RefinedTrack, TrackOptions, motion_sigmas, refine_track, track

SHADES = np.array([200.0, 90.0, 150.0, 240.0, 120.0, 60.0])


def _motion_error(poses, Rs):
    """Per pair of consecutive frames, the angle (degrees) between the estimated and the
    true rotation from one frame to the next: the jitter the trajectory adds."""
    out = []
    for i in range(1, len(Rs)):
        est = poses[i].R @ poses[i - 1].R.T
        true = Rs[i] @ Rs[i - 1].T
        out.append(np.degrees(np.linalg.norm(cv2.Rodrigues(est @ true.T)[0])))
    return np.array(out)


@pytest.fixture(scope="module")
def tracked():
    frames, Rs, ts = _sequence(40, seed=2, noise=2.0, shades=SHADES)
    results = list(
        track(frames, GEO, K, None, (Rs[0], ts[0]), options=TrackOptions(use_points=False))
    )
    assert all(r.ok and r.rows is not None for r in results)
    return results, Rs, ts


def test_refinement_keeps_the_error_and_lowers_the_jitter(tracked):
    results, Rs, ts = tracked
    out = refine_track(results)
    assert isinstance(out, RefinedTrack) and len(out.frames) == len(results)
    assert out.cost_after < out.cost_before
    rot0, tr0 = _errors(results, Rs, ts)
    rot1, tr1 = _errors(out.frames, Rs, ts)
    assert rot1.mean() <= rot0.mean() * 1.05 and tr1.mean() <= tr0.mean() * 1.05
    assert np.percentile(rot1, 95) <= np.percentile(rot0, 95) * 1.05
    jitter0, jitter1 = _motion_error(results, Rs), _motion_error(out.frames, Rs)
    assert np.median(jitter1) < np.median(jitter0)
    assert np.percentile(jitter1, 95) < np.percentile(jitter0, 95)
    for before, after in zip(results, out.frames, strict=True):
        assert after.status == before.status and after.frame == before.frame
        assert np.all(np.isfinite(after.R)) and np.all(np.isfinite(after.t))
        np.testing.assert_allclose(after.R @ after.R.T, np.eye(3), atol=1e-12)
        assert np.isfinite(after.rms) and after.rms < 3.0


def test_a_lost_frame_is_kept_and_breaks_the_chain(tracked):
    results, Rs, ts = tracked
    lost = list(results)
    lost[20] = lost[20]._replace(ok=False, status="lost", rows=None, R=lost[19].R, t=lost[19].t)
    out = refine_track(lost, rotation_sigma=0.02)  # (a strong prior: the chain matters)
    assert out.frames[20] is lost[20]
    # The lost frame's pose (the last one held, 2.7 degrees off) pulls no neighbour: the
    # others are refined as if the frame were not there at all (a gap in the frame
    # numbers breaks the chain the same way).
    without = refine_track(results[:20] + results[21:], rotation_sigma=0.02)
    others = out.frames[:20] + out.frames[21:]
    for a, b in zip(others, without.frames, strict=True):
        np.testing.assert_allclose(a.R, b.R, atol=1e-6)
        np.testing.assert_allclose(a.t, b.t, atol=1e-6 * np.linalg.norm(b.t))
    rot, _ = _errors(out.frames, Rs, ts)
    assert rot[20] > 1.0 and np.all(rot[np.arange(40) != 20] < 0.5)
    # nothing to refine: fewer than three frames with a pose
    few = refine_track(results[:2])
    assert few.frames == results[:2] and few.iterations == 0


def test_bad_arguments(tracked):
    results = tracked[0][:5]
    with pytest.raises(ValueError, match="frames"):
        refine_track([(np.eye(3), np.zeros(3))])
    with pytest.raises(ValueError, match="rotation_sigma"):
        refine_track(results, rotation_sigma=0.0)
    with pytest.raises(ValueError, match="translation_sigma"):
        refine_track(results, translation_sigma=float("nan"))
    with pytest.raises(ValueError, match="iterations"):
        refine_track(results, iterations=0)
    with pytest.raises(ValueError, match="centre"):
        refine_track(results, centre=[0.0, np.inf, 0.0])


def test_a_frame_without_weight_gives_no_nan(tracked):
    results = list(tracked[0][:12])
    rows = results[5].rows
    results[5] = results[5]._replace(rows=rows._replace(weights=np.zeros_like(rows.weights)))
    out = refine_track(results)
    for f in out.frames:
        assert np.all(np.isfinite(f.R)) and np.all(np.isfinite(f.t)) and np.isfinite(f.rms)
    assert np.isfinite(out.cost_before) and np.isfinite(out.cost_after)
    bad = list(results)
    bad[3] = bad[3]._replace(t=np.array([0.0, np.nan, 80.0]))
    with pytest.raises(ValueError, match="frames"):
        refine_track(bad)


def _frames_on(Rs, ts, rows):
    """`TrackedFrame`s with the poses `(Rs, ts)`, each keeping `rows`."""
    from jaxpose.apps import TrackedFrame

    return [TrackedFrame(i, R, t, True, 1, 0, 0.0, "tracked", 0.0, rows)
            for i, (R, t) in enumerate(zip(Rs, ts, strict=True))]  # fmt: skip


def test_motion_sigmas_find_the_spread_of_the_motion(tracked):
    # A turn whose velocity takes Gaussian steps of 0.4 degree per axis: found. A centre
    # that only jitters about a fixed place (Gaussian, 0.001 of the distance per axis):
    # its second differences spread sqrt(6) times as much, as the estimate says (the
    # tracker's noise counts as motion: the prior is never stiffer than the track).
    results = tracked[0]
    rng = np.random.default_rng(7)
    rows = results[0].rows
    w, R = np.zeros(3), np.eye(3)
    Rs, ts = [], []
    for _ in range(400):
        w = w + np.radians(0.4) * rng.standard_normal(3)
        R = cv2.Rodrigues(w)[0] @ R
        Rs.append(R)
        ts.append(np.array([0.0, 0.0, 100.0]) + 0.1 * rng.standard_normal(3))
    centre = np.zeros(3)
    rot, move = motion_sigmas(_frames_on(Rs, ts, rows), centre)
    assert 0.32 < rot < 0.48
    assert 0.8 * np.sqrt(6) * 1e-3 < move < 1.2 * np.sqrt(6) * 1e-3
    # Fewer than three frames with a pose: the fallback; a lost frame breaks the triples.
    assert motion_sigmas(_frames_on(Rs[:2], ts[:2], rows), centre) == (0.05, 2e-4)
    frames = _frames_on(Rs[:3], ts[:3], rows)
    frames[1] = frames[1]._replace(ok=False)
    assert motion_sigmas(frames, centre) == (0.05, 2e-4)


def test_the_default_prior_follows_a_fast_turn():
    # 20 degrees over 20 frames (second differences up to about 2 degrees): the prior
    # taken from the track keeps the tracker's accuracy, a fixed 0.05 degree pulls the
    # trajectory off the turns.
    frames, Rs, ts = _sequence(20, seed=1, noise=2.0, shades=SHADES)
    results = list(
        track(frames, GEO, K, None, (Rs[0], ts[0]), options=TrackOptions(use_points=False))
    )
    assert all(r.ok for r in results)
    auto = refine_track(results)
    assert auto.rotation_sigma > 0.2
    stiff = refine_track(results, rotation_sigma=0.05, translation_sigma=2e-4)
    rot0, _ = _errors(results, Rs, ts)
    rot1, _ = _errors(auto.frames, Rs, ts)
    rot2, _ = _errors(stiff.frames, Rs, ts)
    assert rot1.mean() <= rot0.mean() * 1.1 and rot1.max() <= rot0.max() * 1.1
    assert rot2.max() > 1.5 * rot1.max()
    print(f"mean/max rotation error: tracked {rot0.mean():.3f}/{rot0.max():.3f}, refined "
          f"from the track ({auto.rotation_sigma:.2f} deg) {rot1.mean():.3f}/{rot1.max():.3f}, "
          f"0.05 deg {rot2.mean():.3f}/{rot2.max():.3f}")  # fmt: skip
