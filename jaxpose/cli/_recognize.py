"""`jaxpose recognize`: the known objects a photograph shows, and their poses, from mesh
models (the vertex path, without correspondences) and textured models (the keypoint
path), printed, written as JSON (`--json`) and recorded for rerun (`--rrd`).

Detections are listed polyhedral first, best first as `jaxpose.apps.detect` ranks them
(by the evidence their pose explains), then textured ones by their number of inliers.
Poses are OpenCV's (`x_cam = Rodrigues(rvec) X + tvec`); pixels are those of the image
as given (distorted, when the camera has distortion).
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ._common import CliError, camera_option, new_console, setup_jax, write_report
from ._recording import check_recording_args, make_recording, wants_recording

if TYPE_CHECKING:  # pragma: no cover
    import numpy as np

    from ..apps._polyhedron import Polyhedron
    from ..apps._recognize import Recognition
    from ..features._keypoints import TexturedModel

__all__ = ["cmd_recognize", "detections_report"]

#: Model file suffixes: meshes (the vertex path) and textured models (the keypoint path).
MESH_SUFFIXES = (".ply",)
TEXTURED_SUFFIXES = (".yml", ".yaml", ".xml", ".json")


def _kind(path: Path) -> str:
    """`"mesh"` or `"textured"` by the file's suffix (a `.gz` after a textured one)."""
    name = path.name.lower()
    if name.endswith(MESH_SUFFIXES):
        return "mesh"
    if name.removesuffix(".gz").endswith(TEXTURED_SUFFIXES):
        return "textured"
    raise CliError(
        f"--model {path}: unknown model format (a .ply mesh, or a textured model "
        ".yml/.yaml/.xml/.json, optionally .gz)"
    )


def _read_models(paths: list[str]) -> dict[str, Polyhedron | TexturedModel]:
    """The models of the `--model` files, by name (each file's name without suffixes)."""
    from ..apps._mesh import read_ply
    from ..features._keypoints import read_textured_model

    models: dict[str, Polyhedron | TexturedModel] = {}
    for raw in paths:
        path = Path(raw)
        if not path.is_file():
            raise CliError(f"--model {path}: no such file")
        kind = _kind(path)
        try:
            model = read_ply(path) if kind == "mesh" else read_textured_model(path)
        except ValueError as exc:
            raise CliError(f"--model {path}: {exc}") from None
        if model.name in models:
            raise CliError(f"--model {path}: a model named {model.name!r} is given twice")
        models[model.name] = model
    return models


def _meshes_for_textured(models: dict) -> dict[str, Polyhedron]:
    """The mesh each textured model's vertices are drawn from: the mesh of the same
    name, else the only mesh given; none when there are several others."""
    from ..apps._polyhedron import Polyhedron

    meshes = {n: m for n, m in models.items() if isinstance(m, Polyhedron)}
    out = {}
    for name, model in models.items():
        if isinstance(model, Polyhedron):
            continue
        if name in meshes:
            out[name] = meshes[name]
        elif len(meshes) == 1:
            out[name] = next(iter(meshes.values()))
    return out


def _project(points, rvec, tvec, K, dist) -> np.ndarray:
    """OpenCV's projection of `points` `(n, 3)` (`(0, 2)` for none)."""
    import cv2
    import numpy as np

    points = np.asarray(points, np.float64).reshape(-1, 3)
    if len(points) == 0:
        return np.zeros((0, 2))
    uv, _ = cv2.projectPoints(points, rvec, tvec, K, dist)
    return uv.reshape(-1, 2)


def _distorted(pixels, K, dist) -> np.ndarray:
    """Pixels of the undistorted image (same `K`) as the image given shows them."""
    import numpy as np

    pixels = np.asarray(pixels, np.float64).reshape(-1, 2)
    rays = np.column_stack([pixels, np.ones(len(pixels))]) @ np.linalg.inv(K).T
    return _project(rays, np.zeros(3), np.zeros(3), K, dist)


def _pixels(uv) -> list[list[float] | None]:
    """JSON rows of pixels; `None` for a point that does not project (never NaN)."""
    return [[float(u), float(v)] if math.isfinite(u) and math.isfinite(v) else None for u, v in uv]


def detections_report(
    recognition: Recognition, models: dict, K, dist, meshes: dict | None = None
) -> list[dict[str, Any]]:
    """The detections of `recognition` as JSON-ready rows (the `--json` file's
    `"detections"`): polyhedral ones best first, then textured ones with a pose by
    decreasing inliers. Each has `model`, `kind` (`"vertex"` or `"keypoint"`), `rvec`,
    `tvec`, `score` and `vertices` (every model vertex projected at the pose, pixels of
    the image as given; empty for a textured model without a mesh), and: `support` and
    `matched` (`{"vertex", "pixel"}` for each matched image vertex) for polyhedral
    detections; `inliers`, `matches` and `rms` (px) for textured ones."""
    import cv2
    import numpy as np

    meshes = meshes or {}
    rows: list[dict[str, Any]] = []
    for d in recognition.detections:
        rvec = cv2.Rodrigues(np.asarray(d.R, np.float64))[0].ravel()
        tvec = np.asarray(d.t, np.float64).ravel()
        matched = _distorted(d.pixels, K, dist)
        rows.append(
            {
                "model": d.model,
                "kind": "vertex",
                "rvec": rvec.tolist(),
                "tvec": tvec.tolist(),
                "score": float(d.score),
                "support": float(d.support),
                "error_px": float(d.error),
                "vertices": _pixels(_project(models[d.model].vertices, rvec, tvec, K, dist)),
                "matched": [
                    {"vertex": int(v), "pixel": p}
                    for v, p in zip(d.vertices, _pixels(matched), strict=True)
                ],
            }
        )
    textured = [(n, p) for n, p in recognition.textured.items() if p.ok]
    textured.sort(key=lambda item: -int(np.sum(item[1].inliers)))
    for name, pose in textured:
        rvec = np.asarray(pose.rvec, np.float64).ravel()
        tvec = np.asarray(pose.tvec, np.float64).ravel()
        mesh = meshes.get(name)
        inliers = int(np.sum(pose.inliers))
        rows.append(
            {
                "model": name,
                "kind": "keypoint",
                "rvec": rvec.tolist(),
                "tvec": tvec.tolist(),
                "score": float(inliers),
                "inliers": inliers,
                "matches": len(pose.inliers),
                "rms": float(pose.rms),
                "mesh": None if mesh is None else mesh.name,
                "vertices": (
                    [] if mesh is None else _pixels(_project(mesh.vertices, rvec, tvec, K, dist))
                ),
            }
        )
    return rows


def _check_options(args) -> None:
    for item in args.image:
        if not Path(item).exists():
            raise CliError(f"{item}: no such image file or folder")
    if not Path(args.camera).is_file():
        raise CliError(f"--camera {args.camera}: no such file")
    if args.noise is not None and not (math.isfinite(args.noise) and args.noise > 0):
        raise CliError(f"--noise must be a positive number of px, got {args.noise}")
    if args.min_support is not None and not 0 <= args.min_support <= 1:
        raise CliError(f"--min-support must lie in [0, 1], got {args.min_support}")
    if args.json is not None and Path(args.json).is_dir():
        raise CliError(f"cannot write --json {args.json}: a directory")
    check_recording_args(args)


#: The image files a folder given to `jaxpose recognize` contributes (sorted by name).
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp", ".pgm", ".ppm")


def _image_paths(given: list[str]) -> list[Path]:
    """The images of `given`: files as they are, folders as their image files by name."""
    paths: list[Path] = []
    for item in given:
        path = Path(item)
        if path.is_dir():
            found = sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
            if not found:
                raise CliError(f"{item}: a folder with no image file ({', '.join(IMAGE_SUFFIXES)})")
            paths += found
        else:
            paths.append(path)
    return paths


def cmd_recognize(args) -> int:
    """Run `jaxpose recognize` with the parsed `args`; returns the exit code (0: something
    is recognised in every image, 1: not)."""
    import cv2
    import numpy as np

    console = new_console()
    _check_options(args)
    K, dist = camera_option(args.camera)
    models = _read_models(args.model)
    paths = _image_paths(args.image)
    pictures = []
    for path in paths:  # every image read before anything is computed: bad input fails fast
        picture = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if picture is None:
            raise CliError(f"{path}: not an image OpenCV can read")
        pictures.append(picture)
    setup_jax(True)
    meshes = _meshes_for_textured(models)
    results = [
        _recognize_one(console, args, str(path), picture, models, meshes, K, dist)
        for path, picture in zip(paths, pictures, strict=True)
    ]
    if args.json:
        if len(results) == 1:
            report = {"detections": results[0][1]}
        else:
            pairs = zip(paths, results, strict=True)
            report = {"images": [{"image": str(p), "detections": r[1]} for p, r in pairs]}
        write_report(args.json, report, "--json", console)
    if wants_recording(args):
        from ..viz._rerun_recognition import log_recognition

        def log(rec):
            import rerun as rr

            for i, ((found, _), picture) in enumerate(zip(results, pictures, strict=True)):
                if len(results) > 1:
                    rr.set_time("image", sequence=i, recording=rec)
                shown = picture if not np.any(dist) else cv2.undistort(picture, K, dist)
                log_recognition(rec, found, models, K, meshes=meshes, image=shown[..., ::-1].copy())

        what = str(paths[0]) if len(paths) == 1 else f"{len(paths)} images"
        make_recording(args, console, f"jaxpose recognize {what}", log)
    return 0 if all(rows for _, rows in results) else 1


def _recognize_one(console, args, name: str, picture, models, meshes, K, dist):
    """One image recognised and reported: `(found, rows)`."""
    import numpy as np
    from rich.table import Table

    from ..apps._recognize import recognize

    options = {
        k: v for k, v in (("noise", args.noise), ("min_support", args.min_support)) if v is not None
    }
    with console.status(f"recognising {name}..."):
        t0 = time.perf_counter()
        try:
            found = recognize(picture, models, K, dist, **options)
        except ValueError as exc:
            raise CliError(str(exc)) from None
        elapsed = time.perf_counter() - t0
    rows = detections_report(found, models, K, dist, meshes)

    def vec(v) -> str:
        return "[" + ", ".join(f"{x:.4g}" for x in v) + "]"

    table = Table(title=f"recognised in {name} ({elapsed:.2f} s)")
    for column in ("model", "path", "score", "rvec (rad)", "tvec", "matched"):
        table.add_column(column)
    for row in rows:
        if row["kind"] == "vertex":
            count = len(row["vertices"])
            ids = " ".join(str(m["vertex"]) for m in row["matched"])
            matched = f"{len(row['matched'])} of {count} vertices: {ids}"
            score = f"{row['score']:.2f} (support {row['support']:.2f})"
        else:
            matched = f"{row['inliers']} of {row['matches']} keypoints, rms {row['rms']:.2f} px"
            score = f"{row['score']:.0f} inliers"
        table.add_row(row["model"], row["kind"], score, vec(row["rvec"]), vec(row["tvec"]), matched)
    if rows:
        console.print(table)
    for model_name, pose in found.textured.items():
        if not pose.ok:
            console.print(
                f"{model_name}: no pose agrees with enough of its {len(pose.inliers)} "
                "keypoint matches"
            )
    if found.primitives is not None:
        p = found.primitives
        console.print(
            f"image primitives: {len(p.segments.ends)} segments, "
            f"{len(p.vertices.points)} vertices, {int(np.sum(np.triu(p.links, 1)))} links"
        )
    if not rows:
        console.print(f"nothing recognised in {name}")
    return found, rows
