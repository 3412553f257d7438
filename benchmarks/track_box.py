"""jaxpose's tracker beside OpenCV's real-time pose tutorial on the cookie-box video
(issue #32): the same frames of `box.mp4` (640 x 480, 455 frames, decoded to grey
before any timing), the same camera (`box_video_camera.yml`, the tutorial's) and the
same textured model (`cookies_ORB.yml.gz`, the tutorial's ORB keypoints of the box).

Methods, each run on every frame:

- `jaxpose`: `jaxpose.apps.track` (moving edges and KLT points, the paper's
  small-movement linear method, compiled) from the pose `jaxpose.apps.locate_textured`
  finds in the first frame, with `recognition_reinit` (keypoints first) after a lost
  frame, as `jaxpose track --textured` runs it;
- `jaxpose_refined`: the same trajectory refined offline, all frames jointly
  (`jaxpose.apps.refine_track`: each frame's stored measurements plus a
  constant-velocity prior, default settings: its sigmas from the track,
  `refine_sigmas`); its rate counts the tracking and the
  refinement;
- `jaxpose_keypoints`: `jaxpose.apps.track` with `textured=` the same textured model:
  on every tracked frame its points are matched to the frame's ORB keypoints (500, in
  the model's predicted area) near their predicted projections (the 8 nearest within
  10 px; the nearest descriptor, at most 64 bits and under 0.9 times the second
  nearest's) and taken as point measurements beside the KLT points (Python API only);
- `opencv_pnp`: the tutorial's detection per frame, written here with OpenCV's calls:
  ORB keypoints (2,000) of the frame, FLANN's LSH index (6 tables, key size 12, multi-
  probe level 1) matched two-nearest to the model's descriptors, Lowe's ratio test
  (0.70), `cv2.solvePnPRansac` (iterative, 500 iterations, 6 px, confidence 0.99); a pose
  where at least 30 inliers agree (the tutorial's `minInliersKalman`), none otherwise;
- `opencv_kalman`: the same, then the tutorial's Kalman filter (18 states: position,
  Euler angles, their first and second derivatives, dt 0.125; process noise 1e-5,
  measurement noise 1e-2, initial error covariance 1, state starting at zero), predicted
  and corrected on every frame with the last good measurement; the filter's pose on
  every frame once a first measurement came.

Figures per method, over the frames it gives a pose on:

- `jitter`: between consecutive frames that both have a pose, the rotation (degrees)
  and the movement of the model's centre (mm; the mesh is in cm), median and 95th
  percentile (the box is moved by hand, so this is motion plus noise: the same motion
  for every method);
- `jitter_2nd`: over three consecutive frames with a pose, the change of that
  frame-to-frame motion (the second difference: the rotation vectors' and the centre's),
  median and 95th percentile: a smooth hand motion changes little from one frame to
  the next at 30 frames/s, noise does;
- `edge_distance_px`: per frame, the mean distance from the projected visible model
  edges (sampled every 2 px, hidden parts removed) to the nearest image edge (Canny,
  thresholds 40/120 after a 5 x 5 Gaussian blur, sigma 1.2; the distance transform read
  bilinearly); its mean and median over frames;
- `fps`: frames per second of the method's own per-frame work (decoding and the grey
  conversion excluded, both done beforehand), from the total time over all frames; the
  methods run alternately `--repeats` times (a shared machine's load moves) and each
  one's fastest run counts (every run's seconds are saved).

    python -m benchmarks.track_box [--frames 455] [--repeats 3]
        [--out benchmarks/results/track_box.json]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from ._harness import write_json

#: The tutorial's settings (OpenCV's `real_time_pose_estimation` sample, main_detection).
ORB_FEATURES = 2000
RATIO = 0.70
RANSAC = dict(iterationsCount=500, reprojectionError=6.0, confidence=0.99)
MIN_INLIERS = 30
KALMAN_DT = 0.125
CANNY = (40, 120)


def _euler(R: np.ndarray) -> np.ndarray:
    """(bank, attitude, heading) of `R = Ry(heading) Rz(attitude) Rx(bank)` (the
    tutorial's convention)."""
    if R[1, 0] > 0.998 or R[1, 0] < -0.998:
        return np.array([0.0, np.sign(R[1, 0]) * np.pi / 2, np.arctan2(R[0, 2], R[2, 2])])
    return np.array(
        [np.arctan2(-R[1, 2], R[1, 1]), np.arcsin(R[1, 0]), np.arctan2(-R[2, 0], R[0, 0])]
    )


def _from_euler(e: np.ndarray) -> np.ndarray:
    b, a, h = e
    Rx = np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
    Rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    Ry = np.array([[np.cos(h), 0, np.sin(h)], [0, 1, 0], [-np.sin(h), 0, np.cos(h)]])
    return Ry @ Rz @ Rx


def _kalman():
    """The tutorial's constant-acceleration filter on position and Euler angles."""
    import cv2

    kf = cv2.KalmanFilter(18, 6, 0, cv2.CV_64F)
    kf.processNoiseCov = np.eye(18) * 1e-5
    kf.measurementNoiseCov = np.eye(6) * 1e-2
    kf.errorCovPost = np.eye(18)
    F = np.eye(18)
    for base in (0, 9):
        for i in range(3):
            F[base + i, base + 3 + i] = KALMAN_DT
            F[base + 3 + i, base + 6 + i] = KALMAN_DT
            F[base + i, base + 6 + i] = 0.5 * KALMAN_DT**2
    kf.transitionMatrix = F
    H = np.zeros((6, 18))
    for row, col in enumerate((0, 1, 2, 9, 10, 11)):
        H[row, col] = 1.0
    kf.measurementMatrix = H
    return kf


def run_opencv(frames, textured, K, dist) -> tuple[list, list, float]:
    """The tutorial's pipeline on `frames`: per frame the measured pose (or None) and
    the Kalman filter's pose (or None before the first measurement), and the seconds
    spent in all."""
    import cv2

    orb = cv2.ORB.create(nfeatures=ORB_FEATURES)
    matcher = cv2.FlannBasedMatcher(
        dict(algorithm=6, table_number=6, key_size=12, multi_probe_level=1), dict(checks=50)
    )
    matcher.add([textured.descriptors])
    matcher.train()
    kf = _kalman()
    measurement = np.zeros((6, 1))
    seen = False
    measured, filtered = [], []
    dist_arg = np.zeros(5) if dist is None else dist
    began = time.perf_counter()
    for grey in frames:
        keypoints, descriptors = orb.detectAndCompute(grey, None)
        pose = None
        good = []
        if descriptors is not None and len(keypoints) >= 2:
            for pair in matcher.knnMatch(descriptors, k=2):
                if len(pair) == 2 and pair[0].distance < RATIO * pair[1].distance:
                    good.append(pair[0])
        if len(good) >= 4:
            obj = textured.points[[m.trainIdx for m in good]].astype(np.float64)
            img = np.array([keypoints[m.queryIdx].pt for m in good], np.float64)
            ok, rvec, tvec, inliers = cv2.solvePnPRansac(
                obj,
                img,
                K,
                dist_arg,
                iterationsCount=int(RANSAC["iterationsCount"]),
                reprojectionError=float(RANSAC["reprojectionError"]),
                confidence=float(RANSAC["confidence"]),
                flags=cv2.SOLVEPNP_ITERATIVE,
            )
            if ok and inliers is not None and len(inliers) >= MIN_INLIERS:
                R = cv2.Rodrigues(rvec)[0]
                pose = (R, tvec.reshape(3))
                measurement = np.concatenate([pose[1], _euler(R)]).reshape(6, 1)
                seen = True
            # The tutorial updates the filter whenever matches were found, with the
            # last good measurement when this frame's is not.
            kf.predict()
            state = kf.correct(measurement).ravel()
        else:
            state = None
        measured.append(pose)
        if seen and state is not None:
            filtered.append((_from_euler(state[9:12]), state[:3].copy()))
        elif seen:
            filtered.append(filtered[-1] if filtered else None)
        else:
            filtered.append(None)
    return measured, filtered, time.perf_counter() - began


def run_jaxpose(frames, geo, textured, K, dist, keypoints: bool = False
                ) -> tuple[list, float, dict, list, float]:  # fmt: skip
    """`jaxpose.apps.track` from the keypoint path's first pose (`keypoints`: with the
    textured model's keypoints as measurements); per frame the pose (or None where
    lost), the seconds the tracker spent, the start's details, and the same after
    `refine_track` with the seconds it took."""
    import cv2

    from jaxpose.apps import locate_textured, recognition_reinit, refine_track, track

    began = time.perf_counter()
    first = locate_textured(frames[0], textured, K, dist, features=3000)
    start_s = time.perf_counter() - began
    start = (cv2.Rodrigues(first.rvec)[0], first.tvec.reshape(3))
    reinit = recognition_reinit(geo, K, dist, textured=textured)
    began = time.perf_counter()
    extra = {"textured": textured} if keypoints else {}
    results = list(track(frames, geo, K, dist, start, reinit=reinit, **extra))
    elapsed = time.perf_counter() - began
    poses = [(r.R, r.t) if r.ok else None for r in results]
    statuses = [r.status for r in results]
    counts = {s: statuses.count(s) for s in dict.fromkeys(statuses)}
    info = {"start_rvec": first.rvec.ravel().tolist(), "start_tvec": first.tvec.ravel().tolist(),
            "start_s": start_s, "statuses": counts}  # fmt: skip
    began = time.perf_counter()
    refined = refine_track(results)
    refine_s = time.perf_counter() - began
    info["refine_cost"] = [refined.cost_before, refined.cost_after]
    info["refine_sigmas"] = [refined.rotation_sigma, refined.translation_sigma]
    smooth = [(r.R, r.t) if r.ok else None for r in refined.frames]
    return poses, elapsed, info, smooth, refine_s


def _distance_maps(frames) -> list[np.ndarray]:
    import cv2

    out = []
    for grey in frames:
        edges = cv2.Canny(cv2.GaussianBlur(grey, (5, 5), 1.2), *CANNY)
        out.append(cv2.distanceTransform(255 - edges, cv2.DIST_L2, 5))
    return out


def _edge_distance(dmap, geo, K, dist, R, t) -> float | None:
    """Mean distance (px) from the visible projected model edges to the image's edges."""
    import cv2

    from jaxpose.apps import edge_samples

    size = (dmap.shape[1], dmap.shape[0])
    s = edge_samples(geo, K, dist, R, t, spacing=2.0, image_size=size)
    px = s.pixels[s.visible].astype(np.float32)
    inside = (px[:, 0] >= 0) & (px[:, 1] >= 0) & (px[:, 0] <= size[0] - 1)
    inside &= px[:, 1] <= size[1] - 1
    px = px[inside]
    if len(px) == 0:
        return None
    d = cv2.remap(dmap, px[:, :1].reshape(-1, 1, 1), px[:, 1:].reshape(-1, 1, 1),
                  cv2.INTER_LINEAR)  # fmt: skip
    return float(np.mean(d))


def _figures(poses, centre, dmaps, geo, K, dist, seconds) -> dict:
    import cv2

    rot, move = [], []
    for a, b in zip(poses, poses[1:], strict=False):
        if a is None or b is None:
            continue
        rot.append(np.degrees(np.linalg.norm(cv2.Rodrigues(b[0] @ a[0].T)[0])))
        move.append(10.0 * np.linalg.norm((b[0] @ centre + b[1]) - (a[0] @ centre + a[1])))
    rot2, move2 = [], []  # second differences over three frames with a pose
    for a, b, c in zip(poses, poses[1:], poses[2:], strict=False):
        if a is None or b is None or c is None:
            continue
        turn = [cv2.Rodrigues(y[0] @ x[0].T)[0].ravel() for x, y in ((a, b), (b, c))]
        rot2.append(np.degrees(np.linalg.norm(turn[1] - turn[0])))
        pa, pb, pc = (p[0] @ centre + p[1] for p in (a, b, c))
        move2.append(10.0 * np.linalg.norm(pc - 2 * pb + pa))
    per_frame = [
        _edge_distance(m, geo, K, dist, *p) if p else None
        for m, p in zip(dmaps, poses, strict=True)
    ]
    distances = [d for d in per_frame if d is not None]

    def stats(v):
        return {"median": float(np.median(v)), "p95": float(np.percentile(v, 95))} if v else None

    def pose(p):
        rvec = cv2.Rodrigues(p[0])[0].ravel()
        return [np.round(rvec, 6).tolist(), np.round(p[1], 4).tolist()]

    edges = {"mean": float(np.mean(distances)), "median": float(np.median(distances))}
    return {
        "frames_with_pose": int(sum(p is not None for p in poses)),
        "jitter_rotation_deg": stats(rot),
        "jitter_translation_mm": stats(move),
        "jitter_2nd_rotation_deg": stats(rot2),
        "jitter_2nd_translation_mm": stats(move2),
        "edge_distance_px": edges if distances else None,
        "seconds": seconds,
        "fps": len(poses) / seconds,
        "edge_distance_per_frame": [None if d is None else round(d, 3) for d in per_frame],
        "poses": [None if p is None else pose(p) for p in poses],
    }


def run(frames: int = 455, repeats: int = 3) -> dict:
    """The three methods on the first `frames` frames (see the module docstring)."""
    from jaxpose.apps import mesh_geometry, read_ply, sample_path
    from jaxpose.cli._common import setup_jax
    from jaxpose.features import open_frames, read_camera, read_textured_model

    setup_jax(True)
    data = sample_path("opencv_pose_box")
    K, dist = read_camera(data / "box_video_camera.yml")
    dist = None if not np.any(dist) else dist
    box = read_ply(data / "box.ply")
    geo = mesh_geometry(box)
    centre = box.vertices.mean(axis=0)
    textured = read_textured_model(data / "cookies_ORB.yml.gz")
    grey = list(open_frames(data / "box.mp4", gray=True, stop=frames))
    dmaps = _distance_maps(grey)
    # The two run alternately `repeats` times (the machine is shared: its load moves);
    # the poses are the first run's, the rate each method's best run's.
    cv_runs, jp_runs, kp_runs = [], [], []
    for _ in range(repeats):
        cv_runs.append(run_opencv(grey, textured, K, dist))
        jp_runs.append(run_jaxpose(grey, geo, textured, K, dist))
        kp_runs.append(run_jaxpose(grey, geo, textured, K, dist, keypoints=True))
    (measured, filtered, _), (poses, _, info, smooth, _) = cv_runs[0], jp_runs[0]
    cv_s, jp_s = min(r[2] for r in cv_runs), min(r[1] for r in jp_runs)
    kp_s = min(r[1] for r in kp_runs)
    both_s = min(r[1] + r[4] for r in jp_runs)
    methods = {
        "jaxpose": _figures(poses, centre, dmaps, geo, K, dist, jp_s) | info,
        "jaxpose_refined": _figures(smooth, centre, dmaps, geo, K, dist, both_s),
        "jaxpose_keypoints": _figures(kp_runs[0][0], centre, dmaps, geo, K, dist, kp_s)
        | {"statuses": kp_runs[0][2]["statuses"]},
        "opencv_pnp": _figures(measured, centre, dmaps, geo, K, dist, cv_s),
        "opencv_kalman": _figures(filtered, centre, dmaps, geo, K, dist, cv_s),
    }
    methods["jaxpose"]["seconds_each_run"] = [r[1] for r in jp_runs]
    methods["jaxpose_refined"]["refine_seconds_each_run"] = [r[4] for r in jp_runs]
    methods["jaxpose_keypoints"]["seconds_each_run"] = [r[1] for r in kp_runs]
    methods["jaxpose_refined"]["refine_cost"] = info["refine_cost"]
    # (the prior's sigmas, from the track: degrees and a fraction of the distance per frame^2)
    methods["jaxpose_refined"]["refine_sigmas"] = info["refine_sigmas"]
    for key in ("opencv_pnp", "opencv_kalman"):
        methods[key]["seconds_each_run"] = [r[2] for r in cv_runs]
    return {
        "frames": len(grey),
        "repeats": repeats,
        "image": [int(grey[0].shape[1]), int(grey[0].shape[0])],
        "settings": {
            "orb_features": ORB_FEATURES,
            "ratio": RATIO,
            "ransac": RANSAC,
            "min_inliers": MIN_INLIERS,
            "kalman_dt": KALMAN_DT,
            "canny": CANNY,
            "edge_spacing_px": 2.0,
        },  # fmt: skip
        "note": "opencv_pnp and opencv_kalman share one run: the same seconds",
        "methods": methods,
    }


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=455)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", default="benchmarks/results/track_box.json")
    args = parser.parse_args(argv)
    result = run(args.frames, args.repeats)
    for name, m in result["methods"].items():
        jr, jt, ed = m["jitter_rotation_deg"], m["jitter_translation_mm"], m["edge_distance_px"]
        j2, m2 = m["jitter_2nd_rotation_deg"], m["jitter_2nd_translation_mm"]
        print(f"{name:>15}: {m['frames_with_pose']}/{result['frames']} posed, jitter "
              f"{jr['median']:.3f}/{jr['p95']:.3f} deg, {jt['median']:.2f}/{jt['p95']:.2f} mm, "
              f"2nd difference {j2['median']:.3f}/{j2['p95']:.3f} deg, "
              f"{m2['median']:.2f}/{m2['p95']:.2f} mm (median/p95), edges "
              f"{ed['mean']:.2f} px mean ({ed['median']:.2f} median), "
              f"{m['fps']:.1f} frames/s")  # fmt: skip
    print("written", write_json(Path(args.out), result))


if __name__ == "__main__":
    main()
