"""OpenCV's own test cases for `solvePnP`, `solvePnPRansac` and `solvePnPGeneric`, run on
`cv2` and on jaxpose's drop-ins with the same inputs and OpenCV's thresholds.

The facts of each case (how its problems are drawn, its data, its thresholds and its
pass rule) are those of OpenCV's calib3d tests (`test_solvepnp_ransac.cpp`, and the PnP
cases of `test_usac.cpp`), written here in this project's own code; OpenCV's method is
its default, `SOLVEPNP_ITERATIVE` (RANSAC: OpenCV's defaults for its flags; the USAC
cases: each of OpenCV's USAC methods), jaxpose's its default, the mixed method.
Where this differs from OpenCV's test it says so: fewer trials per accuracy case (1000
in OpenCV; `--trials`, default 100) and 100 points for the clouds of 500 and the USAC
problems of 3,000 and 1,500 (jaxpose compiles one program per size of problem; the pass
rule does not depend on the size).

A case passes for a solver when its rule holds (an accuracy case: at least 70% of its
trials within the thresholds, as OpenCV's). The promise checked by
`tests/api/test_opencv_cases.py`: jaxpose passes every case that `cv2` passes.

    python benchmarks/opencv_cases.py            # --trials 100
    python benchmarks/opencv_cases.py --quick    # --trials 20

Also `solve_pnp_generic` against IPPE (`cv2.solvePnPGeneric(..., SOLVEPNP_IPPE)`, its
two poses refined to their minima) on `--planar` (default 1,000) planar problems.

Prints a table and writes benchmarks/results/opencv_cases.json.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

import jaxpose as jp

RESULTS = Path(__file__).resolve().parent / "results" / "opencv_cases.json"

#: OpenCV's pass rule for an accuracy case: this share of its trials within thresholds.
PASS_RATE = 0.7


# ----------------------------------------------------------------------------- solvers


def _cv_pnp(obj, img, K, dist, rvec=None, tvec=None, guess=False):
    try:
        if guess:
            r, t = np.array(rvec, np.float64).reshape(3, 1), np.array(tvec, np.float64)
            return cv2.solvePnP(obj, img, K, dist, r, t.reshape(3, 1), True)
        return cv2.solvePnP(obj, img, K, dist)
    except cv2.error:
        return False, np.zeros((3, 1)), np.zeros((3, 1))


def _cv_ransac(obj, img, K, dist, iterations=100, threshold=8.0, confidence=0.99, p3p=False):
    flags = cv2.SOLVEPNP_P3P if p3p else cv2.SOLVEPNP_ITERATIVE
    try:
        ok, r, t, inl = cv2.solvePnPRansac(
            obj,
            img,
            K,
            dist,
            iterationsCount=iterations,
            reprojectionError=threshold,
            confidence=confidence,
            flags=flags,
        )
    except cv2.error:
        return False, np.zeros((3, 1)), np.zeros((3, 1)), None
    return ok, r, t, inl


def _cv_generic(obj, img, K, dist):
    try:
        return cv2.solvePnPGeneric(obj, img, K, dist)
    except cv2.error:
        return 0, (), (), np.zeros((0, 1))


def _jp_ransac(obj, img, K, dist, iterations=100, threshold=8.0, confidence=0.99, p3p=False):
    # (every triplet is scored: no iteration count or confidence)
    return jp.solve_pnp_ransac(obj, img, K, dist, reprojection_error=threshold)


#: OpenCV's USAC methods of `test_usac.cpp`'s PnP cases (its parallel one left out there
#: too: not deterministic).
USAC_FLAGS = ("USAC_DEFAULT", "USAC_ACCURATE", "USAC_PROSAC", "USAC_FAST", "USAC_MAGSAC")


def _cv_usac(obj, img, K, iterations, threshold, confidence) -> list:
    """`cv2.solvePnPRansac` with each of `USAC_FLAGS`: one `(ok, rvec, tvec, inliers)`
    each."""
    out = []
    for flag in USAC_FLAGS:
        try:
            out.append(
                cv2.solvePnPRansac(
                    obj,
                    img,
                    K,
                    None,
                    iterationsCount=int(iterations),
                    reprojectionError=threshold,
                    confidence=confidence,
                    flags=getattr(cv2, flag),
                )
            )
        except cv2.error:
            out.append((False, np.zeros((3, 1)), np.zeros((3, 1)), None))
    return out


def _cv_usac_params(obj, img, K):
    """`cv2.solvePnPRansac` with OpenCV's default `cv2.UsacParams()` (threshold 1.5 px,
    confidence 0.99, 5,000 iterations)."""
    try:
        ok, _, r, t, inl = cv2.solvePnPRansac(obj, img, K, np.zeros(4), params=cv2.UsacParams())
    except cv2.error:
        return False, np.zeros((3, 1)), np.zeros((3, 1)), None
    return ok, r, t, inl


#: The triplets jaxpose scores in the USAC cases (`max_triplets`; a uniform sample, the
#: same for every inlier ratio: one compiled program). RANSAC's iterations are OpenCV's
#: budget, `1.3 ln(1 - 0.99) / ln(1 - ratio^3)`: 5,984 at the lowest ratio, 0.1, which
#: leaves about 1% of draws without an all-inlier sample by design; with 10 right
#: matches of 100 (the cases' size) a sample of 8,192 of the C(100, 3) triplets holds
#: none of the 120 all-inlier ones with probability e^-6.
USAC_TRIPLETS = 8192


def _jp_usac(obj, img, K, iterations, threshold, confidence) -> list:
    return [
        jp.solve_pnp_ransac(
            obj, img, K, None, reprojection_error=threshold, max_triplets=USAC_TRIPLETS
        )
    ]


def _jp_usac_params(obj, img, K):
    threshold = cv2.UsacParams().threshold
    return _jp_usac(obj, img, K, 5000, threshold, 0.99)[0]


@dataclass(frozen=True)
class Solver:
    name: str
    pnp: Callable
    ransac: Callable
    generic: Callable
    usac: Callable
    usac_params: Callable


CV2 = Solver("cv2", _cv_pnp, _cv_ransac, _cv_generic, _cv_usac, _cv_usac_params)
JAXPOSE = Solver(
    "jaxpose",
    lambda obj, img, K, dist, rvec=None, tvec=None, guess=False: jp.solve_pnp(
        obj, img, K, dist, rvec, tvec, guess
    ),
    _jp_ransac,
    jp.solve_pnp_generic,
    _jp_usac,
    _jp_usac_params,
)


# ----------------------------------------------------------------------------- problems


def camera(rng) -> np.ndarray:
    """OpenCV's random intrinsics: fx, fy, cx, cy uniform in [1e-3, 100] px."""
    fx, fy, cx, cy = rng.uniform(1e-3, 100, 4)
    return np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])


def distortion(rng, mode: int) -> np.ndarray:
    """OpenCV's: four coefficients, zero (mode 0) or k1, k2, p1 in [0, 1e-6]."""
    d = np.zeros(4)
    if mode:
        d[:3] = rng.uniform(0, 1e-6, 3)
    return d


def pose(points, rng, tries: int = 10):
    """OpenCV's random pose: rvec in [1e-3, 1]^3, tvec x, y in [-1, 1], z in [1e-2, 1],
    drawn again (up to `tries` times) until every point is in front of the camera."""

    def draw():
        rvec = rng.uniform(1e-3, 1, 3)
        return rvec, np.array([*rng.uniform(-1, 1, 2), rng.uniform(1e-2, 1)])

    rvec, tvec = draw()
    for _ in range(tries - 1):
        depth = (np.asarray(points, np.float64) @ cv2.Rodrigues(rvec)[0].T + tvec)[:, 2]
        if np.all(depth > 0):
            break
        rvec, tvec = draw()
    return rvec, tvec


def cloud(rng, n: int) -> np.ndarray:
    """OpenCV's 3D cloud: `n` points in [-1, 1] x [-1, 1] x [5, 10], float32."""
    lo, hi = np.array([-1, -1, 5.0]), np.array([1, 1, 10.0])
    return rng.uniform(lo, hi, (n, 3)).astype(np.float32)


def planar_cloud(rng, n: int) -> np.ndarray:
    """OpenCV's planar cloud: `n` points in [-1, 1]^2 of a plane at a random pose."""
    rvec, tvec = pose(np.zeros((1, 3)), rng)
    R = cv2.Rodrigues(rvec.astype(np.float32))[0]
    p = np.c_[rng.uniform(-1, 1, (n, 2)), np.zeros(n)]
    return (p @ R.T + tvec).astype(np.float32)


def tag(rng) -> np.ndarray:
    """OpenCV's planar tag: a square of side in [0.01, 1], its four corners."""
    h = rng.uniform(0.01, 1) / 2
    return np.array([[-h, h, 0], [h, h, 0], [h, -h, 0], [-h, -h, 0]], np.float32)


def project(points, rvec, tvec, K, dist=None) -> np.ndarray:
    return cv2.projectPoints(np.asarray(points, np.float64), rvec, tvec, K, dist)[0].reshape(-1, 2)


def _diff(a, b) -> float:
    return float(np.linalg.norm(np.asarray(a, np.float64).ravel() - np.ravel(b)))


# ----------------------------------------------------------------------------- cases


def accuracy(points, eps_r, eps_t, mode):
    """`solvePnP` accuracy: exact float32 projections of `points` by a random camera and
    pose; a trial succeeds when the pose is within `eps` (L2) of the truth."""

    def run(solver: Solver, rng, trials: int) -> dict:
        good = 0
        for _ in range(trials):
            K, dist = camera(rng), distortion(rng, mode)
            rvec, tvec = pose(points, rng)
            img = project(points, rvec, tvec, K, dist).astype(np.float32)
            ok, r, t = solver.pnp(points, img, K, dist)
            good += bool(ok) and _diff(r, rvec) < eps_r and _diff(t, tvec) < eps_t
        return {"rate": good / trials, "passed": good >= PASS_RATE * trials}

    return run


def ransac_accuracy(points, eps, mode, outliers=True):
    """`solvePnPRansac` accuracy: as `accuracy`, with 5% of the pixels replaced by
    another point's (wrong matches); inlier threshold 0.5 px, as many iterations as
    points, confidence 0.99. A trial succeeds when no right match is left out and the
    pose is within `eps` of the truth."""

    def run(solver: Solver, rng, trials: int) -> dict:
        good, n = 0, len(points)
        for _ in range(trials):
            K, dist = camera(rng), distortion(rng, mode)
            rvec, tvec = pose(points, rng)
            img = project(points, rvec, tvec, K, dist).astype(np.float32)
            wrong = 0
            for i in range(n):
                if outliers and rng.uniform() > 0.95:
                    img[i] = img[rng.integers(0, n - 1)]
                    wrong += 1
            ok, r, t, inl = solver.ransac(points, img, K, dist, n, 0.5, 0.99)
            count = 0 if inl is None else len(inl)
            good += (
                bool(ok) and count + wrong >= n and _diff(r, rvec) < eps and _diff(t, tvec) < eps
            )
        return {"rate": good / trials, "passed": good >= PASS_RATE * trials}

    return run


_K548 = np.array(
    [
        [5.4794130238156129e2, 0, 2.9835545700043139e2],
        [0, 5.4817724002728005e2, 2.3062194051986233e2],
        [0, 0, 1],
    ]
)


def _ransac_points():
    """The 10 matches of OpenCV's RANSAC input tests (integers; not a real view)."""
    obj, img = [], []
    for i in range(0, 10, 2):
        obj += [(5 + i, 3, 2), (5 + i, 3 + i, 2 + i)]
        img += [(0, i), (-i, i)]
    return np.array(obj, np.float32), np.array(img, np.float32)


def ransac_input_type(solver: Solver, rng, trials: int) -> dict:
    """Every layout of the same matches: a pose each time, the same to 1e-6."""
    obj, img = _ransac_points()
    layouts = [
        (obj, img),
        (obj.reshape(-1, 1, 3), img.reshape(-1, 1, 2)),
        (obj.reshape(1, -1, 3), img.reshape(1, -1, 2)),
        (obj.reshape(-1, 3), img.reshape(-1, 2)),
    ]
    out = [solver.ransac(o, i, _K548, None) for o, i in layouts]
    same = all(_diff(o[1], out[0][1]) <= 1e-6 and _diff(o[2], out[0][2]) <= 1e-6 for o in out)
    return {"passed": all(bool(o[0]) for o in out) and same}


def ransac_double_support(solver: Solver, rng, trials: int) -> dict:
    """float32 and float64 matches give the same pose to 1e-3 (OpenCV: P3P samples,
    threshold 8 px, 100 iterations, confidence 0.999)."""
    obj, img = _ransac_points()
    a = solver.ransac(obj, img, _K548, None, 100, 8.0, 0.999, True)
    b = solver.ransac(
        obj.astype(np.float64), img.astype(np.float64), _K548, None, 100, 8.0, 0.999, True
    )
    ok = np.abs(np.ravel(a[1]) - np.ravel(b[1])).max() <= 1e-3
    return {"passed": bool(ok and np.abs(np.ravel(a[2]) - np.ravel(b[2])).max() <= 1e-3)}


def ransac_bad_input_points(solver: Solver, rng, trials: int) -> dict:
    """OpenCV's issue 19253 data (K = I, threshold 4/460): a pose with 5 inliers."""
    img = np.array(
        [
            [-5.38358629e-01, -5.09638414e-02],
            [-5.07192254e-01, -2.20743284e-01],
            [-5.43107152e-01, -4.90474701e-02],
            [-5.54325163e-01, -1.86715424e-01],
            [-5.59334219e-01, -4.01909500e-02],
            [-5.43504596e-01, -4.61776406e-02],
        ],
        np.float32,
    )
    obj = np.array(
        [
            [-3.01153604e-02, -1.55665115e-01, 4.50000018e-01],
            [4.27827090e-01, 4.28645730e-01, 1.08600008e00],
            [-3.14165242e-02, -1.52656138e-01, 4.50000018e-01],
            [-1.46217480e-01, 5.57961613e-02, 7.17000008e-01],
            [-4.89348806e-02, -1.38795510e-01, 4.47000027e-01],
            [-3.13065052e-02, -1.52636901e-01, 4.51000035e-01],
        ],
        np.float32,
    )
    ok, r, t, inl = solver.ransac(obj, img, np.eye(3), None, 100, 4 / 460, 0.99)
    return {"passed": bool(ok) and inl is not None and len(inl) == 5}


def pnp_input_type(solver: Solver, rng, trials: int) -> dict:
    """A cube of side 0.2 (8 points), a tag of side 0.05 (4) and the cube's first 4
    points, each in float32 and float64 in every combination: the pose within 1e-3 of
    the truth; `solvePnPGeneric`'s first pose too."""
    L = 0.1
    cube = np.array(
        [
            (-L, -L, -L),
            (L, -L, -L),
            (L, L, -L),
            (-L, L, -L),
            (-L, -L, L),
            (L, -L, L),
            (L, L, L),
            (-L, L, L),
        ]
    )
    h = 0.025
    tag4 = np.array([(-h, h, 0), (h, h, 0), (h, -h, 0), (-h, -h, 0)])
    rvec, tvec = np.array([0.1, -0.25, 0.467]), np.array([-0.21, 0.12, 0.746])
    passed = True
    for obj in (cube, tag4, cube[:4]):
        img = project(obj, rvec, tvec, _K548)
        for o, i in (
            (obj, img),
            (obj.astype(np.float32), img.astype(np.float32)),
            (obj.astype(np.float32), img),
            (obj, img.astype(np.float32)),
        ):
            ok, r, t = solver.pnp(o, i, _K548, None)
            close = (
                np.abs(np.ravel(r) - rvec).max() <= 1e-3
                and np.abs(np.ravel(t) - tvec).max() <= 1e-3
            )
            n, rs, ts, _ = solver.generic(o, i, _K548, None)
            gclose = n > 0 and np.abs(np.ravel(rs[0]) - rvec).max() <= 1e-3
            passed = passed and bool(ok) and close and gclose
    return {"passed": bool(passed)}


def generic(dtype):
    """`solvePnPGeneric` on 6 points (a square of side 0.2 and two off its plane), K of
    605 px, random poses: some pose within 1e-4 (L2) of the truth, errors ascending."""
    L = 0.1
    obj = np.array(
        [(-L, L, 0), (L, L, 0), (L, -L, 0), (-L, -L, 0), (-L, L, L / 2), (0, 0, -L / 2)], dtype
    )
    K = np.array([[605.4, 0, 317.35], [0, 601.2, 242.63], [0, 0, 1]], dtype)

    def run(solver: Solver, rng, trials: int) -> dict:
        good = 0
        for _ in range(10):
            rvec, tvec = pose(obj, rng)
            img = project(obj, rvec, tvec, K.astype(np.float64)).astype(dtype)
            n, rs, ts, errs = solver.generic(obj, img, K, None)
            e = np.ravel(errs)
            found = any(_diff(r, rvec) < 1e-4 and _diff(t, tvec) < 1e-4 for r, t in zip(rs, ts))
            good += n > 0 and bool(np.all(np.diff(e) >= 0)) and found
        return {"rate": good / 10, "passed": good == 10}

    return run


def invalid_pose(solver: Solver, rng, trials: int) -> dict:
    """OpenCV's issue 25094: 6 matches for which OpenCV's iterative method returned `ok`
    with a pose of huge reprojection error. OpenCV's test asks for `ok` False; the
    matches do have an exact pose (the camera looking along the model's y axis, 10
    units away: the points on that axis image alike), so the rule here is the test's
    intent: no `ok` with a pose that does not explain the matches (RMS error above
    1 px)."""
    obj = np.array([(0, 0, 0), (1, 0, 0), (0, 0, 1), (-1, 0, 0), (0, 0, -1), (0, 2, 0)], np.float32)
    img = np.array(
        [(500, 500), (600, 500), (500, 400), (400, 500), (500, 600), (500, 500)], np.float32
    )
    K = np.array([[1000.0, 0, 500], [0, 1000, 500], [0, 0, 1]])
    ok, r, t = solver.pnp(obj, img, K, np.zeros(4))
    error = np.sqrt(np.mean(np.sum((project(obj, r, t, K) - img) ** 2, axis=1)))
    return {"passed": not ok or bool(error < 1.0)}


def refine(points, truth, start, dtype):
    """From a given pose (`useExtrinsicGuess`) on exact data: the truth to 1e-6."""

    def run(solver: Solver, rng, trials: int) -> dict:
        obj = np.asarray(points, dtype)
        K = np.array([[605.4, 0, 317.35], [0, 601.2, 242.63], [0, 0, 1]], dtype)
        img = project(obj, truth[0], truth[1], K.astype(np.float64)).astype(dtype)
        if solver is CV2 and len(obj) < 4:  # OpenCV's test refines 3 points with RefineLM
            r, t = cv2.solvePnPRefineLM(
                obj,
                img,
                K,
                None,
                np.array(start[0], dtype).reshape(3, 1),
                np.array(start[1], dtype).reshape(3, 1),
            )
            ok = True
        else:
            ok, r, t = solver.pnp(obj, img, K, None, start[0], start[1], True)
        close = (
            np.abs(np.ravel(r) - truth[0]).max() <= 1e-6
            and np.abs(np.ravel(t) - truth[1]).max() <= 1e-6
        )
        return {"passed": bool(ok) and bool(close)}

    return run


def normalised(solver: Solver, rng, trials: int) -> dict:
    """A cube of side 1 in normalised coordinates (K = I): the truth to 1e-6."""
    L = 0.5
    obj = np.array([(-L, -L, L), (L, -L, L), (L, L, L), (-L, L, L), (-L, -L, -L), (L, -L, -L)])
    rvec, tvec = np.array([0.407, 0.092, 0.88]), np.array([0.576, -0.43, 1.3798])
    img = project(obj, rvec, tvec, np.eye(3))
    ok, r, t = solver.pnp(obj, img, np.eye(3), None)
    return {"passed": bool(ok) and _diff(r, rvec) < 1e-6 and _diff(t, tvec) < 1e-6}


# ----------------------------------------------------------------------------- USAC


#: The inlier ratios of `test_usac.cpp`'s accuracy loop: 0.1, 0.2, ..., 0.9.
USAC_RATIOS = tuple(k / 10 for k in range(1, 10))


def _euler(rng) -> np.ndarray:
    """`test_usac.cpp`'s rotation: `Rz(yaw) Ry(pitch) Rx(roll)`, each angle uniform in
    [-30, 30] degrees."""
    pitch, yaw, roll = rng.uniform(-np.pi / 6, np.pi / 6, 3)
    c, s = np.cos, np.sin
    Rx = np.array([[1, 0, 0], [0, c(roll), -s(roll)], [0, s(roll), c(roll)]])
    Ry = np.array([[c(pitch), 0, s(pitch)], [0, 1, 0], [-s(pitch), 0, c(pitch)]])
    Rz = np.array([[c(yaw), -s(yaw), 0], [s(yaw), c(yaw), 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def usac_problem(rng, n: int, ratio: float, noise: float):
    """`test_usac.cpp`'s PnP problem: `int(ratio n)` right matches first, object points
    uniform in [0, 1]^3 seen by the rotation of `_euler` and a translation with x, y in
    [-0.5, 0.5], z in [1, 2] (moved back along z by the nearest depth + 1 where a point
    is behind the camera), and a camera with fx, fy in [100, 1000] px, cx = 100, cy in
    [-100, 100]; then wrong matches, pixels uniform in [0, 1000]^2 and object points in
    [0, 1000]^3; every pixel with Gaussian noise of deviation `noise`. Returns `(obj,
    img, K, inliers)` (float64; `inliers` the count of right matches)."""
    R = _euler(rng)
    t = np.array([*rng.uniform(-0.5, 0.5, 2), rng.uniform(1, 2)])
    K = np.array(
        [[rng.uniform(100, 1000), 0, 100], [0, rng.uniform(100, 1000), rng.uniform(-100, 100)]]
    )
    K = np.vstack([K, [0, 0, 1]])
    right = int(ratio * n)
    obj = rng.uniform(0, 1, (right, 3))
    nearest = (obj @ R.T + t)[:, 2].min()
    if nearest < 0:
        t[2] -= nearest + 1
    cam = (obj @ R.T + t) @ K.T
    img = cam[:, :2] / cam[:, 2:]
    img = np.vstack([img, rng.uniform(0, 1000, (n - right, 2))])
    obj = np.vstack([obj, rng.uniform(0, 1000, (n - right, 3))])
    return obj, img + rng.normal(0, noise, img.shape), K, right


def usac_inliers_hold(out, obj, img, K, threshold: float, right: int) -> bool:
    """`test_usac.cpp`'s check of a RANSAC answer `(ok, rvec, tvec, inliers)`: `ok`,
    every match reported as an inlier within `1.001 threshold` px of its projection by
    the pose, and more than 80% of the right matches reported."""
    ok, r, t, inl = out
    if not ok or inl is None:
        return False
    index = np.asarray(inl, np.int64).ravel()
    if len(index) <= 0.8 * right:
        return False
    error = np.linalg.norm(project(obj[index], r, t, K) - img[index], axis=1)
    return bool(np.all(error < 1.001 * threshold))


def _usac_iterations(ratio: float, sample: int = 3, confidence: float = 0.99) -> int:
    """`test_usac.cpp`'s iteration budget: RANSAC's bound with a margin of 1.3."""
    return int(1.3 * np.log(1 - confidence) / np.log(1 - ratio**sample))


def usac_accuracy(n: int):
    """`test_usac.cpp`'s P3P accuracy test: problems of `usac_problem` (noise 0.15 px)
    at the inlier ratios of `USAC_RATIOS`, threshold 2 px, confidence 0.99, OpenCV's
    iteration budget for the ratio; `cv2` with each of `USAC_FLAGS`. OpenCV runs each
    ratio once, from its seeded generator, and asserts `usac_inliers_hold` of every
    answer; here trial `k` is one fresh problem at ratio `USAC_RATIOS[k % 9]`, which
    holds when every answer holds, and the case passes as OpenCV's accuracy tests do
    (`PASS_RATE` of its trials)."""

    def run(solver: Solver, rng, trials: int) -> dict:
        good = 0
        for k in range(trials):
            ratio = USAC_RATIOS[k % len(USAC_RATIOS)]
            obj, img, K, right = usac_problem(rng, n, ratio, 0.15)
            outs = solver.usac(obj, img, K, _usac_iterations(ratio), 2.0, 0.99)
            good += all(usac_inliers_hold(o, obj, img, K, 2.0, right) for o in outs)
        return {"rate": good / trials, "passed": good >= PASS_RATE * trials}

    return run


def usac_params(n: int):
    """`test_usac.cpp`'s default-parameters test, its P3P part: `cv2.UsacParams()`
    (threshold 1.5 px, confidence 0.99, 5,000 iterations) on a problem whose inlier
    ratio is the lowest those parameters cover, `(1 - 0.01^(1/5000))^(1/3)` (9.7%), with
    noise 0.01 px; a trial holds when `usac_inliers_hold` does (OpenCV: one seeded
    problem; here `PASS_RATE` of fresh ones). (Its P6P part estimates the camera matrix
    too: not a calibrated problem, left out.)"""

    def run(solver: Solver, rng, trials: int) -> dict:
        params = cv2.UsacParams()
        ratio = (1 - np.exp(np.log(1 - params.confidence) / params.maxIterations)) ** (1 / 3)
        good = 0
        for _ in range(trials):
            obj, img, K, right = usac_problem(rng, n, ratio, 0.01)
            out = solver.usac_params(obj, img, K)
            good += usac_inliers_hold(out, obj, img, K, params.threshold, right)
        return {"rate": good / trials, "passed": good >= PASS_RATE * trials}

    return run


def usac_camera_view(solver: Solver, rng, trials: int) -> dict:
    """`test_usac.cpp`'s regression 21105: 100 matches, 10% right (noise 0.15 px),
    threshold 2 px, `USAC_DEFAULT`; the camera matrix given as itself and as the first
    three columns of a 3x4 matrix (a strided view): a pose both times, the same pose and
    inliers. Every trial must hold (OpenCV asserts equality)."""
    iterations = _usac_iterations(0.1)
    for _ in range(max(1, trials // 4)):
        obj, img, K, right = usac_problem(rng, 100, 0.1, 0.15)
        view = np.hstack([K, np.zeros((3, 1))])[:, :3]
        a = solver.usac(obj, img, K, iterations, 2.0, 0.99)[0]
        b = solver.usac(obj, img, view, iterations, 2.0, 0.99)[0]
        same = (
            bool(a[0])
            and bool(b[0])
            and np.array_equal(a[1], b[1])
            and np.array_equal(a[2], b[2])
            and np.array_equal(np.ravel(a[3]), np.ravel(b[3]))
        )
        if not same:
            return {"passed": False}
    return {"passed": True}


def cases(points: int = 100) -> dict[str, Callable]:
    """Every case, by name: `fn(solver, rng, trials) -> {"passed": bool, ...}`."""
    seed = np.random.default_rng(2024)
    c3 = cloud(seed, points)
    plane = planar_cloud(seed, 30)
    square = tag(seed)
    p5 = [(-0.1, -0.1, 0.0), (0.1, -0.1, 0.0), (0.1, 0.1, 0.0), (-0.1, 0.1, 0.05), (0, 0, -0.05)]
    t64 = (np.array([0.3, -0.2, 0.75]), np.array([0.15, -0.2, 1.5]))
    t32 = (np.array([-0.75, 0.4, 0.34]), np.array([-0.15, 0.35, 1.58]))
    return {
        "solvePnP accuracy, 3D cloud": accuracy(c3, 1e-6, 1e-6, 0),
        "solvePnP accuracy, 3D cloud, distortion": accuracy(c3, 1e-6, 1e-6, 1),
        "solvePnP accuracy, planar": accuracy(plane, 1e-6, 1e-6, 0),
        "solvePnP accuracy, planar, distortion": accuracy(plane, 1e-4, 1e-4, 1),
        "solvePnP accuracy, planar tag (4 points)": accuracy(square, 1e-6, 1e-6, 0),
        "solvePnP accuracy, planar tag, distortion": accuracy(square, 1e-4, 1e-4, 1),
        "solvePnPRansac accuracy, 3D cloud": ransac_accuracy(c3, 1e-2, 0),
        "solvePnPRansac accuracy, 3D cloud, distortion": ransac_accuracy(c3, 1e-2, 1),
        "solvePnPRansac accuracy, planar": ransac_accuracy(plane, 1e-2, 0),
        "solvePnPRansac accuracy, planar tag": ransac_accuracy(square, 1e-2, 0, outliers=False),
        "solvePnPRansac input layouts": ransac_input_type,
        "solvePnPRansac float32 and float64": ransac_double_support,
        "solvePnPRansac issue 19253 data": ransac_bad_input_points,
        "solvePnP input types": pnp_input_type,
        "solvePnPGeneric, float64": generic(np.float64),
        "solvePnPGeneric, float32": generic(np.float32),
        "solvePnP no ok with a huge error (issue 25094)": invalid_pose,
        "solvePnP refine from a guess, float64": refine(
            p5, t64, ((0.1, -0.1, 0.1), (0, -0.5, 1)), np.float64
        ),
        "solvePnP refine from a guess, float32": refine(
            p5, t32, ((-0.1, 0.1, 0.1), (0, 0, 1)), np.float32
        ),
        "refine 3 points from a guess": refine(
            p5[:3], t64, ((0.2, -0.1, 0.6), (0.05, -0.05, 1)), np.float64
        ),
        "solvePnP normalised coordinates (K = I)": normalised,
        "USAC P3P accuracy, inlier ratios 0.1-0.9": usac_accuracy(points),
        "USAC default parameters (UsacParams), P3P": usac_params(points),
        "USAC camera matrix as a 3x4 view (issue 21105)": usac_camera_view,
    }


# ----------------------------------------------------------------------------- IPPE


def _residuals(obj, img, K, dist, x):
    """The pixel residuals of the pose `x = (rvec, tvec)` and their Jacobian `(2 n, 6)`
    (OpenCV's, `cv2.projectPoints`)."""
    proj, J = cv2.projectPoints(obj, x[:3], x[3:], K, dist)
    return (proj.reshape(-1, 2) - img).ravel(), J[:, :6]


def _gradient_hessian(obj, img, K, dist, x):
    """The gradient of `f = |residuals|^2 / 2` at `x`, its Hessian (central differences
    of the analytic gradient, symmetrised) and the Gauss-Newton matrix `J^T J`."""
    r, J = _residuals(obj, img, K, dist, x)
    H = np.empty((6, 6))
    for j in range(6):
        e = np.zeros(6)
        e[j] = 1e-6 * max(1.0, abs(x[j]))
        rp, Jp = _residuals(obj, img, K, dist, x + e)
        rm, Jm = _residuals(obj, img, K, dist, x - e)
        H[:, j] = (Jp.T @ rp - Jm.T @ rm) / (2 * e[j])
    return J.T @ r, (H + H.T) / 2, J.T @ J


def local_minimum(obj, img, K, dist, rvec, tvec, steps: int = 30):
    """The local minimum of OpenCV's reprojection error whose basin holds `(rvec,
    tvec)`, by damped Newton steps (OpenCV's residuals and Jacobian, the Hessian by
    central differences; numpy only), and whether it is one: `(rvec, tvec, ok)`, `ok`
    when the last Gauss-Newton step is small and the
    Hessian, scaled by the diagonal of `J^T J`, is positive definite, and every point
    is in front of the camera (the reprojection error cannot tell a pose from its
    reflection through the camera centre, behind it). The step bound is `1e-6` (rad;
    relative to `|t|`): below it the error changes by less than its rounding."""
    x = np.r_[np.ravel(rvec), np.ravel(tvec)].astype(np.float64)

    def f(x):
        return 0.5 * np.sum(_residuals(obj, img, K, dist, x)[0] ** 2)

    mu = 0.0
    for _ in range(steps):
        g, H, JTJ = _gradient_hessian(obj, img, K, dist, x)
        D = np.diag(np.diag(JTJ))
        try:
            step = -np.linalg.solve(H + mu * D, g)
        except np.linalg.LinAlgError:
            mu = max(1e-3, 10 * mu)
            continue
        if f(x + step) <= f(x):
            x, mu = x + step, mu / 10
        else:
            mu = max(1e-3, 10 * mu)
        if np.abs(step).max() < 1e-14 * max(1.0, np.abs(x).max()):
            break
    g, H, JTJ = _gradient_hessian(obj, img, K, dist, x)
    scale = 1 / np.sqrt(np.diag(JTJ))
    newton = np.linalg.solve(JTJ, g)
    small = np.abs(newton[:3]).max() < 1e-6 and np.abs(newton[3:]).max() < 1e-6 * max(
        np.abs(x[3:]).max(), 1e-300
    )
    definite = np.linalg.eigvalsh(scale[:, None] * H * scale[None, :]).min() > 0
    depth = (np.asarray(obj, np.float64).reshape(-1, 3) @ cv2.Rodrigues(x[:3])[0].T)[:, 2] + x[5]
    ok = bool(np.all(np.isfinite(x)) and small and definite and np.all(depth > 0))
    rvec = cv2.Rodrigues(cv2.Rodrigues(x[:3])[0])[0]  # |rvec| <= pi
    return rvec.reshape(3, 1), x[3:].reshape(3, 1), ok


def _refined_ippe(obj, img, K, dist):
    """IPPE's two poses, each refined to its local minimum of the reprojection error by
    OpenCV alone: `cv2.solvePnPRefineLM` from it (its 20 iterations can stop short in
    the flat valleys of the planar ambiguity, up to 0.03 rad from the bottom, measured
    even with 200), then `local_minimum`'s Newton steps to the bottom of that valley. A
    start that leads to no local minimum in front of the camera is left out (IPPE's
    poses can lie behind it: 2 problems of 1,000 of `planar_case`, seed 30)."""
    n, rs, ts, _ = cv2.solvePnPGeneric(obj, img, K, dist, flags=cv2.SOLVEPNP_IPPE)
    out = []
    for r, t in zip(rs, ts, strict=True):
        r, t = cv2.solvePnPRefineLM(obj, img, K, dist, r.copy(), t.copy())
        r, t, ok = local_minimum(obj, img, K, dist, r, t)
        if ok:
            out.append((r, t))
    return out


def _error(obj, img, K, dist, r, t):
    proj = cv2.projectPoints(obj, r, t, K, dist)[0].reshape(-1, 2)
    return np.linalg.norm(proj - img) / np.sqrt(2 * len(obj))


def _matches(ours, theirs, obj, img, K, dist):
    """One local minimum: the same pose (to the solvers' tolerance: rotations within
    1e-5 rad, whatever their rotation vectors' turns) and error."""
    (r, t), (rc, tc) = ours, theirs
    Ra, Rb = (
        cv2.Rodrigues(np.asarray(r, np.float64))[0],
        cv2.Rodrigues(np.asarray(rc, np.float64))[0],
    )
    angle = np.arccos(np.clip((np.trace(Ra.T @ Rb) - 1) / 2, -1, 1))
    close = angle < 1e-5 and np.abs(t - tc).max() < 1e-5 * np.abs(tc).max()
    e, ec = _error(obj, img, K, dist, r, t), _error(obj, img, K, dist, rc, tc)
    return close and abs(e - ec) <= 1e-9 * ec


def planar_case(rng, dist=None, max_points: int = 11):
    """A noisy view of 4 to `max_points` points of the plane z = 0 (the IPPE
    comparison's problem; `tests/api/test_generic.py` keeps to 8, one bucket)."""
    n = int(rng.integers(4, max_points + 1))
    obj = np.c_[rng.uniform(-1, 1, (n, 2)), np.zeros(n)]
    K = np.array([[rng.uniform(300, 2000), 0, 320], [0, 0, 240], [0, 0, 1]])
    K[1, 1] = K[0, 0] * rng.uniform(0.9, 1.1)
    rvec = rng.normal(0, 0.6, 3)
    tvec = np.array([*rng.normal(0, 0.5, 2), rng.uniform(4, 15)])
    img = cv2.projectPoints(obj, rvec, tvec, K, dist)[0].reshape(-1, 2)
    return obj, img + rng.normal(0, rng.uniform(0.1, 2.0), img.shape), K


def p3p_case(rng, dist=None):
    """Four matches of a general (non-coplanar) model, as `planar_case` otherwise."""
    obj = rng.uniform(-1, 1, (4, 3))
    K = np.array([[rng.uniform(300, 2000), 0, 320], [0, 0, 240], [0, 0, 1]])
    K[1, 1] = K[0, 0]
    rvec = rng.normal(0, 0.6, 3)
    tvec = np.array([*rng.normal(0, 0.5, 2), rng.uniform(4, 15)])
    img = cv2.projectPoints(obj, rvec, tvec, K, dist)[0].reshape(-1, 2)
    return obj, img + rng.normal(0, rng.uniform(0.1, 2.0), img.shape), K


def compare_minima(obj, img, K, dist, reference) -> tuple[bool, int]:
    """`(same, count)`: whether `solve_pnp_generic`'s poses hold every pose of
    `reference` (local minima found by OpenCV), each of its own poses is a distinct
    local minimum (`local_minimum`: it does not move, and the Hessian is positive
    definite), sorted by OpenCV's error, given with it; and how many it found."""
    count, rvecs, tvecs, errs = jp.solve_pnp_generic(obj, img, K, dist)
    ours = list(zip(rvecs, tvecs, strict=True))
    if count == 0:
        return False, count
    for (r, t), e in zip(ours, errs[:, 0], strict=True):
        if not np.isclose(e, _error(obj, img, K, dist, r, t), rtol=1e-9):
            return False, count
        rm, tm, ok = local_minimum(obj, img, K, dist, r, t)
        if not ok or not _matches((r, t), (rm, tm), obj, img, K, dist):
            return False, count
    if list(errs[:, 0]) != sorted(errs[:, 0]):
        return False, count
    for i, a in enumerate(ours):
        if any(_matches(a, b, obj, img, K, dist) for b in ours[:i]):
            return False, count
    found = all(any(_matches(o, c, obj, img, K, dist) for o in ours) for c in reference)
    return found, count


def compare_with_ippe(obj, img, K, dist=None) -> tuple[bool, int]:
    """`compare_minima` against IPPE's two poses refined to their minima
    (`_refined_ippe`): both are among `solve_pnp_generic`'s poses, and those are local
    minima. (Where IPPE's two poses refine to one minimum, or one to none,
    `solve_pnp_generic` may find more minima than IPPE: each is checked to be one.)"""
    return compare_minima(obj, img, K, dist, _refined_ippe(obj, img, K, dist))


def refined_p3p(obj, img, K, dist=None, flags: int = cv2.SOLVEPNP_P3P):
    """`cv2.solvePnPGeneric(..., flags)`'s poses (by default P3P's, 4 matches), each
    refined by `cv2.solvePnPRefineLM` and `local_minimum`: those that are local minima,
    distinct."""
    n, rs, ts, _ = cv2.solvePnPGeneric(obj, img, K, dist, flags=flags)
    out = []
    for r, t in zip(rs, ts, strict=True):
        r, t = cv2.solvePnPRefineLM(obj, img, K, dist, r.copy(), t.copy())
        r, t, ok = local_minimum(obj, img, K, dist, r, t)
        if ok and not any(_matches((r, t), o, obj, img, K, dist) for o in out):
            out.append((r, t))
    return out


def ippe_share(problems: int, seed: int = 30) -> dict:
    """`solve_pnp_generic` on `problems` planar problems (`planar_case`): the share whose
    minima hold IPPE's two refined ones and are all local minima (`compare_with_ippe`),
    and the share with two or more."""
    rng = np.random.default_rng(seed)
    same = twos = 0
    for _ in range(problems):
        obj, img, K = planar_case(rng)
        ok, count = compare_with_ippe(obj, img, K)
        same += ok
        twos += count >= 2
    return {"problems": problems, "same_as_ippe": same / problems, "two_minima": twos / problems}


def run_case(fn: Callable, solver: Solver, trials: int, seed: int = 0) -> dict:
    """One case on one solver, its random draws from `seed` (the same for every solver)."""
    start = time.perf_counter()
    out = fn(solver, np.random.default_rng(seed), trials)
    out["seconds"] = time.perf_counter() - start
    return out


def main(argv=None) -> dict:
    from benchmarks._harness import write_json

    p = argparse.ArgumentParser(description=(__doc__ or "").split("\n")[0])
    p.add_argument("--trials", type=int, default=100)
    p.add_argument("--quick", action="store_true", help="20 trials per accuracy case")
    p.add_argument("--planar", type=int, default=1000, help="planar problems against IPPE")
    p.add_argument("--out", default=str(RESULTS))
    args = p.parse_args(argv)
    trials = 20 if args.quick else args.trials
    planar = 100 if args.quick else args.planar
    rows = []
    for k, (name, fn) in enumerate(cases().items()):
        row: dict[str, Any] = {"case": name}
        for solver in (CV2, JAXPOSE):
            row[solver.name] = run_case(fn, solver, trials, seed=k)
        rows.append(row)
        cv, ours = row["cv2"], row["jaxpose"]
        print(f"{name}: cv2 {cv['passed']} {cv.get('rate', '')}", end="", flush=True)
        print(f", jaxpose {ours['passed']} {ours.get('rate', '')}", flush=True)
    ippe = ippe_share(planar)
    print(f"planar problems whose minima are IPPE's two, refined: {ippe}", flush=True)
    result = {
        "benchmark": "OpenCV's solvePnP/solvePnPRansac/solvePnPGeneric test cases",
        "ippe": ippe,
        "trials": trials,
        "pass_rate": PASS_RATE,
        "rows": rows,
        "jaxpose_passes_every_cv2_pass": all(
            r["jaxpose"]["passed"] or not r["cv2"]["passed"] for r in rows
        ),
    }
    write_json(args.out, result)
    return result


if __name__ == "__main__":
    main()
