"""Tables of the accuracy benchmarks (`benchmarks/accuracy.py`, `p3p_rate.py`, `float32.py`,
`robust.py`, `gradients.py`)."""

from __future__ import annotations

import sys
from pathlib import Path

_ROOT = str(Path(__file__).resolve().parents[2])  # the repository, for `benchmarks`
if _ROOT not in sys.path:
    sys.path.insert(0, _ROOT)

from tables_format import Missing, caption, duration, load, number, share, table  # noqa: E402

from benchmarks._accuracy_report import chessboard_cells  # noqa: E402


def p3p(results: Path) -> str:
    d, name = load(results, "p3p_rate.json")
    names = [name]
    rows = dict(d["rows"])
    try:
        d32, name32 = load(results, "p3p_rate_float32.json")
        rows.update({k: v for k, v in d32["rows"].items() if k.startswith("jaxpose")})
        names.append(name32)
    except Missing:
        pass
    tol = d.get("args", {}).get("tol", 1e-6)
    out_rows = [
        (
            solver,
            f"{r['instances']:,}",
            share(r["found_rate"], 3),
            share(r["found_rate_at_1e-3"], 3),
            number(r["p999_error"]),
            f"{r['mean_solutions']:.3f}",
            r["nonfinite_solutions"],
            duration(1e-9 * r["ns_per_triplet"])
            + (" amortised" if solver.startswith("jaxpose") else " per call"),
        )
        for solver, r in rows.items()
    ]
    header = (
        "solver",
        "instances",
        f"true pose found ({tol:g})",
        "found (1e-3)",
        "99.9th-pct error",
        "solutions",
        "non-finite",
        "time per triplet",
    )
    command = "python benchmarks/p3p_rate.py --n 100000 [--dtype float32]"
    return table(header, out_rows) + "\n\n" + caption(d, *names, command=command)


def accuracy(results: Path) -> str:
    d, name = load(results, "accuracy.json")
    kinds = list(d["at_optimum"])
    methods: list[str] = []
    for k in kinds:
        methods += [m for m in d["at_optimum"][k] if m not in methods]
    rows = []
    for m in methods:
        cells = []
        for k in kinds:
            c = d["at_optimum"][k].get(m)
            if c is None:
                cells.append("-")
                continue
            misses = [f"{c[key]} {label}" for key, label in _MISSES if c.get(key)]
            cells.append(
                f"{share(c['share_abs'])} of {c['trials']:,}"
                + (f" ({', '.join(misses)})" if misses else "")
            )
        rows.append((m, *cells))
    header = ("method", *(k.replace("_", "-") for k in kinds))
    mode = "" if d.get("mode") == "full" else " --quick"
    definition = d.get("protocol", {}).get("at_optimum")
    note = f"At the ML optimum: {definition}.\n\n" if definition else ""
    return (
        note
        + table(header, rows)
        + "\n\n"
        + caption(d, name, command=f"python benchmarks/accuracy.py{mode}")
    )


_MISSES = (("failed", "failed"), ("local_minima", "local minima"))
_MEDIAN_METHODS = ("ML optimum", "jaxpose mixed", "PoseLib", "cv2 SQPNP", "cv2 ITERATIVE")


def accuracy_medians(results: Path) -> str:
    d, name = load(results, "accuracy.json")
    text = []
    for kind, sweeps in d["synthetic"].items():
        for axis, other in (("sigma", "n"), ("n", "sigma")):
            sweep = sweeps[axis]
            methods = [m for m in _MEDIAN_METHODS if m in sweep["cells"][0]["methods"]]
            rows = []
            for value, cell in zip(sweep["values"], sweep["cells"], strict=True):
                row = [f"{value:g}"]
                for m in methods:
                    c = cell["methods"].get(m)
                    row.append(
                        "-"
                        if c is None
                        else f"{c['rotation_deg']['median']:.3f} / "
                        f"{c['translation_pct']['median']:.3f}"
                    )
                rows.append(row)
            label = "sigma (px)" if axis == "sigma" else "n"
            text.append(
                f"**{kind.replace('_', '-')}**, {other} = {sweep[other]:g}: median rotation "
                "error (deg) / translation error (%)\n\n" + table((label, *methods), rows)
            )
    text.append(caption(d, name, command="python benchmarks/accuracy.py"))
    return "\n\n".join(text)


def chessboard(results: Path) -> str:
    d, name = load(results, "accuracy.json")
    rows = []
    for im in d["chessboard"]["images"]:
        if not im.get("found"):
            rows.append((im["image"], "corners not found", "", "", "", "", "", ""))
            continue
        rows.append(chessboard_cells(im, (".2g", ".2g"), (".2g", ".2g"), joined=" / "))
    header = (
        "image",
        "vs reference: deg / mm",
        "vs `cv2.solvePnP`: deg / mm",
        "RMS reference",
        "RMS `cv2.solvePnP`",
        "RMS jaxpose",
        "undistorted: cv2",
        "undistorted: jaxpose",
    )
    return table(header, rows) + "\n\n" + caption(d, name, command="python benchmarks/accuracy.py")


def float32(results: Path) -> str:
    d, name = load(results, "float32.json", "float32_quick.json")
    s = d["summary"]
    rows = [
        ("trials", f"{s['trials']:,}"),
        ("float32 at the float64 optimum", share(s["at_float64_optimum"])),
        ("float32 failed where float64 succeeded", share(s["float32_failed_float64_ok"])),
        ("float64 failed where float32 succeeded", share(s["float64_failed_float32_ok"])),
        (
            "rotation difference, worst 99th percentile (deg)",
            number(s["worst_rotation_diff_deg_p99"]),
        ),
        ("rotation difference, largest (deg)", number(s["worst_rotation_diff_deg_max"])),
        (
            "translation difference, worst 99th percentile (relative)",
            number(s["worst_translation_rel_diff_p99"]),
        ),
        (
            "reprojection RMS difference, worst 99th percentile (px)",
            number(s["worst_rms_diff_px_p99"]),
        ),
        (
            "float64 optimum rounded to float32, largest RMS change (px)",
            number(s["worst_rounding_floor_px_max"]),
        ),
    ]
    out = table(("float32 against float64, mixed method", "value"), rows)
    q = d.get("p3p")
    if q:
        out += "\n\n" + table(
            (
                f"three-point solver, {q['instances']:,} random instances",
                "found (1e-6)",
                "found (1e-3)",
                "non-finite",
            ),
            [
                (
                    k,
                    share(r["found_rate"]),
                    share(r["found_rate_at_1e-3"]),
                    r["nonfinite_solutions"],
                )
                for k, r in q["rows"].items()
            ],
        )
    mode = " --quick" if d.get("quick") else ""
    return out + "\n\n" + caption(d, name, command=f"python benchmarks/float32.py{mode}")


def float32_cells(results: Path) -> str:
    d, name = load(results, "float32.json", "float32_quick.json")
    rows = [
        (
            c["kind"].replace("_", "-"),
            c["n"],
            f"{c['sigma']:g}",
            c["trials"],
            share(c["at_float64_optimum"]),
            f"{number(c['rotation_diff_deg']['p99'])} / {number(c['rotation_diff_deg']['max'])}",
            number(c["translation_rel_diff"]["p99"]),
            f"{number(c['median_rotation_error_deg']['float64'])} / "
            f"{number(c['median_rotation_error_deg']['float32'])}",
        )
        for c in d["cells"]
    ]
    header = (
        "case",
        "n",
        "sigma (px)",
        "trials",
        "at the float64 optimum",
        "rotation diff. p99 / max (deg)",
        "translation diff. p99",
        "median rotation error f64 / f32 (deg)",
    )
    return table(header, rows) + "\n\n" + caption(d, name, command="python benchmarks/float32.py")


# ----------------------------------------------------------------------------- robust, gradients

_ROBUST = (
    ("jaxpose", "jaxpose `robust`"),
    ("cv2", "cv2 (defaults)"),
    ("cv2_1000", "cv2 (1000 it.)"),
    ("poselib", "PoseLib"),
)


def _robust(results: Path, kind: str) -> str:
    d, name = load(results, "robust.json")
    cells = d["cells"][kind]
    rows = []
    for frac, c in cells.items():
        row = [share(float(frac), 0)]
        for key, _ in _ROBUST:
            r = c.get(key)
            if r is None:
                row.append("-")
                continue
            cell = f"{share(r['correct_rate'], 1)} / {duration(r['per_call_s_median'])}"
            if "per_problem_batched_s" in r:
                cell += f" ({duration(r['per_problem_batched_s'])})"
            row.append(cell)
        rows.append(row)
    header = ("wrong matches", *(label for _, label in _ROBUST))
    return table(header, rows) + "\n\n" + caption(d, name, command="python benchmarks/robust.py")


def robust_bench(results: Path) -> str:
    return _robust(results, "bench")


def robust_random(results: Path) -> str:
    return _robust(results, "random")


def gradients(results: Path) -> str:
    d, name = load(results, "gradients.json")
    rows = [
        (
            r["batch"],
            f"{duration(r['forward_s']['median'])} "
            f"({duration(1e-3 * r['per_problem_ms']['forward'])} per problem)",
            duration(r["forward_backward_s"]["median"]),
            f"{r['backward_over_forward']:.3f}",
            "yes" if r.get("gradients_finite") else "no",
        )
        for r in d["rows"]
    ]
    header = (
        "batch",
        "forward (median)",
        "forward + backward (median)",
        "backward cost / forward cost",
        "finite",
    )
    out = table(header, rows)
    out += f"\n\n*{d.get('benchmark', '')}; loss {d.get('loss', '')}; {d.get('dtype', '')}.*"
    return out + "\n\n" + caption(d, name, command="python benchmarks/gradients.py")


def distortion(results: Path) -> str:
    """`benchmarks/distortion.py`: `solve_pnp` with `dist_coeffs` at OpenCV's image-space
    optimum."""
    d, name = load(results, "distortion.json", "distortion_quick.json")
    rows = [
        ("problems (k1 in [-0.4, 0.2], 12 matches, 1 px noise)", f"{d['problems']:,}"),
        ("at `cv2.solvePnPRefineLM`'s image-space optimum", share(d["at_optimum"])),
        ("target", f">= {share(d['target'])}: {d['verdict']}"),
        ("largest excess over the optimum (px)", number(d["worst_excess_px"])),
        (
            "`project_points` against `cv2.projectPoints` (largest, px)",
            number(d["projection_max_diff_px"]),
        ),
        ("`solve_pnp` with `dist_coeffs`, per problem", duration(d["solve_pnp_ms"] / 1e3)),
    ]
    command = "python -m benchmarks.distortion" + (" --quick" if "quick" in name else "")
    return table(("", "jaxpose"), rows, left=2) + "\n\n" + caption(d, name, command=command)


def recognition(results: Path) -> str:
    """`benchmarks/recognition.py`: rendered scenes, empty scenes, the box photograph."""
    d, name = load(results, "recognition.json", "recognition_quick.json")
    box = d["box"]

    def largest(errors) -> str:
        return "not found" if errors is None else f"{max(errors):.2f}"

    rows = [
        ("rendered scenes (cross prism, 0-30% occluded, clutter)", f"{d['scenes']:,}"),
        ("right model, vertices within 2 px RMS", share(d["right"], 1)),
        ("target", f">= {share(d['right_target'], 0)}: {d['right_verdict']}"),
        ("median vertex RMS of the right ones (px)", f"{d['median_rms_px']:.2f}"),
        ("scenes without a model", f"{d['empty_scenes']:,}"),
        ("false detections there (target 0)", f"{d['false_detections']}: {d['false_verdict']}"),
        ("time per image, front end + detection (median)", duration(d["seconds_per_image_median"])),
        ("target <= 1 s", d["seconds_verdict"]),
        ("box photograph, mesh only: largest vertex error (px)", largest(box["vertex_path_px"])),
        ("box photograph, ORB model: largest vertex error (px)", largest(box["keypoint_path_px"])),
        ("the same matches, `cv2.solvePnPRansac` (px)", largest(box["opencv_ransac_px"])),
        (
            "target <= 3 px (mesh / ORB)",
            f"{box['vertex_path_verdict']} / {box['keypoint_path_verdict']}",
        ),
    ]

    def corners(key: str) -> str:
        c = box.get(key)
        return "not found" if c is None else f"{c['rms']:.2f} / {c['max']:.2f}"

    if "mesh_fit_corners" in box:  # results written since the corners were measured
        rows += [
            ("box photograph against its measured corners: RMS / largest (px)", ""),
            ("mesh only", corners("vertex_path_corners")),
            ("ORB model", corners("keypoint_path_corners")),
            ("the reference pose", corners("reference_corners")),
            ("the mesh's own least-squares fit (the floor)", corners("mesh_fit_corners")),
        ]
    command = "python -m benchmarks.recognition" + (" --quick" if "quick" in name else "")
    return table(("", "jaxpose"), rows, left=2) + "\n\n" + caption(d, name, command=command)
