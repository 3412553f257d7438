"""Reading pose problems from files (JSON, OpenCV YAML, text tables; see `_problem` for
the formats) into a `Problem`."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np

from ..apps._polyhedron import Polyhedron
from ..geometry._validate import as_camera, as_dist_coeffs, as_intrinsics, as_points
from ._problem import Problem, ProblemError, _fail, _format

__all__ = ["read_fields", "read_problem"]

_PROBLEM_KEYS = {
    "camera",
    "image_size",
    "model_points",
    "polyhedron",
    "matched_vertices",
    "image_points",
    "mask",
    "true_pose",
}
_CAMERA_KEYS = {"K", "dist", "R", "rvec", "t", "C"}


# --------------------------------------------------------------------------- reading files


def _check_file(path: Path) -> None:
    if not path.exists():
        _fail(path, "no such file")
    if not path.is_file():
        _fail(path, "not a file")


def _read_json(path: Path):
    try:
        return json.loads(path.read_text())
    except UnicodeDecodeError:
        _fail(path, "not a text file")
    except json.JSONDecodeError as exc:
        _fail(path, f"invalid JSON: {exc.msg} at line {exc.lineno}, column {exc.colno}")
    except OSError as exc:
        _fail(path, f"cannot read: {exc.strerror or exc}")


def _node_value(node):
    """A `cv2.FileNode` as numpy / Python values (matrices, sequences, numbers, strings)."""
    if node.isNone() or node.empty():
        return None
    if node.isMap():
        mat = node.mat()
        if mat is not None:
            return np.asarray(mat)
        return {k: _node_value(node.getNode(k)) for k in node.keys()}
    if node.isSeq():
        return [_node_value(node.at(i)) for i in range(node.size())]
    if node.isInt():
        return int(node.real())
    if node.isReal():
        return float(node.real())
    if node.isString():
        return node.string()
    return None


def _read_yaml(path: Path) -> dict:
    import cv2

    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:  # the binding may wrap cv2.error in SystemError
        cause = exc if isinstance(exc, cv2.error) else (exc.__cause__ or exc.__context__ or exc)
        lines = [s.strip() for s in str(cause).splitlines() if s.strip()]
        reason = lines[-1] if lines else "parse error"
        # OpenCV says "... error: (-212:Parsing error) fn in function 'FILE(LINE): what'".
        where = re.search(r"\((\d+)\): (.*?)'?$", reason)
        if where:
            reason = f"line {where.group(1)}: {where.group(2)}"
        _fail(path, f"invalid OpenCV YAML/XML: {reason}")
    try:
        if not fs.isOpened():
            _fail(path, "cannot open it as OpenCV YAML/XML")
        root = fs.root()
        return {k: _node_value(root.getNode(k)) for k in root.keys()}
    finally:
        fs.release()


def _read_text(path: Path) -> np.ndarray:
    delimiter = "," if path.suffix.lower() == ".csv" else None
    try:
        arr = np.loadtxt(path, delimiter=delimiter, ndmin=2, comments="#")
    except (ValueError, UnicodeDecodeError) as exc:
        reason = str(exc).splitlines()[0] if str(exc) else "not a table of numbers"
        _fail(path, f"not a table of numbers: {reason}")
    except OSError as exc:
        _fail(path, f"cannot read: {exc.strerror or exc}")
    return arr


# --------------------------------------------------------------------------- fields


def _array(path: Path, key: str, value, *, dtype=float) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=dtype)
    except (TypeError, ValueError):
        _fail(path, f"{key} must be an array of numbers")
    if dtype is float and not np.all(np.isfinite(arr)):
        _fail(path, f"{key} contains NaN or infinite values")
    return arr


def _points(path: Path, key: str, value, dim: int) -> np.ndarray:
    arr = _array(path, key, value)
    if arr.ndim == 1 and arr.size % dim == 0 and arr.size > 0 and arr.size != dim:
        # OpenCV stores (n, 1, dim) point vectors as n x 1 matrices of `dim` channels.
        arr = arr.reshape(-1, dim)
    try:
        return as_points(arr, key, dim, min_count=3)
    except ValueError as exc:
        _fail(path, str(exc))


def _rotation(path: Path, key: str, value) -> np.ndarray:
    import cv2

    arr = _array(path, key, value)
    if arr.size == 3:
        R, _ = cv2.Rodrigues(arr.reshape(3, 1))
        return R
    if arr.shape != (3, 3):
        _fail(
            path, f"{key} must be a 3x3 rotation matrix or a rotation vector of 3, got {arr.shape}"
        )
    if not np.allclose(arr @ arr.T, np.eye(3), atol=1e-6) or np.linalg.det(arr) < 0:
        _fail(path, f"{key} is not a rotation matrix (orthonormal, det +1)")
    return arr


def _vector3(path: Path, key: str, value) -> np.ndarray:
    arr = _array(path, key, value)
    if arr.size != 3:
        _fail(path, f"{key} must have 3 numbers, got shape {arr.shape}")
    return arr.reshape(3)


def _image_size(path: Path, value) -> tuple[int, int]:
    arr = _array(path, "image_size", value).reshape(-1)
    if arr.size != 2 or not np.all(arr > 0):
        _fail(path, f"image_size must be [width, height] > 0, got {arr.tolist()}")
    return int(math.ceil(arr[0])), int(math.ceil(arr[1]))


def _mask(path: Path, value) -> np.ndarray:
    arr = np.asarray(value).reshape(-1)
    if arr.dtype == np.bool_:
        return arr
    if np.issubdtype(arr.dtype, np.number) and np.all((arr == 0) | (arr == 1)):
        return arr.astype(bool)
    _fail(path, "mask must hold booleans (or 0/1)")


def _polyhedron(path: Path, value) -> Polyhedron:
    if not isinstance(value, dict):
        _fail(path, "polyhedron must be an object with vertices, edges (and faces)")
    unknown = set(value) - {"vertices", "edges", "faces", "name"}
    if unknown:
        _fail(path, f"unknown key(s) in polyhedron: {', '.join(sorted(unknown))}")
    if "vertices" not in value or "edges" not in value:
        _fail(path, "polyhedron needs vertices and edges")
    vertices = _points(path, "polyhedron.vertices", value["vertices"], 3)
    edges = _indices(path, "polyhedron.edges", value["edges"], len(vertices))
    if edges.ndim != 2 or edges.shape[1] != 2:
        _fail(path, f"polyhedron.edges must have shape (E, 2), got {edges.shape}")
    faces = []
    for f in value.get("faces") or ():
        faces.append(tuple(int(i) for i in _indices(path, "polyhedron.faces", f, len(vertices))))
    name = str(value.get("name", path.stem))
    return Polyhedron(
        name=name, vertices=vertices, edges=edges.astype(np.int32), faces=tuple(faces)
    )


def _indices(path: Path, key: str, value, count: int) -> np.ndarray:
    arr = _array(path, key, value)
    if arr.size and (not np.all(arr == np.round(arr)) or arr.min() < 0 or arr.max() >= count):
        _fail(path, f"{key} must hold vertex indices in [0, {count})")
    return arr.astype(np.int64)


# --------------------------------------------------------------------------- per format


def _fields_from_json(path: Path, data, role: str) -> dict:
    """The raw fields of a JSON file: `role` is "problem", "model", "image" or "camera"."""
    if isinstance(data, list):
        if role == "model":
            return {"model_points": data}
        if role == "image":
            return {"image_points": data}
        _fail(path, "expected a JSON object")
    if not isinstance(data, dict):
        _fail(path, "expected a JSON object")
    if role == "camera" and "camera" not in data and set(data) & _CAMERA_KEYS:
        data = {"camera": {k: v for k, v in data.items() if k != "image_size"}} | (
            {"image_size": data["image_size"]} if "image_size" in data else {}
        )
    unknown = set(data) - _PROBLEM_KEYS
    if unknown:
        _fail(
            path,
            f"unknown key(s) {', '.join(repr(k) for k in sorted(unknown))}; expected "
            + ", ".join(sorted(_PROBLEM_KEYS)),
        )
    camera = data.get("camera")
    if camera is not None:
        if not isinstance(camera, dict):
            _fail(path, 'camera must be an object with "K" (and "dist", "R", "t") or "C"')
        unknown = set(camera) - _CAMERA_KEYS
        if unknown:
            _fail(
                path,
                f"unknown key(s) in camera: {', '.join(repr(k) for k in sorted(unknown))};"
                f" expected {', '.join(sorted(_CAMERA_KEYS))}",
            )
    return dict(data)


_YAML_CAMERA = {
    "camera_matrix": "K",
    "distortion_coefficients": "dist",
    "projection_matrix": "C",
    "camera_rotation": "R",
    "camera_translation": "t",
}


def _fields_from_yaml(path: Path, data: dict) -> dict:
    out: dict = {}
    camera = {new: data[old] for old, new in _YAML_CAMERA.items() if data.get(old) is not None}
    if camera:
        out["camera"] = camera
    if data.get("image_width") is not None and data.get("image_height") is not None:
        out["image_size"] = [data["image_width"], data["image_height"]]
    for key, new in (("object_points", "model_points"), ("image_points", "image_points")):
        if data.get(key) is not None:
            out[new] = data[key]
    if data.get("mask") is not None:
        out["mask"] = data["mask"]
    if data.get("model_vertices") is not None:
        if data.get("model_edges") is None:
            _fail(path, "model_vertices needs model_edges")
        out["polyhedron"] = {"vertices": data["model_vertices"], "edges": data["model_edges"]}
    if data.get("matched_vertices") is not None:
        out["matched_vertices"] = data["matched_vertices"]
    return out


def _fields_from_text(path: Path, table: np.ndarray, role: str) -> dict:
    if role == "model":
        return {"model_points": table}
    if role == "image":
        return {"image_points": table}
    _fail(path, f"a {path.suffix} file can only hold model or image points")


def read_fields(path, role: str = "problem") -> dict:
    """The raw fields of one file (see the module docstring), tagged with their source.

    **Arguments:**
    - `path`: the file; its suffix picks the format.
    - `role`: `"problem"` (everything), `"model"`, `"image"` or `"camera"`: what the file
      is expected to hold (bare lists and text tables need it).

    **Returns:** a dict of the fields present, values as read (not yet validated).

    **Raises:** `ProblemError` for a missing, unreadable or malformed file.
    """
    path = Path(path)
    _check_file(path)
    kind = _format(path)
    if kind == "json":
        return _fields_from_json(path, _read_json(path), role)
    if kind == "yaml":
        return _fields_from_yaml(path, _read_yaml(path))
    return _fields_from_text(path, _read_text(path), role)


# --------------------------------------------------------------------------- assembling


def _camera(path: Path, cam: dict):
    """`(C, K, dist, R_wc, t_wc)` from a camera object."""
    if "C" in cam:
        extra = set(cam) - {"C"}
        if extra:
            _fail(path, f"camera: give either C or K (with dist, R, t), not C with {sorted(extra)}")
        try:
            C = as_camera(_array(path, "camera.C", cam["C"]), "camera.C")
        except ValueError as exc:
            _fail(path, str(exc))
        return C.astype(np.float64), None, None, None, None
    if "K" not in cam:
        _fail(path, 'camera needs "K" (intrinsics) or "C" (a 3x4 projection matrix)')
    try:
        K = as_intrinsics(_array(path, "camera.K", cam["K"]), "camera.K").astype(np.float64)
        dist = as_dist_coeffs(cam.get("dist"), "camera.dist")
    except ValueError as exc:
        _fail(path, str(exc))
    if "R" in cam and "rvec" in cam:
        _fail(path, "camera: give R or rvec, not both")
    rot = cam.get("R", cam.get("rvec"))
    R = np.eye(3) if rot is None else _rotation(path, "camera.R", rot)
    t = np.zeros(3) if cam.get("t") is None else _vector3(path, "camera.t", cam["t"])
    C = K @ np.column_stack([R, t])
    return C, K, dist, R, t


def _pose(path: Path, value) -> tuple[np.ndarray, np.ndarray]:
    if (
        not isinstance(value, dict)
        or "t" not in value
        or ("R" not in value) == ("rvec" not in value)
    ):
        _fail(path, 'true_pose must be {"R" or "rvec": ..., "t": [x, y, z]}')
    R = _rotation(path, "true_pose.R", value.get("R", value.get("rvec")))
    return R, _vector3(path, "true_pose.t", value["t"])


def read_problem(
    problem=None,
    *,
    model=None,
    image=None,
    camera=None,
) -> Problem:
    """Read one pose problem from a problem file and/or separate files.

    Fields of `model`, `image` and `camera` files override those of the `problem` file.
    The image points are undistorted when the camera has distortion coefficients.

    **Arguments:**
    - `problem`: path of a file holding a whole problem (or part of it), or None.
    - `model`, `image`, `camera`: paths of files holding the model points (or polyhedron),
      the image points (and mask) and the camera (and image size), or None.

    **Returns:** a `Problem`.

    **Raises:** `ProblemError` (a `ValueError`, one line naming the file and the field)
    for missing files, bad formats, missing or malformed fields, or point counts that
    do not match.
    """
    fields: dict = {}
    origin: dict = {}
    sources = []
    for path, role in (
        (problem, "problem"),
        (model, "model"),
        (image, "image"),
        (camera, "camera"),
    ):
        if path is None:
            continue
        path = Path(path)
        got = read_fields(path, role)
        wanted = {
            "problem": None,
            "model": {"model_points", "polyhedron", "matched_vertices", "true_pose"},
            "image": {"image_points", "mask", "image_size"},
            "camera": {"camera", "image_size"},
        }[role]
        if wanted is not None:
            got = {k: v for k, v in got.items() if k in wanted}
            if not got:
                _fail(path, f"no {role} data found in it")
        fields.update(got)
        origin.update(dict.fromkeys(got, path))
        sources.append(str(path))
    if not sources:
        raise ProblemError("no input: give a problem file, or --model, --image and --camera")
    anywhere = Path(sources[0])

    def where(key: str) -> Path:
        return origin.get(key, anywhere)

    if "camera" not in fields:
        raise ProblemError(f"{', '.join(sources)}: no camera given (camera / camera_matrix)")
    if "image_points" not in fields:
        raise ProblemError(f"{', '.join(sources)}: no image points given (image_points)")
    C, K, dist, R_wc, t_wc = _camera(where("camera"), fields["camera"])

    poly = None
    if fields.get("polyhedron") is not None:
        poly = _polyhedron(where("polyhedron"), fields["polyhedron"])
    if fields.get("model_points") is not None:
        model_points = _points(where("model_points"), "model_points", fields["model_points"], 3)
    elif poly is not None and fields.get("matched_vertices") is not None:
        idx = _indices(
            where("matched_vertices"),
            "matched_vertices",
            np.asarray(fields["matched_vertices"]).reshape(-1),
            len(poly.vertices),
        )
        model_points = poly.vertices[idx]
    else:
        raise ProblemError(
            f"{', '.join(sources)}: no model points given (model_points, or a polyhedron "
            "with matched_vertices)"
        )
    observed = _points(where("image_points"), "image_points", fields["image_points"], 2)
    if len(observed) != len(model_points):
        model_source = where("model_points" if "model_points" in fields else "matched_vertices")
        raise ProblemError(
            f"{where('image_points')}: {len(observed)} image points but {len(model_points)} "
            f"model points (from {model_source}); they must match one to one"
        )
    mask = None
    if fields.get("mask") is not None:
        mask = _mask(where("mask"), fields["mask"])
        if mask.shape != (len(observed),):
            _fail(where("mask"), f"mask must have {len(observed)} entries, got {mask.size}")
        if int(mask.sum()) < 3:
            _fail(where("mask"), f"mask selects {int(mask.sum())} matches; at least 3 are needed")
    image_points = observed
    if dist is not None and K is not None:  # a distortion comes with its K
        from ..geometry._camera import undistort_pixels

        image_points = undistort_pixels(observed.astype(np.float64), K, dist)
    size = None
    if fields.get("image_size") is not None:
        size = _image_size(where("image_size"), fields["image_size"])
    true_pose = None
    if fields.get("true_pose") is not None:
        true_pose = _pose(where("true_pose"), fields["true_pose"])
    return Problem(
        camera=C,
        model_points=model_points.astype(np.float64),
        image_points=np.asarray(image_points, np.float64),
        observed_points=observed.astype(np.float64),
        mask=mask,
        K=K,
        dist=dist,
        R_wc=R_wc,
        t_wc=t_wc,
        image_size=size,
        polyhedron=poly,
        true_pose=true_pose,
        sources=tuple(sources),
    )
