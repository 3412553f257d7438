"""Track the cookie box through OpenCV's tutorial video, and draw the model over it.

The first frame is recognised by the keypoint path (the textured model's ORB keypoints
matched, jaxpose's robust mode on the matches: `jaxpose.apps.locate_textured`); from
there `jaxpose.apps.track` keeps the pose frame after frame (moving edges and KLT points,
the paper's small-movement linear method). Writes the video with the box's visible
edges drawn at each frame's pose (`track_video.mp4`) and the poses (`track_video.json`:
rvec, tvec per frame, OpenCV's convention), and prints the time per frame.

    python examples/track_video.py [--frames N] [--out DIR] [--video PATH]
        [--compare K] [--figure docs/figures/track_video.jpg]

`--compare K` recognises the box again every K frames (the keypoint path alone) and
prints how far apart the two poses put the box's vertices (mean, px); `--figure PATH`
draws frames 0, 100, 300 and 450 (those there are), half size, as the documentation's
figure.

The video has no ground truth: the drawing shows how well the mesh (2.5% smaller than
the box, see `jaxpose/data/README.md`) and the tutorial's approximate camera fit it.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import cv2
import numpy as np

import jaxpose as jp

BOX = jp.apps.sample_path("opencv_pose_box")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--video", default=str(BOX / "box.mp4"))
    parser.add_argument("--frames", type=int, default=None, help="the first N frames only")
    parser.add_argument("--out", default=".", help="folder of the video and the poses")
    parser.add_argument("--compare", type=int, default=0, help="recognise every K frames")
    parser.add_argument("--figure", default=None, help="write the 2 x 2 figure here")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    K, dist = jp.features.read_camera(BOX / "box_video_camera.yml")
    mesh = jp.apps.mesh_geometry(jp.apps.read_ply(BOX / "box.ply"))
    frames = list(jp.features.open_frames(args.video, stop=args.frames))
    textured = jp.features.read_textured_model(BOX / "cookies_ORB.yml.gz")
    start = jp.apps.locate_textured(frames[0], textured, K, dist, features=3000)
    if not start.ok:
        print("the box was not recognised in the first frame")
        return 1
    initial = (cv2.Rodrigues(start.rvec)[0], start.tvec.ravel())

    began = time.perf_counter()
    results = list(jp.apps.track(frames, mesh, K, dist, initial))
    per_frame = (time.perf_counter() - began) / len(frames)

    h, w = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(out / "track_video.mp4"), cv2.VideoWriter.fourcc(*"mp4v"),
                             30.0, (w, h))  # fmt: skip
    poses, drawn = [], {}
    for frame, r in zip(frames, results, strict=True):
        seen = jp.apps.edge_samples(mesh, K, dist, r.R, r.t, spacing=2.0, image_size=(w, h))
        picture = frame.copy()
        for x, y in np.round(seen.pixels[seen.visible]).astype(int):
            cv2.circle(picture, (int(x), int(y)), 1, (255, 255, 0), -1)  # cyan
        writer.write(picture)
        if r.frame in (0, 100, 300, 450):
            drawn[r.frame] = picture
        rvec = cv2.Rodrigues(r.R)[0].ravel()
        poses.append({"frame": r.frame, "ok": r.ok, "rvec": rvec.tolist(),
                      "tvec": r.t.tolist(), "edges": r.edges, "points": r.points,
                      "rms_px": r.rms})  # fmt: skip
    writer.release()
    (out / "track_video.json").write_text(json.dumps({"per_frame_s": per_frame,
                                                      "frames": poses}, indent=1))  # fmt: skip
    if args.figure and drawn:
        tiles = list(drawn.values()) + [np.zeros_like(frames[0])] * (4 - len(drawn))
        grid = np.vstack([np.hstack(tiles[:2]), np.hstack(tiles[2:])])
        grid = cv2.resize(grid, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
        cv2.imwrite(args.figure, grid, [cv2.IMWRITE_JPEG_QUALITY, 85])
    for i in range(0, len(frames), args.compare) if args.compare > 0 else ():
        again = jp.apps.locate_textured(frames[i], textured, K, dist, features=3000)
        if not again.ok:
            print(f"frame {i}: not recognised")
            continue
        ours = cv2.projectPoints(mesh.model.vertices, cv2.Rodrigues(results[i].R)[0],
                                 results[i].t, K, dist)[0]  # fmt: skip
        theirs = cv2.projectPoints(mesh.model.vertices, again.rvec, again.tvec, K, dist)[0]
        apart = float(np.linalg.norm((ours - theirs).reshape(-1, 2), axis=1).mean())
        print(f"frame {i}: tracked and recognised poses {apart:.1f} px apart")
    lost = sum(not r.ok for r in results)
    print(f"{len(frames)} frames, {1e3 * per_frame:.1f} ms per frame, {lost} without a pose")
    print(f"written {out / 'track_video.mp4'} and {out / 'track_video.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
