"""Tracking front end: the time per frame of each image-measurement step (issue #32) on
the frames of OpenCV's box video (640 x 480), with the box's mesh at the pose the
keypoint path finds in its first frame (`jaxpose.apps.locate_textured`, the textured
model, 3000 ORB features: rvec (1.9126, -1.2641, 0.7411), tvec (21.44, 0.69, 152.13) cm),
and the whole tracker (`jaxpose.apps.track`) from that pose through the same frames.

Steps, each timed per frame over the frames read (median and mean, milliseconds):

- `read`: decode the next frame and convert it to grey;
- `edge_samples`: the visible edges sampled every `spacing` px (back-face culling and the
  depth test);
- `moving_edges`: the search along each sample's normal (+-`search` px);
- `face_mask`: the visible faces' area, eroded;
- `detect_corners`: corners inside it (a full re-detection, the worst case per frame);
- `track_points`: pyramidal Lucas-Kanade forward and backward for the corners;
- `cast_rays`: the corners' 3D points on the mesh;
- `track`, `track_edges_only`: a whole tracker step per frame (two rounds of moving
  edges and the solve, KLT points tracked, recast, topped up), with and without the
  KLT points.

    python -m benchmarks.frontend [--frames 100] [--out benchmarks/results/frontend.json]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from ._harness import write_json


def run(frames: int = 100, spacing: float = 8.0, search: int = 10, corners: int = 300) -> dict:
    """Time the steps on the first `frames` frames of the box video (see the module
    docstring); returns the figures as a dict."""
    import cv2

    from jaxpose.apps import (
        TrackOptions,
        cast_rays,
        edge_samples,
        face_mask,
        mesh_geometry,
        read_ply,
        sample_path,
        track,
    )
    from jaxpose.features import (
        detect_corners,
        moving_edges,
        open_frames,
        read_camera,
        track_points,
    )

    K, dist = read_camera(sample_path("opencv_pose_box", "box_video_camera.yml"))
    geo = mesh_geometry(read_ply(sample_path("opencv_pose_box", "box.ply")))
    R = cv2.Rodrigues(np.array([1.91258699, -1.26409631, 0.74108325]))[0]
    t = np.array([21.43863207, 0.69211619, 152.12559535])
    size = (640, 480)
    steps: dict[str, list[float]] = {}

    def timed(name, fn, *args, **kwargs):
        start = time.perf_counter()
        out = fn(*args, **kwargs)
        steps.setdefault(name, []).append(1e3 * (time.perf_counter() - start))
        return out

    stream = iter(open_frames(sample_path("opencv_pose_box", "box.mp4"), stop=frames + 1))
    previous = cv2.cvtColor(next(stream), cv2.COLOR_BGR2GRAY)
    counts = {"samples": [], "matches": [], "corners": [], "tracked": []}
    for _ in range(frames):
        start = time.perf_counter()
        frame = next(stream, None)
        if frame is None:
            break
        grey = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
        steps.setdefault("read", []).append(1e3 * (time.perf_counter() - start))
        samples = timed("edge_samples", edge_samples, geo, K, dist, R, t, spacing=spacing,
                        image_size=size)  # fmt: skip
        found = timed("moving_edges", moving_edges, grey, samples.pixels, samples.normals,
                      search=search, mask=samples.visible)  # fmt: skip
        region = timed("face_mask", face_mask, geo, K, dist, R, t, size, erode=4)
        points = timed("detect_corners", detect_corners, previous, region, max_corners=corners)
        tracks = timed("track_points", track_points, previous, grey, points)
        timed("cast_rays", cast_rays, geo, K, dist, R, t, points)
        counts["samples"].append(int(samples.visible.sum()))
        counts["matches"].append(int(found.valid.sum()))
        counts["corners"].append(len(points))
        counts["tracked"].append(int(tracks.valid.sum()))
        previous = grey
    grey = list(open_frames(sample_path("opencv_pose_box", "box.mp4"), gray=True,
                            stop=frames + 1))  # fmt: skip
    for name, options in (("track", TrackOptions()),
                          ("track_edges_only", TrackOptions(use_points=False))):  # fmt: skip
        stepper = track(grey, geo, K, dist, (R, t), options=options)
        start = time.perf_counter()
        for _ in stepper:
            steps.setdefault(name, []).append(1e3 * (time.perf_counter() - start))
            start = time.perf_counter()
    figures = {
        name: {"median_ms": float(np.median(v)), "mean_ms": float(np.mean(v))}
        for name, v in steps.items()
    }
    parts = [k for k in figures if not k.startswith("track")]
    total = sum(figures[k]["median_ms"] for k in parts)
    return {
        "frames": len(steps["read"]),
        "image": list(size),
        "options": {"spacing": spacing, "search": search, "max_corners": corners},
        "per_frame": figures,
        "total_median_ms": total,
        "counts_median": {k: float(np.median(v)) for k, v in counts.items()},
    }


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=100)
    parser.add_argument("--out", default="benchmarks/results/frontend.json")
    args = parser.parse_args(argv)
    result = run(args.frames)
    for name, f in result["per_frame"].items():
        print(f"{name:>15}: {f['median_ms']:7.2f} ms median, {f['mean_ms']:7.2f} ms mean")
    print(f"{'steps':>15}: {result['total_median_ms']:7.2f} ms per frame (medians summed)")
    print("counts (median per frame):", result["counts_median"])
    print("written", write_json(Path(args.out), result))


if __name__ == "__main__":
    main()
