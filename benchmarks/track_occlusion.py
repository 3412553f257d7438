"""Tracking through a full occlusion with re-initialisation by recognition (issue #32):
rendered sequences of the box with known poses, everything hidden by a grey rectangle
for a few frames, tracked by `jaxpose.apps.track` from the first pose with
`jaxpose.apps.recognition_reinit` (recognition from the mesh alone) as `reinit`.

Sequences: the box flat-shaded and textured from its photograph
(`jaxpose.apps.face_textures`), `--seeds` trajectories each (`smooth_trajectory`:
up to 20 degrees and 4 mm about the start, over `--frames` frames), 480 x 360, f = 600
px, the box about 8 cm away, noise sigma 2, hidden on frames 8-12. For each run:

- `hidden_tracked`: frames reported tracked (or re-initialised) while hidden (want 0);
- `back_after`: frames from the reappearance to the first frame with a pose (want
  <= 4, i.e. back within 5 frames) and that frame's rotation and translation errors;
- `seen_on_target`: the fraction of the frames seen with rotation <= 0.5 degree and
  translation <= 0.5% of the distance, `max_rotation_deg` among the frames reported
  with a pose;
- `wrong_tracked`: frames reported with a pose but off the target.

Each run is made twice: as the tracker is, and without the symmetric variants of the
recognised pose (`symmetries: false`), to show what they do.

    python -m benchmarks.track_occlusion [--seeds 5] [--frames 24]
        [--out benchmarks/results/track_occlusion.json]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from ._harness import write_json

HIDDEN = range(8, 13)


def _errors(results, Rs, ts, centre):
    import cv2

    rotation, translation = [], []
    for r, R, t in zip(results, Rs, ts, strict=True):
        rotation.append(float(np.degrees(np.linalg.norm(cv2.Rodrigues(r.R @ R.T)[0]))))
        where = R @ centre + t
        translation.append(
            float(np.linalg.norm(r.R @ centre + r.t - where) / np.linalg.norm(where))
        )
    return np.array(rotation), np.array(translation)


def run(seeds: int = 5, frames: int = 24) -> dict:
    """The runs described in the module docstring; returns the figures as a dict."""
    import cv2

    import jaxpose.apps._track as tracker
    from jaxpose.apps import (
        face_textures,
        mesh_geometry,
        read_ply,
        recognition_reinit,
        render,
        sample_path,
        smooth_trajectory,
        track,
    )
    from jaxpose.cli._common import setup_jax

    setup_jax(True)
    box = read_ply(sample_path("opencv_pose_box", "box.ply"))
    geo = mesh_geometry(box)
    centre = box.vertices.mean(axis=0)
    K = np.array([[600.0, 0, 240], [0, 600, 180], [0, 0, 1]])
    size = (480, 360)
    photo = cv2.imread(str(sample_path("opencv_pose_box", "resized_IMG_3875.JPG")))
    K_photo = np.array([[1384.484, 0, 359], [0, 1385.235, 240], [0, 0, 1.0]])
    R_photo = cv2.Rodrigues(np.array([2.05445, -0.78674, 0.31403]))[0]
    textures = face_textures(photo, geo, K_photo, None, R_photo, [-1.0904, 11.6255, 91.0701],
                             texture_scale=0.05)  # fmt: skip
    looks = {
        "flat": dict(shades=np.array([200.0, 90.0, 150.0, 240.0, 120.0, 60.0])),
        "photo": dict(texture=textures, texture_scale=0.05, ambient=0.4),
    }
    reinit = recognition_reinit(box, K)
    began = time.perf_counter()
    reinit(render(geo, K, None, np.eye(3), np.array([0, 0, 80.0]), size), 0)  # compile
    compile_s = time.perf_counter() - began
    symmetries = tracker._symmetries
    runs = []
    for look, style in looks.items():
        for seed in range(1, seeds + 1):
            R0 = cv2.Rodrigues(np.array([2.2, -0.6, 0.4]))[0]
            t0 = np.array([0.0, 0.0, 80.0]) - R0 @ centre
            Rs, ts = smooth_trajectory(R0, t0, frames, centre=centre, rotation=20.0,
                                       translation=4.0, seed=seed)  # fmt: skip
            rng = np.random.default_rng(seed)
            images = [
                render(geo, K, None, R, t, size, background=40, supersample=2, noise=2.0,
                       rng=rng, occluder=(30, 15, 450, 345) if i in HIDDEN else None,
                       **style)
                for i, (R, t) in enumerate(zip(Rs, ts, strict=True))
            ]  # fmt: skip
            for use in (True, False):
                tracker._symmetries = symmetries if use else (lambda geo, within=0: [])
                try:
                    began = time.perf_counter()
                    results = list(track(images, geo, K, None, (Rs[0], ts[0]), reinit=reinit))
                    elapsed = time.perf_counter() - began
                finally:
                    tracker._symmetries = symmetries
                rotation, translation = _errors(results, Rs, ts, centre)
                on = (rotation <= 0.5) & (translation <= 0.005)
                seen = np.array([i not in HIDDEN for i in range(frames)])
                posed = np.array([r.ok for r in results])
                back = [i for i in range(HIDDEN[-1] + 1, frames) if results[i].ok]
                runs.append({
                    "look": look,
                    "seed": seed,
                    "symmetries": use,
                    "statuses": [r.status for r in results],
                    "hidden_tracked": int(np.sum(posed & ~seen)),
                    "back_after": back[0] - HIDDEN[-1] - 1 if back else None,
                    "back_rotation_deg": float(rotation[back[0]]) if back else None,
                    "back_translation": float(translation[back[0]]) if back else None,
                    "seen_on_target": float(np.mean(on[seen])),
                    "max_rotation_deg": float(rotation[posed].max()),
                    "wrong_tracked": int(np.sum(posed & ~on)),
                    "seconds": elapsed,
                })  # fmt: skip
    return {"frames": frames, "hidden": list(HIDDEN), "recognition_compile_s": compile_s,
            "runs": runs}  # fmt: skip


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--frames", type=int, default=24)
    parser.add_argument("--out", default="benchmarks/results/track_occlusion.json")
    args = parser.parse_args(argv)
    result = run(args.seeds, args.frames)
    for r in result["runs"]:
        back = "never" if r["back_after"] is None else (
            f"+{r['back_after']} ({r['back_rotation_deg']:.2f} deg, "
            f"{100 * r['back_translation']:.2f}%)")  # fmt: skip
        print(f"{r['look']:>5} seed {r['seed']} symmetries {str(r['symmetries']):>5}: "
              f"hidden tracked {r['hidden_tracked']}, back {back}, seen on target "
              f"{100 * r['seen_on_target']:.0f}%, wrong tracked {r['wrong_tracked']}, "
              f"max {r['max_rotation_deg']:.2f} deg")  # fmt: skip
    print("written", write_json(Path(args.out), result))


if __name__ == "__main__":
    main()
