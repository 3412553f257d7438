"""Superimposition figures: a recognised model's edges drawn at jaxpose's pose.

- `bench_overlay.png`: the rendered bench (the cross prism, 768 x 576), the model's edges
  at the pose `jaxpose.solve` recovers from the 16 noisy matches, the observed points
  (red circles) and their reprojections (cyan crosses); right: the same, seen through a
  zoomed camera (the overlay redrawn at the higher resolution, not an enlarged bitmap).
- `recognition.png`: a box on the bench and two hypotheses verified at once: the box
  (accepted, green) and an L-block matched to the same image points (rejected, red,
  drawn at its best-fitting pose).
- `chessboard_leftNN.png`: OpenCV's sample photographs, the board's grid lines drawn at
  the pose `jaxpose.solve_pnp` recovers from the detected corners (with the lens
  distortion, so the lines bend as the lens bends them).

    python examples/superimpose.py [--out docs/figures] [--images 03 06 12]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import jax
import numpy as np

import jaxpose as jp
from jaxpose.apps._models import chessboard, model_bench
from jaxpose.apps._recognition import Hypothesis, verify_hypotheses
from jaxpose.viz._overlay import overlay, render

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "jaxpose" / "data" / "chessboard"


def zoom_camera(camera: np.ndarray, box: tuple[float, float, float, float], scale: float):
    """The camera that sees the pixel box `(x0, y0, x1, y1)` of `camera` enlarged `scale`
    times, and that image's size."""
    x0, y0, x1, y1 = box
    S = np.array([[scale, 0.0, -scale * x0], [0.0, scale, -scale * y0], [0.0, 0.0, 1.0]])
    return S @ camera, (int(round(scale * (x1 - x0))), int(round(scale * (y1 - y0))))


def label(image: np.ndarray, lines: list[str]) -> np.ndarray:
    """White text on a darkened band at the top left."""
    out = image.copy()
    font, scale = cv2.FONT_HERSHEY_SIMPLEX, 0.5
    width = max(cv2.getTextSize(t, font, scale, 1)[0][0] for t in lines) + 16
    height = 20 * len(lines) + 10
    band = out[:height, :width]
    band[:] = (band * 0.35).astype(out.dtype)
    for i, text in enumerate(lines):
        cv2.putText(out, text, (8, 20 + 20 * i), font, scale, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def panel(bench, pose, model=None, vertices=None, observed=None, color=(0, 255, 0), pad=30):
    """The bench image with an overlay, beside a zoom on the object."""
    model = bench.model if model is None else model
    vertices = bench.visible if vertices is None else vertices
    observed = bench.image_points if observed is None else observed
    full = render(bench.camera, bench.model, (bench.R, bench.t), bench.image_size)
    full = overlay(
        full,
        bench.camera,
        model,
        pose,
        vertices=vertices,
        observed=observed,
        edge_color=color,
        cull=True,
    )
    lo = bench.clean_points.min(axis=0) - pad
    hi = bench.clean_points.max(axis=0) + pad
    height = bench.image_size[1]
    scale = height / (hi[1] - lo[1])
    cam, size = zoom_camera(bench.camera, (*lo, *hi), scale)
    S = cam @ np.linalg.pinv(bench.camera)  # pixel map of the zoom (3x3)
    zoomed_obs = np.column_stack([observed, np.ones(len(observed))]) @ S.T
    zoomed_obs = zoomed_obs[:, :2] / zoomed_obs[:, 2:]
    zoom = render(cam, bench.model, (bench.R, bench.t), size)
    zoom = overlay(
        zoom,
        cam,
        model,
        pose,
        vertices=vertices,
        observed=zoomed_obs,
        edge_color=color,
        thickness=2,
        cull=True,
    )
    return full, zoom


def bench_figure(out: Path) -> Path:
    bench = jp.default_bench()
    with jax.enable_x64(True):
        sol = jp.solve(bench.camera, bench.model_points, bench.image_points)
        pose = (np.asarray(sol.pose.R), np.asarray(sol.pose.t))
        error, pose_error = float(sol.error), float(sol.pose_error)
    full, zoom = panel(bench, pose)
    full = label(
        full,
        [
            "bench (rendered): cross prism, 16 matches, noise 0.8 px",
            f"jaxpose.solve: Eq. 8 error {error:.2f} px, pose error {pose_error:.2f} mm",
            "green: model edges at the recovered pose",
            "red o: observed, cyan +: reprojected",
        ],
    )
    zoom = label(zoom, ["zoom (redrawn through a zoomed camera)"])
    path = out / "bench_overlay.png"
    cv2.imwrite(str(path), np.hstack([full, zoom]), [cv2.IMWRITE_PNG_COMPRESSION, 9])
    return path


def recognition_figure(out: Path) -> Path:
    db = jp.apps.model_database()
    bench = model_bench("box", seed=0)
    k = len(bench.visible)
    wrong = db["l_block"]
    right_h = Hypothesis(bench.model, bench.visible, bench.image_points, "box")
    wrong_h = Hypothesis(wrong, np.arange(k), bench.image_points, "l_block")
    verdicts = {
        v.hypothesis.label: v
        for v in verify_hypotheses(bench.camera, [right_h, wrong_h], noise=bench.noise)
    }
    panels = []
    for name, color in (("box", (0, 255, 0)), ("l_block", (0, 0, 255))):
        v = verdicts[name]
        h = v.hypothesis
        _, zoom = panel(bench, (v.R, v.t), h.model, h.vertices, h.image_points, color)
        verdict = "ACCEPTED" if v.accepted else "REJECTED"
        zoom = label(
            zoom,
            [
                f"hypothesis: {name}, {k} matches -> {verdict}",
                f"Eq. 8 error {v.error:.2f} px (bound {v.error_threshold:.2f} px)",
                f"consensus {100 * v.consensus:.0f}% "
                f"(residual bound {v.residual_threshold:.2f} px)",
            ],
        )
        panels.append(zoom)
    h = min(p.shape[0] for p in panels)
    path = out / "recognition.png"
    cv2.imwrite(str(path), np.hstack([p[:h] for p in panels]), [cv2.IMWRITE_PNG_COMPRESSION, 9])
    return path


def chessboard_figure(out: Path, number: str) -> Path | None:
    fs = cv2.FileStorage(str(DATA / "left_intrinsics.yml"), cv2.FILE_STORAGE_READ)
    K = fs.getNode("camera_matrix").mat()
    dist = fs.getNode("distortion_coefficients").mat().ravel()
    fs.release()
    gray = cv2.imread(str(DATA / f"left{number}.jpg"), cv2.IMREAD_GRAYSCALE)
    found, corners = cv2.findChessboardCorners(gray, (9, 6))
    if not found:
        return None
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 1e-3)
    corners = cv2.cornerSubPix(gray, corners, (11, 11), (-1, -1), crit).reshape(-1, 2)
    model, inner = chessboard((9, 6), 0.025)
    ok, rvec, tvec = jp.solve_pnp(model.vertices[inner], corners, K, dist)
    if not ok:
        return None
    R = cv2.Rodrigues(rvec)[0]
    pose = (R, tvec.ravel())
    camera = np.column_stack([K, np.zeros(3)])
    image = cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR)
    drawn = overlay(
        image, camera, model, pose, vertices=inner, observed=corners, dist_coeffs=dist, thickness=1
    )
    proj, _ = cv2.projectPoints(model.vertices[inner], rvec, tvec, K, dist)
    rms = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - corners) ** 2, axis=1))))
    drawn = label(
        drawn,
        [
            f"left{number}.jpg: 9x6 corners, jaxpose.solve_pnp (with distortion)",
            f"reprojection error {rms:.2f} px; green: board grid at the pose",
        ],
    )
    path = out / f"chessboard_left{number}.png"
    cv2.imwrite(str(path), drawn, [cv2.IMWRITE_PNG_COMPRESSION, 9])
    return path


def main(argv=None) -> list[Path]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(ROOT / "docs" / "figures"))
    parser.add_argument("--images", nargs="*", default=["03", "06", "12"])
    parser.add_argument("--no-recognition", action="store_true", help="skip recognition.png")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    paths = [bench_figure(out)]
    if not args.no_recognition:
        paths.append(recognition_figure(out))
    paths += [p for n in args.images if (p := chessboard_figure(out, n)) is not None]
    for p in paths:
        print(f"wrote {p} ({p.stat().st_size / 1024:.0f} KB)")
    return paths


if __name__ == "__main__":
    main()
