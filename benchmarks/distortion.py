"""Real lenses: `solve_pnp` with `dist_coeffs` against OpenCV in the distorted image.

Random problems (`jaxpose.apps.random_scene`, 12 matches, OpenCV's convention, f = 800 px)
seen through a lens of their own: `k1` uniform in [-0.4, 0.2] (a strong wide-angle lens
to a mild pincushion), `k2` ~ N(0, 0.02), `p1, p2` ~ N(0, 1e-3), `k3` ~ N(0, 0.02);
pixels with 1 px of noise. For each:

- jaxpose: `jaxpose.solve_pnp(obj, img, K, dist)`;
- the reference optimum: the lower image-space RMS of `cv2.solvePnP` (SQPnP, and the
  iterative method) each refined by `cv2.solvePnPRefineLM` (200 iterations, eps 1e-15);
- the projection: `jaxpose.geometry.project_points` against `cv2.projectPoints` at
  jaxpose's pose (largest difference, px).

A problem is at the optimum when jaxpose's image RMS is within 1e-6 (relative) or 1e-9 px
of the reference's, or below it. Writes `benchmarks/results/distortion.json`
(`distortion_quick.json` with `--quick`: 200 problems instead of 1,000).

    python -m benchmarks.distortion [--quick]
"""

from __future__ import annotations

import argparse
import time

import cv2
import jax
import numpy as np

import jaxpose as jp

from ._harness import K_PIXELS, RESULTS, rich_console, verdict, write_json

__all__ = ["TARGET", "main", "measure"]

#: The share of problems at OpenCV's image-space optimum that the issue asks for.
TARGET = 0.999
CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 200, 1e-15)


def _lens(rng) -> np.ndarray:
    d = np.empty(5)
    d[0] = rng.uniform(-0.4, 0.2)
    d[1], d[4] = rng.normal(scale=0.02, size=2)
    d[2:4] = rng.normal(scale=1e-3, size=2)
    return d


def _problem(rng, n: int = 12, noise: float = 1.0):
    s = jp.apps.random_scene(rng, n, noise=0.0, world_camera=False)
    _, rvec, tvec = cv2.solvePnP(s.model_points, s.image_points, K_PIXELS, None)
    d = _lens(rng)
    img, _ = cv2.projectPoints(s.model_points, rvec, tvec, K_PIXELS, d)
    return s.model_points, img.reshape(-1, 2) + rng.normal(scale=noise, size=(n, 2)), d


def _rms(obj, img, d, rvec, tvec) -> float:
    rvec, tvec = np.asarray(rvec, float), np.asarray(tvec, float)
    proj, _ = cv2.projectPoints(obj, rvec, tvec, K_PIXELS, d)
    return float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - img) ** 2, axis=1))))


def _opencv(obj, img, d) -> float:
    best = np.inf
    for flag in (cv2.SOLVEPNP_SQPNP, cv2.SOLVEPNP_ITERATIVE):
        ok, rvec, tvec = cv2.solvePnP(obj, img, K_PIXELS, d, flags=flag)
        if ok:
            rvec, tvec = cv2.solvePnPRefineLM(obj, img, K_PIXELS, d, rvec, tvec, criteria=CRITERIA)
            best = min(best, _rms(obj, img, d, rvec, tvec))
    return best


def measure(count: int, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    problems = [_problem(rng) for _ in range(count)]
    jp.solve_pnp(*problems[0][:2], K_PIXELS, problems[0][2])  # compile
    ours, ref, proj, at = [], [], [], []
    seconds = 0.0
    for obj, img, d in problems:
        start = time.perf_counter()
        ok, rvec, tvec = jp.solve_pnp(obj, img, K_PIXELS, d)
        seconds += time.perf_counter() - start
        e, r = _rms(obj, img, d, rvec, tvec), _opencv(obj, img, d)
        ours.append(e)
        ref.append(r)
        at.append(bool(ok) and e - r <= max(1e-6 * r, 1e-9))
        cv, _ = cv2.projectPoints(obj, rvec, tvec, K_PIXELS, d)
        with jax.enable_x64(True):
            mine = np.asarray(
                jp.geometry.project_points(obj, rvec.ravel(), tvec.ravel(), K_PIXELS, d)
            )
        proj.append(float(np.max(np.abs(mine - cv.reshape(-1, 2)))))
    share = float(np.mean(at))
    return {
        "problems": count,
        "at_optimum": share,
        "target": TARGET,
        "verdict": verdict(share, TARGET, higher_is_better=True),
        "worst_excess_px": float(np.max(np.array(ours) - np.array(ref))),
        "median_rms_px": float(np.median(ours)),
        "projection_max_diff_px": float(np.max(proj)),
        "solve_pnp_ms": 1e3 * seconds / count,
        "k1_range": [-0.4, 0.2],
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="200 problems instead of 1,000")
    args = parser.parse_args(argv)
    res = measure(200 if args.quick else 1000)
    res["quick"] = args.quick
    out = write_json(RESULTS / ("distortion_quick.json" if args.quick else "distortion.json"), res)
    console = rich_console(100)
    console.print(
        f"distortion: {100 * res['at_optimum']:.2f}% of {res['problems']} problems at OpenCV's "
        f"image-space optimum (target >= {100 * TARGET:.1f}%: {res['verdict']}); projection "
        f"within {res['projection_max_diff_px']:.1e} px of cv2.projectPoints; solve_pnp "
        f"{res['solve_pnp_ms']:.2f} ms per problem"
    )
    console.print(f"written: {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
