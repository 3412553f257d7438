"""The table of the tracker beside OpenCV's real-time pose tutorial on `box.mp4`
(`benchmarks/track_box.py`), for the documentation (`tables.py`)."""

from __future__ import annotations

from pathlib import Path

from tables_format import caption, load, table

#: The methods in their order, with their labels.
LABELS = {
    "jaxpose": "jaxpose `track` (edges + KLT, linear method)",
    "jaxpose_refined": "jaxpose `track`, then `refine_track` (offline, all frames jointly)",
    "jaxpose_keypoints": "jaxpose `track(textured=...)`: edges + KLT + the textured "
    "model's keypoints near the prediction",
    "opencv_pnp": "OpenCV tutorial: ORB + FLANN + `solvePnPRansac`",
    "opencv_kalman": "OpenCV tutorial, with its Kalman filter",
}


def _pair(stats: dict | None, digits: int) -> str:
    return "-" if not stats else f"{stats['median']:.{digits}f} / {stats['p95']:.{digits}f}"


def track_box(results: Path) -> str:
    """One row per method: frames with a pose, frame-to-frame jitter and its second
    difference (median / 95th percentile), the mean distance of the projected model
    edges to the image's edges, and the frames per second (decoding excluded)."""
    d, name = load(results, "track_box.json")
    rows = []
    for key, label in LABELS.items():
        m = d["methods"].get(key)
        if m is None:
            continue
        edge = m["edge_distance_px"]
        rows.append((
            label,
            f"{m['frames_with_pose']}/{d['frames']}",
            _pair(m["jitter_rotation_deg"], 3),
            _pair(m["jitter_translation_mm"], 2),
            _pair(m.get("jitter_2nd_rotation_deg"), 3),
            _pair(m.get("jitter_2nd_translation_mm"), 2),
            "-" if not edge else f"{edge['mean']:.2f}",
            f"{m['fps']:.1f}",
        ))  # fmt: skip
    header = ("method", "frames posed", "jitter rotation (deg)", "jitter centre (mm)",
              "2nd difference rotation (deg)", "2nd difference centre (mm)",
              "edge distance (px)", "frames/s")  # fmt: skip
    out = table(header, rows)
    out += (
        f"\n\n*`box.mp4`, {d['frames']} frames of {d['image'][0]} x {d['image'][1]}, the "
        "tutorial's camera and textured model for every method. Jitter: between "
        "consecutive frames with a pose, median / 95th percentile (the box moves by hand: "
        "motion plus noise); 2nd difference: the change of that motion over three "
        "consecutive frames, median / 95th percentile (a hand's smooth motion changes "
        "little from one frame to the next, noise does). Edge distance: mean over frames "
        "of the mean distance from the "
        "visible projected model edges to the nearest Canny edge. Frames/s: each method's "
        f"own work per frame, decoding excluded, its fastest of {d.get('repeats', 1)} runs "
        "made alternately (the refined row: tracking plus refinement).*"
    )
    return out + "\n\n" + caption(d, name, command="python -m benchmarks.track_box")
