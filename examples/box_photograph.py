"""The box photograph recognised both ways, and its figure for the documentation.

Recognises OpenCV's cookie-box photograph (`jaxpose/data/opencv_pose_box`) by the vertex
path (the mesh alone, no correspondence given) and by the keypoint path (the textured
model), saves the poses (`benchmarks/results/box_photograph.json`), then draws from that
saved result `docs/figures/box_photograph.png`: left, the mesh's edges at the vertex
path's pose with the matched image vertices (red circles) and their reprojections (cyan
crosses); right, the edges at the keypoint path's pose.

    python examples/box_photograph.py [--out docs/figures] [--draw-only]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import jax
import numpy as np

import jaxpose as jp
from jaxpose.viz._overlay import overlay

ROOT = Path(__file__).resolve().parents[1]
RESULT = ROOT / "benchmarks" / "results" / "box_photograph.json"
BOX = jp.apps.sample_path("opencv_pose_box")
K = np.array([[1384.484, 0, 359], [0, 1385.235, 240], [0, 0, 1]])


def recognise() -> dict:
    """Both paths on the photograph: the poses, in the camera frame (OpenCV's)."""
    box = jp.apps.read_ply(BOX / "box.ply", name="box")
    orb = jp.features.read_textured_model(BOX / "cookies_ORB.yml.gz")
    with jax.enable_x64(True):
        found = jp.apps.recognize(str(BOX / "resized_IMG_3875.JPG"), [box, orb], K)
    out: dict = {"detections": []}
    for d in found.detections:
        out["detections"].append(
            {
                "model": d.model,
                "R": np.asarray(d.R).tolist(),
                "t": np.asarray(d.t).tolist(),
                "score": float(d.score),
                "vertices": np.asarray(d.vertices).tolist(),
                "pixels": np.asarray(d.pixels).tolist(),
            }
        )
    pose = found.textured[orb.name]
    out["keypoints"] = {
        "ok": bool(pose.ok),
        "rvec": np.ravel(pose.rvec).tolist(),
        "tvec": np.ravel(pose.tvec).tolist(),
        "inliers": int(np.sum(pose.inliers)),
        "rms": float(pose.rms),
    }
    return out


def draw(result: dict, out: Path) -> Path:
    """The figure, from a saved `result` of `recognise`."""
    photo = cv2.imread(str(BOX / "resized_IMG_3875.JPG"))
    box = jp.apps.read_ply(BOX / "box.ply", name="box")
    camera = np.hstack([K, np.zeros((3, 1))])
    panels = []
    if result["detections"]:
        d = result["detections"][0]
        panels.append(
            overlay(
                photo,
                camera,
                box,
                (np.array(d["R"]), np.array(d["t"])),
                vertices=np.array(d["vertices"]),
                observed=np.array(d["pixels"]),
                thickness=2,
            )
        )
    else:
        panels.append(photo.copy())
    kp = result["keypoints"]
    if kp["ok"]:
        R, _ = cv2.Rodrigues(np.array(kp["rvec"]))
        panels.append(overlay(photo, camera, box, (R, np.array(kp["tvec"])), thickness=2))
    else:
        panels.append(photo.copy())
    for panel, text in zip(panels, ("mesh alone (vertex path)", "textured model (keypoints)")):
        cv2.putText(panel, text, (12, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (255, 255, 255), 2)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "box_photograph.png"
    cv2.imwrite(str(path), np.hstack(panels))
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "figures")
    parser.add_argument("--draw-only", action="store_true", help="from the saved result")
    args = parser.parse_args(argv)
    if not args.draw_only:
        RESULT.write_text(json.dumps(recognise(), indent=1) + "\n")
        print(f"wrote {RESULT}")
    print(f"wrote {draw(json.loads(RESULT.read_text()), args.out)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
