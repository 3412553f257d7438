"""Tests of jaxpose.features._klt on rendered textured boxes: corners found on the
visible faces, tracked to where the known motion takes them, their 3D points on the
mesh."""

import cv2
import numpy as np
import pytest

from jaxpose.apps import (
    cast_rays,
    face_mask,
    mesh_geometry,
    noise_texture,
    read_ply,
    render,
    sample_path,
)
from jaxpose.features import detect_corners, track_points

BOX = read_ply(sample_path("opencv_pose_box", "box.ply"))
GEO = mesh_geometry(BOX)
K = np.array([[800.0, 0.0, 320.0], [0.0, 800.0, 240.0], [0.0, 0.0, 1.0]])
SIZE = (640, 480)
TEXTURE = noise_texture(256, feature=3.0, seed=7)


def _poses(rotation, translation):
    R0 = cv2.Rodrigues(np.array([2.2, -0.6, 0.4]))[0]
    centre = BOX.vertices.mean(axis=0)
    t0 = np.array([0.0, 0.0, 80.0]) - R0 @ centre
    dR = cv2.Rodrigues(np.asarray(rotation, float))[0]
    R1 = dR @ R0
    return (R0, t0), (R1, R0 @ centre + t0 - R1 @ centre + np.asarray(translation, float))


def _draw(pose, **options):
    return render(
        GEO,
        K,
        None,
        *pose,
        SIZE,
        texture=TEXTURE,
        texture_scale=0.05,
        background=40,
        supersample=4,
        **options,
    )


@pytest.mark.parametrize("noise", [0.0, 2.0])
def test_tracks_follow_the_known_motion(noise):
    p0, p1 = _poses([0.012, -0.01, 0.015], [0.3, -0.2, 0.8])
    a, b = _draw(p0), _draw(p1, noise=noise, rng=np.random.default_rng(2))
    region = face_mask(GEO, K, None, *p0, SIZE, erode=6)
    corners = detect_corners(a, region, max_corners=200)
    assert 150 <= len(corners) <= 200
    iy, ix = np.round(corners[:, 1]).astype(int), np.round(corners[:, 0]).astype(int)
    assert np.all(region[iy, ix] > 0)
    # Their 3D points lie on the mesh and project back onto them.
    hits = cast_rays(GEO, K, None, *p0, corners)
    assert hits.hit.all()
    size = np.ptp(BOX.vertices, axis=0).max()
    plane = (GEO.normals[hits.face] * hits.points).sum(1) - GEO.offsets[hits.face]
    assert np.abs(plane).max() <= 1e-6 * size
    # Tracked to where the motion takes those 3D points.
    tracks = track_points(a, b, corners)
    expected, _ = cv2.projectPoints(hits.points, cv2.Rodrigues(p1[0])[0], p1[1], K, None)
    error = np.linalg.norm(tracks.points - expected.reshape(-1, 2), axis=1)[tracks.valid]
    assert tracks.valid.mean() > 0.9
    assert np.median(error) < (0.05 if noise == 0 else 0.1)
    assert np.percentile(error, 95) < 0.3
    assert np.all(tracks.fb_error[tracks.valid] <= 1.0)


def test_forward_backward_rejects_occluded_points():
    p0, p1 = _poses([0.0, 0.0, 0.0], [0.2, 0.1, 0.0])
    a = _draw(p0)
    box = (250, 180, 330, 260)
    b = _draw(p1, occluder=box, occluder_grey=128, noise=1.0)
    corners = detect_corners(a, face_mask(GEO, K, None, *p0, SIZE, erode=6), max_corners=300)
    tracks = track_points(a, b, corners, fb_threshold=0.5)
    under = (
        (corners[:, 0] > box[0] + 12)
        & (corners[:, 0] < box[2] - 12)
        & (corners[:, 1] > box[1] + 12)
        & (corners[:, 1] < box[3] - 12)
    )
    assert under.sum() >= 5 and not tracks.valid[under].any()
    assert tracks.valid[~under].mean() > 0.8
    np.testing.assert_array_equal(tracks.points[~tracks.valid], corners[~tracks.valid])


def test_points_on_noise_alone_are_refused_by_their_correlation():
    # A plain face (grey 150 on 40, no texture: its only corners are the noise, sigma 2,
    # drawn afresh on each frame) moved 4 px right and 3 down: the flow cannot follow
    # such points; many pass the forward-backward check and lie pixels from where the
    # motion takes them. Their patches do not correlate from frame to frame; a textured
    # box's do, and are kept.
    rng = np.random.default_rng(4)

    def plain(x0, y0):
        image = np.full((240, 320), 40.0)
        image[y0 : y0 + 150, x0 : x0 + 200] = 150.0
        return np.clip(np.round(image + rng.normal(0.0, 2.0, image.shape)), 0, 255).astype(np.uint8)

    a, b = plain(50, 40), plain(54, 43)
    inside = np.zeros((240, 320), np.uint8)
    inside[50:180, 60:240] = 255  # (the face, 10 px in from its borders)
    corners = detect_corners(a, inside, max_corners=100)
    followed = track_points(a, b, corners)
    error = np.linalg.norm(followed.points - (corners + [4.0, 3.0]), axis=1)
    assert len(corners) >= 50 and followed.valid.mean() > 0.3
    assert np.median(error[followed.valid]) > 1.0  # (the textured box: 0.1)
    checked = track_points(a, b, corners, min_correlation=0.5)
    assert checked.valid.mean() < 0.05
    assert np.all(checked.correlation[checked.valid] >= 0.5)
    assert np.percentile(checked.correlation[followed.valid], 90) < 0.5
    assert followed.correlation is None
    # The textured box's points correlate (about 1) and are kept.
    p0, p1 = _poses([0.012, -0.01, 0.015], [0.3, -0.2, 0.8])
    t0, t1 = _draw(p0), _draw(p1, noise=2.0, rng=np.random.default_rng(3))
    corners = detect_corners(t0, face_mask(GEO, K, None, *p0, SIZE, erode=6), max_corners=200)
    kept = track_points(t0, t1, corners, min_correlation=0.5)
    base = track_points(t0, t1, corners)
    assert kept.valid.sum() >= 0.95 * base.valid.sum()
    assert np.median(kept.correlation[kept.valid]) > 0.9


def test_top_up_avoids_existing_tracks():
    p0, _ = _poses([0, 0, 0], [0, 0, 0])
    a = _draw(p0)
    region = face_mask(GEO, K, None, *p0, SIZE, erode=6)
    first = detect_corners(a, region, max_corners=40, min_distance=10)
    more = detect_corners(a, region, max_corners=80, min_distance=10, existing=first)
    gaps = np.linalg.norm(more[:, None] - first[None], axis=2).min(axis=1)
    assert len(more) > 0 and gaps.min() > 9


def test_bad_arguments():
    image = np.zeros((40, 50), np.uint8)
    with pytest.raises(ValueError, match="image"):
        detect_corners(np.zeros(3), None)
    with pytest.raises(ValueError, match="mask"):
        detect_corners(image, np.ones((4, 4)))
    with pytest.raises(ValueError, match="max_corners"):
        detect_corners(image, max_corners=0)
    with pytest.raises(ValueError, match="current"):
        track_points(image, np.zeros((10, 10), np.uint8), np.zeros((1, 2)))
    with pytest.raises(ValueError, match="points"):
        track_points(image, image, np.full((1, 2), np.nan))
    with pytest.raises(ValueError, match="window"):
        track_points(image, image, np.zeros((1, 2)), window=4)
    with pytest.raises(ValueError, match="min_correlation"):
        track_points(image, image, np.zeros((1, 2)), min_correlation=1.5)
    with pytest.raises(ValueError, match="patch"):
        track_points(image, image, np.zeros((1, 2)), min_correlation=0.5, patch=4)
    assert detect_corners(image, np.zeros((40, 50), bool)).shape == (0, 2)
    empty = track_points(image, image, np.zeros((0, 2)))
    assert empty.points.shape == (0, 2) and empty.valid.shape == (0,)
