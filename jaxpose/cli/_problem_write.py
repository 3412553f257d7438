"""Writing pose problems to files (JSON or OpenCV YAML, as `_problem_read` reads them
back), and the embedded bench as an example problem."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ._problem import Problem, _fail, _format

__all__ = ["bench_problem", "dumps", "write_problem"]


def bench_problem(bench) -> Problem:
    """The embedded bench (`jaxpose.default_bench`) as a `Problem`, with its polyhedron and
    true pose: an example input for `jaxpose solve`."""
    return Problem(
        camera=np.asarray(bench.camera, np.float64),
        model_points=np.asarray(bench.model_points, np.float64),
        image_points=np.asarray(bench.image_points, np.float64),
        observed_points=np.asarray(bench.image_points, np.float64),
        K=np.asarray(bench.K, np.float64),
        R_wc=np.asarray(bench.R_wc, np.float64),
        t_wc=np.asarray(bench.t_wc, np.float64),
        image_size=(int(bench.image_size[0]), int(bench.image_size[1])),
        polyhedron=bench.model,
        true_pose=(np.asarray(bench.R, np.float64), np.asarray(bench.t, np.float64)),
    )


def write_problem(path, problem: Problem) -> Path:
    """Write `problem` as a problem file that `read_problem` reads back: JSON (`.json`)
    or OpenCV YAML (`.yaml`, `.yml`), by suffix. The camera is written as `K`, `dist`,
    `R`, `t` when it was given so, else as `C`; the image points as observed. YAML holds
    no faces and no true pose."""
    path = Path(path)
    kind = _format(path)
    if kind == "text":
        _fail(path, "a problem is written as .json or .yaml")
    path.parent.mkdir(parents=True, exist_ok=True)
    if kind == "json":
        _write_json(path, problem)
    else:
        _write_yaml(path, problem)
    return path


def _camera_motion(problem: Problem) -> tuple[np.ndarray, np.ndarray]:
    """`(R_wc, t_wc)` of a problem whose camera was given as `K` (they come with it)."""
    if problem.R_wc is None or problem.t_wc is None:
        raise ValueError("a camera given as K needs its R_wc and t_wc")
    return problem.R_wc, problem.t_wc


def _write_json(path: Path, problem: Problem) -> None:
    if problem.K is not None:
        R_wc, t_wc = _camera_motion(problem)
        cam: dict = {"K": problem.K.tolist()}
        if problem.dist is not None:
            cam["dist"] = problem.dist.tolist()
        cam |= {"R": R_wc.tolist(), "t": t_wc.tolist()}
    else:
        cam = {"C": problem.camera.tolist()}
    data: dict = {"camera": cam}
    if problem.image_size is not None:
        data["image_size"] = list(problem.image_size)
    data["model_points"] = problem.model_points.tolist()
    data["image_points"] = problem.observed_points.tolist()
    if problem.mask is not None:
        data["mask"] = problem.mask.tolist()
    if problem.polyhedron is not None:
        data["polyhedron"] = {
            "vertices": problem.polyhedron.vertices.tolist(),
            "edges": problem.polyhedron.edges.tolist(),
            "faces": [list(f) for f in problem.polyhedron.faces],
        }
    if problem.true_pose is not None:
        R, t = problem.true_pose
        data["true_pose"] = {"R": R.tolist(), "t": t.tolist()}
    path.write_text(dumps(data) + "\n")


def dumps(value, indent: str = "") -> str:
    """JSON with one line per point (rows of numbers are kept on one line)."""
    inner = indent + "  "
    if isinstance(value, dict):
        items = [f"{inner}{json.dumps(k)}: {dumps(v, inner)}" for k, v in value.items()]
        return "{\n" + ",\n".join(items) + "\n" + indent + "}"
    if isinstance(value, list) and value and all(isinstance(v, list) for v in value):
        return "[\n" + ",\n".join(inner + dumps(v, inner) for v in value) + "\n" + indent + "]"
    return json.dumps(value)


def _write_yaml(path: Path, problem: Problem) -> None:
    import cv2

    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    try:
        if problem.K is not None:
            R_wc, t_wc = _camera_motion(problem)
            fs.write("camera_matrix", problem.K)
            if problem.dist is not None:
                fs.write("distortion_coefficients", problem.dist.reshape(-1, 1))
            fs.write("camera_rotation", R_wc)
            fs.write("camera_translation", t_wc.reshape(3, 1))
        else:
            fs.write("projection_matrix", problem.camera)
        if problem.image_size is not None:
            fs.write("image_width", int(problem.image_size[0]))
            fs.write("image_height", int(problem.image_size[1]))
        fs.write("object_points", problem.model_points)
        fs.write("image_points", problem.observed_points)
        if problem.mask is not None:
            fs.write("mask", problem.mask.astype(np.int32).reshape(-1, 1))
        if problem.polyhedron is not None:
            fs.write("model_vertices", np.asarray(problem.polyhedron.vertices, np.float64))
            fs.write("model_edges", np.asarray(problem.polyhedron.edges, np.int32))
    finally:
        fs.release()
