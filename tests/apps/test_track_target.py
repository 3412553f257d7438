"""A clicked point followed through tracked poses (`jaxpose.apps.anchor_click`,
`follow_anchor`, `follow_click`): the click's model point found exactly, carried by each
pose to its camera-frame position and pixel, out of sight where a face hides it or faces
away, nothing on frames without a pose; bad arguments refused by name."""

import cv2
import numpy as np
import pytest

from jaxpose.apps import (
    Anchor,
    TrackedFrame,
    anchor_click,
    follow_anchor,
    follow_click,
    read_ply,
    sample_path,
)

BOX = read_ply(sample_path("opencv_pose_box") / "box.ply")
K = np.array([[600.0, 0.0, 240.0], [0.0, 600.0, 180.0], [0.0, 0.0, 1.0]])
DIST = np.array([-0.12, 0.05, 0.001, -0.002, 0.0])
CENTRE = BOX.vertices.mean(axis=0)
R0 = cv2.Rodrigues(np.array([2.2, -0.6, 0.4]))[0]
T0 = np.array([0.0, 0.0, 80.0]) - R0 @ CENTRE


def _pixel(m, R, t, dist=None):
    return cv2.projectPoints(m.reshape(1, 3), cv2.Rodrigues(R)[0], t, K, dist)[0].reshape(2)


def _front_faces(R, t):
    """The faces turned to the camera at `(R, t)`, with their centres (model frame)."""
    out = []
    for i, face in enumerate(BOX.faces):
        corners = BOX.vertices[list(face)]
        normal = np.cross(corners[1] - corners[0], corners[2] - corners[0])
        centre = corners.mean(axis=0)
        if (R @ normal) @ (R @ centre + t) < 0:
            out.append((i, centre))
    return out


def _turned(angle_deg, axis=(0.3, 1.0, 0.2)):
    """The box turned about its centre by `angle_deg` (from the first pose)."""
    axis = np.asarray(axis) / np.linalg.norm(axis)
    dR = cv2.Rodrigues(np.radians(angle_deg) * axis)[0]
    R = dR @ R0
    return R, R0 @ CENTRE + T0 - R @ CENTRE


@pytest.mark.parametrize("dist", [None, DIST], ids=["pinhole", "distorted"])
def test_a_click_is_the_model_point_under_it_and_follows_the_pose(dist):
    faces = _front_faces(R0, T0)
    assert len(faces) >= 2
    R1, t1 = _turned(12.0)
    for index, centre in faces:
        click = _pixel(centre, R0, T0, dist)
        anchor = anchor_click(BOX, K, dist, R0, T0, click, frame=3)
        assert anchor is not None and anchor.face == index and anchor.frame == 3
        np.testing.assert_allclose(anchor.point, centre, atol=1e-9)
        here = follow_anchor(anchor, BOX, K, dist, R0, T0, frame=3)
        assert here.visible
        np.testing.assert_allclose(here.pixel, click, atol=1e-6)
        there = follow_anchor(anchor, BOX, K, dist, R1, t1, frame=4)
        np.testing.assert_allclose(there.point, R1 @ centre + t1, atol=1e-9)
        np.testing.assert_allclose(there.pixel, _pixel(centre, R1, t1, dist), atol=1e-6)
        assert there.frame == 4


def test_a_point_turned_away_or_behind_the_camera_is_out_of_sight():
    index, centre = _front_faces(R0, T0)[0]
    anchor = anchor_click(BOX, K, None, R0, T0, _pixel(centre, R0, T0))
    R1, t1 = _turned(180.0)  # its face now turned away, other faces in front of it
    assert index not in [i for i, _ in _front_faces(R1, t1)]
    away = follow_anchor(anchor, BOX, K, None, R1, t1, frame=1)
    assert not away.visible and away.point[2] > 0
    behind = follow_anchor(anchor, BOX, K, None, R0, T0 - [0.0, 0.0, 200.0], frame=2)
    assert not behind.visible and behind.point[2] < 0
    assert np.all(np.isfinite(behind.pixel))


def test_a_click_beside_the_object_anchors_nothing():
    assert anchor_click(BOX, K, None, R0, T0, (2.0, 2.0)) is None
    frames = [TrackedFrame(i, R0, T0, True, 50, 20, 0.5, "tracked") for i in range(3)]
    out = list(follow_click(iter(frames), BOX, K, None, (0, 2.0, 2.0)))
    assert [(a, t) for _, a, t in out] == [(None, None)] * 3


def test_follow_click_anchors_on_the_first_posed_frame_and_skips_lost_ones():
    index, centre = _front_faces(R0, T0)[0]
    R1, t1 = _turned(6.0)
    poses = [(R0, T0)] * 3 + [(R1, t1)] * 3
    ok = [True, False, True, True, False, True]
    frames = [TrackedFrame(i, R, t, k, 50, 20, 0.5, "tracked" if k else "lost")
              for i, ((R, t), k) in enumerate(zip(poses, ok, strict=True))]  # fmt: skip
    click = _pixel(centre, R0, T0)
    out = list(follow_click(frames, BOX, K, None, (1, *click)))
    anchors = [a for _, a, _ in out]
    targets = [t for _, _, t in out]
    assert anchors[:2] == [None, None] and all(isinstance(a, Anchor) for a in anchors[2:])
    assert anchors[2].frame == 2 and anchors[2].face == index
    assert [t is None for t in targets] == [True, True, False, False, True, False]
    for r, _, target in out:
        if target is not None:
            assert target.frame == r.frame
            np.testing.assert_allclose(target.point, r.R @ centre + r.t, atol=1e-9)


@pytest.mark.parametrize(
    ("call", "name"),
    [
        (lambda: anchor_click(BOX, K, None, R0, T0, (np.nan, 3.0)), "pixel"),
        (lambda: anchor_click(BOX, K, None, R0, T0, (1.0, 2.0, 3.0)), "pixel"),
        (lambda: anchor_click(BOX.vertices, K, None, R0, T0, (1.0, 2.0)), "model"),
        (lambda: anchor_click(BOX, K[:2], None, R0, T0, (1.0, 2.0)), "K"),
        (lambda: anchor_click(BOX, K, [0.1, 0.2], R0, T0, (1.0, 2.0)), "dist"),
        (lambda: anchor_click(BOX, K, None, R0[:2], T0, (1.0, 2.0)), "R must"),
        (lambda: anchor_click(BOX, K, None, R0, T0[:2], (1.0, 2.0)), "t must"),
        (lambda: follow_anchor((1, 2), BOX, K, None, R0, T0, frame=0), "anchor"),
        (lambda: follow_click([], BOX, K, None, (0, 1.0)), "click"),
        (lambda: follow_click([], BOX, K, None, (-1, 1.0, 2.0)), "click"),
        (lambda: follow_click([], BOX, K, None, (0, 1.0, np.inf)), "pixel"),
    ],
)
def test_bad_arguments_are_refused_by_name(call, name):
    with pytest.raises(ValueError, match=name):
        call()


def test_the_target_covariance_carries_the_pose_covariance():
    # Poses drawn from a pose covariance (w, dt): the followed point's spread is the
    # target's covariance.
    index, centre = _front_faces(R0, T0)[0]
    anchor = anchor_click(BOX, K, None, R0, T0, _pixel(centre, R0, T0))
    rng = np.random.default_rng(5)
    L = rng.normal(size=(6, 6)) * np.array([2e-3] * 3 + [0.05] * 3)[:, None]
    pose_cov = L @ L.T
    target = follow_anchor(anchor, BOX, K, None, R0, T0, frame=0, pose_covariance=pose_cov)
    draws = rng.multivariate_normal(np.zeros(6), pose_cov, size=4000)
    points = [cv2.Rodrigues(d[:3])[0] @ R0 @ anchor.point + T0 + d[3:] for d in draws]
    np.testing.assert_allclose(target.covariance, np.cov(np.array(points).T), rtol=0.1,
                               atol=0.02 * np.max(np.diag(target.covariance)))  # fmt: skip
    assert follow_anchor(anchor, BOX, K, None, R0, T0, frame=0).covariance is None
    with pytest.raises(ValueError, match="pose_covariance"):
        follow_anchor(anchor, BOX, K, None, R0, T0, frame=0, pose_covariance=np.eye(3))
