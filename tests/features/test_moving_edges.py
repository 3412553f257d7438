"""Tests of jaxpose.features._moving_edges on rendered images: the edges of a box found
after a known small motion, to a fraction of a pixel."""

import cv2
import numpy as np
import pytest

from jaxpose.apps import edge_samples, read_ply, render, sample_path
from jaxpose.features import moving_edges

BOX = read_ply(sample_path("opencv_pose_box", "box.ply"))
K = np.array([[800.0, 0.0, 320.0], [0.0, 800.0, 240.0], [0.0, 0.0, 1.0]])
SIZE = (640, 480)
SHADES = np.array([200.0, 90.0, 150.0, 240.0, 120.0, 60.0])  # one grey level per face


def _pose(rvec, centre_at):
    R = cv2.Rodrigues(np.asarray(rvec, float))[0]
    return R, np.asarray(centre_at, float) - R @ BOX.vertices.mean(axis=0)


def _expected_offsets(samples, R, t):
    """Signed distances, along each sample's normal, from the sample to its edge projected
    at pose (R, t)."""
    edges = np.asarray(BOX.edges)[samples.edge]
    ends, _ = cv2.projectPoints(BOX.vertices, cv2.Rodrigues(R)[0], t, K, None)
    ends = ends.reshape(-1, 2)
    a, b = ends[edges[:, 0]], ends[edges[:, 1]]
    d = (b - a) / np.linalg.norm(b - a, axis=1, keepdims=True)
    line_normal = np.column_stack([-d[:, 1], d[:, 0]])
    # The point p + s n on the line through a with normal m: m . (p + s n - a) = 0.
    m, n, p = line_normal, samples.normals, samples.pixels
    return (m * (a - p)).sum(1) / (m * n).sum(1)


@pytest.mark.parametrize(
    "motion, noise, blur",
    [
        (([0, 0, 0], [0, 0, 0]), 0.0, 0.0),
        (([0.01, -0.008, 0.012], [0.25, -0.18, 0.6]), 0.0, 0.0),
        (([-0.015, 0.01, -0.02], [-0.3, 0.2, -0.8]), 3.0, 0.8),
    ],
)
def test_box_edges_after_a_small_motion(motion, noise, blur):
    R0, t0 = _pose([2.2, -0.6, 0.4], [0.0, 0.0, 80.0])
    dR = cv2.Rodrigues(np.asarray(motion[0], float))[0]
    centre = BOX.vertices.mean(axis=0)  # turned about the box's centre, then moved
    R1 = dR @ R0
    t1 = R0 @ centre + t0 - R1 @ centre + np.asarray(motion[1], float)
    image = render(
        BOX,
        K,
        None,
        R1,
        t1,
        SIZE,
        shades=SHADES,
        background=20,
        noise=noise,
        blur=blur,
        supersample=8,
        rng=np.random.default_rng(1),
    )
    samples = edge_samples(BOX, K, None, R0, t0, spacing=6.0, image_size=SIZE)
    expected = _expected_offsets(samples, R1, t1)
    assert np.abs(expected[samples.visible]).max() > (1.0 if any(motion[1]) else -1)
    found = moving_edges(
        image, samples.pixels, samples.normals, search=10, threshold=8.0, mask=samples.visible
    )
    ok = found.valid
    assert ok.sum() >= 0.9 * samples.visible.sum()
    error = found.offset[ok] - expected[ok]
    # Sub-pixel, but for a few samples near corners, where another edge is in range.
    assert np.median(np.abs(error)) < (0.05 if noise == 0 else 0.1)
    assert np.percentile(np.abs(error), 90) < (0.15 if noise == 0 else 0.3)
    np.testing.assert_allclose(found.matched, found.points + found.offset[:, None] * found.normals)
    assert np.all(found.offset[~ok] == 0) and np.all(found.strength[~ok] == 0)
    assert np.all(np.isfinite(found.matched))
    # The signs found again on the next frame with contrast keep the same matches.
    again = moving_edges(
        image,
        samples.pixels,
        samples.normals,
        search=10,
        threshold=8.0,
        mask=samples.visible,
        contrast=found.strength,
    )
    np.testing.assert_array_equal(again.valid[ok], True)
    np.testing.assert_allclose(again.offset[ok], found.offset[ok])


def test_contrast_picks_the_edge_of_the_expected_sign():
    image = np.full((60, 80), 50, np.uint8)
    image[:, 30:36] = 200  # rising edge at x = 29.5, falling edge at x = 35.5
    image[:, 36:] = 120
    points = np.array([[33.0, 20.0], [33.0, 40.0]])
    normals = np.array([[1.0, 0.0], [2.0, 0.0]])  # normalised inside
    plain = moving_edges(image, points, normals, search=6)
    np.testing.assert_allclose(plain.matched[:, 0], 29.5)  # the stronger, rising edge
    assert np.all(plain.strength > 0)
    falling = moving_edges(image, points, normals, search=6, contrast=[-1.0, -5.0])
    np.testing.assert_allclose(falling.matched[:, 0], 35.5)
    np.testing.assert_allclose(falling.strength, -40.0)  # a sharp step read bilinearly
    # The size of the contrast too: a rising edge of 75 per pixel, not of 20.
    sized = moving_edges(image, points, normals, search=6, contrast=[75.0, 60.0], ratio=1.5)
    np.testing.assert_allclose(sized.matched[:, 0], 29.5)
    weak = moving_edges(image, points, normals, search=6, contrast=[20.0, 20.0], ratio=1.5)
    assert not weak.valid.any()
    # The nearest edge rather than the strongest: from x = 34, the falling one.
    closer = points + [1.0, 0.0]
    strongest = moving_edges(image, closer, normals, search=6)
    np.testing.assert_allclose(strongest.matched[:, 0], 29.5)
    nearest = moving_edges(image, closer, normals, search=6, choose="nearest")
    np.testing.assert_allclose(nearest.matched[:, 0], 35.5)
    # An edge along the normal gives no response; a search line leaving the image, none.
    along = moving_edges(image, points, [[0.0, 1.0], [0.0, 1.0]], search=6)
    assert not along.valid.any()
    out = moving_edges(image, [[2.0, 20.0]], [[1.0, 0.0]], search=6)
    assert not out.valid[0] and out.offset[0] == 0


def test_a_smeared_edge_is_found_at_its_middle():
    # A step smeared by motion over 6 px (a ramp over x = 26.5 to 32.5 in OpenCV's pixel
    # centres, the edge at mid-exposure at x = 29.5) with noise: its derivative is a
    # plateau; the match is the plateau's centre, where the peak alone lands anywhere
    # along it.
    rng = np.random.default_rng(3)
    x = np.arange(80, dtype=np.float64)
    ramp = np.clip((x + 0.5 - 27.0) / 6.0, 0.0, 1.0)  # each pixel's covered fraction
    image = 40.0 + 120.0 * np.tile(ramp, (60, 1)) + rng.normal(0.0, 2.0, (60, 80))
    points = np.column_stack([np.full(20, 31.3), np.linspace(8, 52, 20)])
    normals = np.tile([1.0, 0.0], (20, 1))
    found = moving_edges(image, points, normals, search=8, threshold=8.0)
    assert found.valid.all()
    np.testing.assert_allclose(found.matched[:, 0], 29.5, atol=0.15)
    # cut by the end of a shorter range, the lobe gives no match
    cut = moving_edges(image, points + [2.0, 0.0], normals, search=4, threshold=8.0)
    assert not cut.valid.any()
    # Smeared over 8 px, a step of 60 rises 7.5 a pixel, below the threshold of 8: the
    # lobe's step (60 >= 3 x 8) makes it a match; the same slope over 2 px is none.
    ramp = np.clip((x + 0.5 - 26.0) / 8.0, 0.0, 1.0)
    smeared = 40.0 + 60.0 * np.tile(ramp, (60, 1)) + rng.normal(0.0, 0.5, (60, 80))
    found = moving_edges(smeared, points, normals, search=8, threshold=8.0)
    assert found.valid.all()
    np.testing.assert_allclose(found.matched[:, 0], 29.5, atol=0.25)
    short = np.clip((x + 0.5 - 29.0) / 2.0, 0.0, 1.0)
    faint = 40.0 + 15.0 * np.tile(short, (60, 1))
    assert not moving_edges(faint, points, normals, search=8, threshold=8.0).valid.any()
    # Two rising edges 3.5 px apart (a printed border beside an outline), blurred: the
    # derivative between them stays above the lobe's floor, and the lobe stops where it
    # rises again, so the match is the stronger edge; without that stop, between them.
    two = np.full((60, 80), 40.0)
    two[:, 30:] += 100.0
    two[:, 34:] += 60.0  # (a step between pixels 29 | 30 and 33 | 34, blurred below)
    two = cv2.GaussianBlur(two, (0, 0), 1.0)
    at = (np.column_stack([np.full(20, 30.3), np.linspace(8, 52, 20)]), normals)
    found = moving_edges(two, *at, search=8, threshold=8.0)
    np.testing.assert_allclose(found.matched[:, 0], 29.5, atol=0.35)  # (measured: 29.78)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr("jaxpose.features._moving_edges._LOBE_RISE", np.inf)
        merged = moving_edges(two, *at, search=8, threshold=8.0)
    assert np.all(merged.matched[:, 0] > 30.5)  # (measured: 30.73)


def test_a_ramp_of_the_known_smear_is_found_at_its_middle():
    # A step of 60 smeared over 8 px (the middle at x = 29.0) under noise of sigma 3: the
    # derivative's plateau (7.5 a pixel) is broken into pieces, each taken for the edge
    # (90% within 2.3 px, the worst 3.1: measured); the step over a box of the smear's
    # width puts it at the ramp's middle (0.22 px, the worst 0.41).
    rng = np.random.default_rng(5)
    x = np.arange(80, dtype=np.float64)
    ramp = np.clip((x + 0.5 - 25.5) / 8.0, 0.0, 1.0)
    image = 40.0 + 60.0 * np.tile(ramp, (200, 1)) + rng.normal(0.0, 3.0, (200, 80))
    points = np.column_stack([np.full(40, 31.3), np.linspace(8, 190, 40)])
    normals = np.tile([1.0, 0.0], (40, 1))
    plain = moving_edges(image, points, normals, search=8, threshold=8.0)
    found = moving_edges(image, points, normals, search=8, threshold=8.0, smear=np.full(40, 8.0))
    assert found.valid.all()
    assert np.abs(found.matched[:, 0] - 29.0).max() < 0.5
    assert np.percentile(np.abs(plain.matched[plain.valid, 0] - 29.0), 90) > 1.5
    np.testing.assert_allclose(np.median(found.strength), 60.0 / 9, rtol=0.1)  # (mean slope)
    # A sharp step where the smear was predicted: the frame shows no ramps, as without it.
    sharp = 40.0 + 60.0 * (np.tile(x, (200, 1)) >= 30) + rng.normal(0.0, 3.0, (200, 80))
    a = moving_edges(sharp, points, normals, search=8, threshold=8.0)
    b = moving_edges(sharp, points, normals, search=8, threshold=8.0, smear=np.full(40, 8.0))
    np.testing.assert_array_equal(a.matched, b.matched)
    np.testing.assert_array_equal(a.valid, b.valid)


def test_a_blurred_frame_flags_another_edge_on_the_line_as_a_rival():
    # The ramp of the test above (a step of 60 smeared over 8 px, the middle at 29.0)
    # alone, then with a dark printed line (30 grey levels, 2 px wide) 11 px past its
    # middle on the lower half of the samples, past the search range: on the blurred
    # frame, `rival` flags those when it looks that far (`reach`), and no other; the
    # matches are the same; a sharp frame flags none.
    rng = np.random.default_rng(5)
    x = np.arange(80, dtype=np.float64)
    ramp = 40.0 + 60.0 * np.clip((x + 0.5 - 25.5) / 8.0, 0.0, 1.0)
    image = np.tile(ramp, (200, 1)) + rng.normal(0.0, 3.0, (200, 80))
    image[100:, 40:42] -= 30.0
    points = np.column_stack([np.full(40, 31.3), np.linspace(8, 190, 40)])
    normals = np.tile([1.0, 0.0], (40, 1))
    lined = points[:, 1] + 1 >= 100  # (read a pixel either side along the edge)
    smear = np.full(40, 8.0)
    near = moving_edges(image, points, normals, search=8, threshold=8.0, smear=smear)
    far = moving_edges(image, points, normals, search=8, threshold=8.0, smear=smear, reach=14)
    assert near.blurred and far.blurred and far.valid.all()
    np.testing.assert_array_equal(near.matched, far.matched)  # (the matches unchanged)
    np.testing.assert_array_equal(far.rival, lined)
    assert not np.any(near.rival)
    # Where another edge of the model is predicted there (the line's edges at 9.2 and
    # 11.2 px, predicted at 10.2), the line is no rival.
    model = moving_edges(image, points, normals, search=8, threshold=8.0, smear=smear, reach=14,
                         others=np.full((40, 1), 10.2))  # fmt: skip
    assert not np.any(model.rival)
    sharp = moving_edges(image, points, normals, search=8, threshold=8.0, reach=14)
    assert not sharp.blurred and not np.any(sharp.rival)


def test_a_smear_wider_than_the_image_reads_no_further():
    # A smear from a pose gone far off (a tracker's wild solve: billions of pixels) is
    # taken as the image's width: the call returns, as fast as with that smear, and the
    # one sample so smeared gives the same answer as at the image's width.
    rng = np.random.default_rng(2)
    image = 40.0 + 60.0 * (np.tile(np.arange(80.0), (60, 1)) >= 30) + rng.normal(0, 1, (60, 80))
    points = np.column_stack([np.full(6, 31.3), np.linspace(10, 50, 6)])
    normals = np.tile([1.0, 0.0], (6, 1))
    wild = np.array([1.0, 1.0, 1.0, 1.0, 1.0, 3e12])
    a = moving_edges(image, points, normals, search=8, threshold=8.0, smear=wild)
    b = moving_edges(image, points, normals, search=8, threshold=8.0,
                     smear=np.minimum(wild, 80.0))  # fmt: skip
    np.testing.assert_array_equal(a.matched, b.matched)
    np.testing.assert_array_equal(a.valid, b.valid)
    assert a.valid[:5].all() and np.abs(a.matched[:5, 0] - 29.5).max() < 0.3


def test_a_video_sized_image():
    # 400 samples on a 640 x 480 image (`benchmarks/frontend.py` times it)
    rng = np.random.default_rng(0)
    image = cv2.GaussianBlur(rng.uniform(0, 255, (480, 640)).astype(np.uint8), (0, 0), 2)
    points = rng.uniform(40, 400, (400, 2))
    angle = rng.uniform(0, np.pi, 400)
    normals = np.column_stack([np.cos(angle), np.sin(angle)])
    found = moving_edges(image, points, normals, search=10)
    assert found.matched.shape == (400, 2) and np.all(np.isfinite(found.matched))
    assert found.valid.any() and np.all(np.abs(found.offset) <= 10)


def test_limits_keep_a_sample_to_its_own_edge():
    # A sliver: a face of 200, a face of 240 three pixels wide, the background at 40; the
    # crease (x = 29.5, +40) and the outline (x = 32.5, -200). The crease's sample, at it,
    # takes the stronger outline; limited to half the way to the outline's predicted
    # place (+1.5 px), the crease.
    image = np.full((60, 80), 200, np.uint8)
    image[:, 30:33] = 240
    image[:, 33:] = 40
    points = np.array([[29.5, 20.0], [29.5, 40.0]])
    normals = np.tile([1.0, 0.0], (2, 1))
    plain = moving_edges(image, points, normals, search=6)
    np.testing.assert_allclose(plain.matched[:, 0], 32.5)
    limits = np.array([[-np.inf, 1.5], [-np.inf, 1.5]])
    own = moving_edges(image, points, normals, search=6, limits=limits)
    np.testing.assert_allclose(own.matched[:, 0], 29.5)
    np.testing.assert_allclose(own.strength, 40.0)
    # The outline's sample (at 32.5, the crease predicted 3 px before it) keeps the outline.
    outline = moving_edges(image, points + [3.0, 0.0], normals, search=6,
                           limits=[[-1.5, np.inf]] * 2)  # fmt: skip
    np.testing.assert_allclose(outline.matched[:, 0], 32.5)
    # With nothing within its limits, no match.
    none = moving_edges(image, points, normals, search=6, limits=[[0.5, 2.0]] * 2)
    assert not none.valid.any()
    # A smeared ramp's box is held to the limits too: a second, stronger ramp 14 px
    # beyond the first is the match without them and out of reach with them.
    x = np.arange(80, dtype=np.float64)
    ramps = 40 + 40 * np.clip((x - 22) / 6, 0, 1) + 100 * np.clip((x - 36) / 6, 0, 1)
    rng = np.random.default_rng(2)
    image = np.tile(ramps, (200, 1)) + rng.normal(0.0, 1.0, (200, 80))
    points = np.column_stack([np.full(40, 28.0), np.linspace(8, 190, 40)])
    normals = np.tile([1.0, 0.0], (40, 1))
    smear = np.full(40, 6.0)
    free = moving_edges(image, points, normals, search=16, smear=smear)
    held = moving_edges(image, points, normals, search=16, smear=smear,
                        limits=np.tile([-np.inf, 6.0], (40, 1)))  # fmt: skip
    assert free.blurred and held.blurred
    assert free.valid.mean() > 0.9 and held.valid.mean() > 0.9
    assert np.all(np.abs(free.matched[free.valid, 0] - 39.0) < 1.0)
    assert np.all(np.abs(held.matched[held.valid, 0] - 25.0) < 1.0)


def test_bad_arguments():
    image = np.zeros((20, 20), np.uint8)
    p, n = np.zeros((3, 2)), np.ones((3, 2))
    with pytest.raises(ValueError, match="image"):
        moving_edges(np.zeros(5), p, n)
    with pytest.raises(ValueError, match="image"):
        moving_edges(np.full((4, 4), np.nan), p, n)
    with pytest.raises(ValueError, match="points"):
        moving_edges(image, np.zeros((3, 3)), n)
    with pytest.raises(ValueError, match="normals"):
        moving_edges(image, p, np.ones((2, 2)))
    with pytest.raises(ValueError, match="search"):
        moving_edges(image, p, n, search=1)
    with pytest.raises(ValueError, match="contrast"):
        moving_edges(image, p, n, contrast=[1.0])
    with pytest.raises(ValueError, match="mask"):
        moving_edges(image, p, n, mask=[1, 0, 1])
    with pytest.raises(ValueError, match="ratio"):
        moving_edges(image, p, n, contrast=[1.0, 1.0, 1.0], ratio=0.5)
    with pytest.raises(ValueError, match="choose"):
        moving_edges(image, p, n, choose="best")
    with pytest.raises(ValueError, match="smear"):
        moving_edges(image, p, n, smear=[1.0, -1.0, 2.0])
    with pytest.raises(ValueError, match="limits"):
        moving_edges(image, p, n, limits=np.zeros((3, 3)))
    with pytest.raises(ValueError, match="limits"):
        moving_edges(image, p, n, limits=np.full((3, 2), np.nan))
    empty = moving_edges(image, np.zeros((0, 2)), np.zeros((0, 2)))
    assert empty.matched.shape == (0, 2) and empty.valid.shape == (0,)
