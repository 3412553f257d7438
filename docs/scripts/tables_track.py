"""The table of the tracker beside OpenCV's real-time pose tutorial on `box.mp4`
(`benchmarks/track_box.py`), for the documentation (`tables.py`)."""

from __future__ import annotations

from pathlib import Path

from tables_format import Missing, caption, load, table

#: The methods in their order, with their labels.
LABELS = {
    "jaxpose": "jaxpose `track` (edges + KLT, linear method)",
    "jaxpose_refined": "jaxpose `track`, then `refine_track` (offline, all frames jointly)",
    "jaxpose_keypoints": "jaxpose `track(textured=...)`: edges + KLT + the textured "
    "model's keypoints near the prediction",
    "opencv_pnp": "OpenCV tutorial: ORB + FLANN + `solvePnPRansac`",
    "opencv_kalman": "OpenCV tutorial, with its Kalman filter",
}


def _pair(stats: dict | None, digits: int) -> str:
    return "-" if not stats else f"{stats['median']:.{digits}f} / {stats['p95']:.{digits}f}"


def track_box(results: Path) -> str:
    """One row per method: frames with a pose, frame-to-frame jitter and its second
    difference (median / 95th percentile), the mean distance of the projected model
    edges to the image's edges, and the frames per second (decoding excluded)."""
    d, name = load(results, "track_box.json")
    rows = []
    for key, label in LABELS.items():
        m = d["methods"].get(key)
        if m is None:
            continue
        edge = m["edge_distance_px"]
        rows.append((
            label,
            f"{m['frames_with_pose']}/{d['frames']}",
            _pair(m["jitter_rotation_deg"], 3),
            _pair(m["jitter_translation_mm"], 2),
            _pair(m.get("jitter_2nd_rotation_deg"), 3),
            _pair(m.get("jitter_2nd_translation_mm"), 2),
            "-" if not edge else f"{edge['mean']:.2f}",
            f"{m['fps']:.1f}",
        ))  # fmt: skip
    header = ("method", "frames posed", "jitter rotation (deg)", "jitter centre (mm)",
              "2nd difference rotation (deg)", "2nd difference centre (mm)",
              "edge distance (px)", "frames/s")  # fmt: skip
    out = table(header, rows)
    out += (
        f"\n\n*`box.mp4`, {d['frames']} frames of {d['image'][0]} x {d['image'][1]}, the "
        "tutorial's camera and textured model for every method. Jitter: between "
        "consecutive frames with a pose, median / 95th percentile (the box moves by hand: "
        "motion plus noise); 2nd difference: the change of that motion over three "
        "consecutive frames, median / 95th percentile (a hand's smooth motion changes "
        "little from one frame to the next, noise does). Edge distance: mean over frames "
        "of the mean distance from the "
        "visible projected model edges to the nearest Canny edge. Frames/s: each method's "
        f"own work per frame, decoding excluded, its fastest of {d.get('repeats', 1)} runs "
        "made alternately (the refined row: tracking plus refinement).*"
    )
    return out + "\n\n" + caption(d, name, command="python -m benchmarks.track_box")


#: The rendered objects and conditions of `benchmarks/track_rendered.py`, with labels.
OBJECTS = {"box_flat": "box, flat-shaded", "box_photo": "box, photo-textured",
           "prism": "bench's prism"}  # fmt: skip
CONDITIONS = {"noise": "noise", "motion_blur": "motion blur", "lighting": "lighting change",
              "clutter": "clutter", "partial_occlusion": "partial occlusion",
              "full_occlusion": "full occlusion"}  # fmt: skip


def _both(cells: dict, key: str, show) -> str:
    """`given / recognition` of one figure of a cell pair."""
    return " / ".join(show(cells[start][key]) if start in cells else "-"
                      for start in ("given", "recognition"))  # fmt: skip


def track_rendered(results: Path) -> str:
    """One row per object and condition, each figure for the two starts (the given first
    pose / recognition of the first frame): the least fraction of the frames seen on
    target over the seeds, the same up to the model's symmetries, the frames reported
    tracked off target, the frames reported tracked while hidden, the frames to come back
    after the full occlusion, the time per frame and whether the issue's targets hold."""
    d, name = load(results, "track_rendered.json", "track_rendered_quick.json")
    cells: dict = {}
    for c in d["cells"]:
        cells.setdefault((c["object"], c["condition"]), {})[c["start"]] = c
    percent = lambda x: f"{100 * x:.0f}%"  # noqa: E731
    rows = []
    for (obj, condition), pair in cells.items():
        rows.append((
            OBJECTS.get(obj, obj),
            CONDITIONS.get(condition, condition),
            _both(pair, "min_seen_on_target", percent),
            _both(pair, "min_seen_on_target_up_to_symmetry", percent),
            _both(pair, "min_refined_seen_on_target", percent),
            _both(pair, "wrong_tracked", str),
            _both(pair, "hidden_tracked", str),
            _both(pair, "max_back_after", lambda x: "-" if x is None else str(x)),
            _both(pair, "median_ms_per_frame", lambda x: f"{x:.0f}"),
            _both(pair, "targets_met", lambda x: "met" if x else "missed"),
        ))  # fmt: skip
    header = ("object", "condition", "seen on target", "up to symmetry", "refined offline",
              "wrong tracked",
              "hidden tracked", "back after", "ms/frame", "targets")  # fmt: skip
    t = d["targets"]
    runs = len(d["runs"])
    out = table(header, rows, left=2)
    out += (
        f"\n\n*Each figure: from the given first pose / from recognition of the first frame. "
        f"{d['seeds']} {'trajectory' if d['seeds'] == 1 else 'trajectories'} per cell, "
        f"{d['frames']} frames each ({runs} runs). Seen "
        f"on target: the least over the trajectories of the fraction of the frames where "
        f"the object is seen with a pose within {t['rotation_deg']} degree and "
        f"{100 * t['translation']:g}% of the distance (target >= "
        f"{100 * t['seen_on_target']:.0f}%); up to symmetry: the same with the rotation "
        f"error taken up to the model's half-turn symmetries (the box's three; the prism "
        f"has none); refined offline: the seen on target of the run refined afterwards, "
        f"all frames jointly (`refine_track`, default settings; the targets are the "
        f"tracker's own, online). Wrong tracked: frames reported with a pose off the target (all "
        f"trajectories); hidden tracked: frames reported with a pose while the object is "
        f"hidden (target 0); back after: the most frames from the reappearance to the "
        f"first frame with a pose (target <= {t['back_after']}, back within "
        f"{t['back_after'] + 1} frames); ms/frame: median over the runs, recognition "
        f"included. Targets: all three hold on every trajectory.{_recognised(d)}*"
    )
    return out + "\n\n" + caption(d, name, command="python -m benchmarks.track_rendered")


#: The saved runs of the rendered matrix by drawing: the saved one (2x), then finer.
DRAWINGS = ("track_rendered.json", "track_rendered_ss4.json", "track_rendered_ss8.json")


def track_drawings(results: Path) -> str:
    """One row per saved drawing of the rendered matrix (`--supersample`): the cells
    met and the cells missed, each with its least share of the frames seen on target
    (from the given pose / from recognition)."""
    rows, names, data = [], [], None
    for file in DRAWINGS:
        try:
            d, name = load(results, file)
        except Missing:
            continue
        data = data or d
        names.append(name)
        missed: dict = {}
        for c in d["cells"]:
            if not c["targets_met"]:
                missed.setdefault((c["object"], c["condition"]), {})[c["start"]] = c
        listed = "; ".join(
            f"{OBJECTS.get(o, o)}, {CONDITIONS.get(k, k)}: "
            + _both(pair, "min_seen_on_target", lambda x: f"{100 * x:.0f}%")
            for (o, k), pair in missed.items()
        )  # fmt: skip
        met = sum(c["targets_met"] for c in d["cells"])
        named = [c for c in d["cells"] if c["object"] in d.get("issue_objects", ())]
        issue = f"{sum(c['targets_met'] for c in named)} of {len(named)}" if named else "-"
        rows.append((f"{d.get('supersample', 2)} x", f"{met} of {len(d['cells'])}", issue,
                     listed or "none"))  # fmt: skip
    if data is None:
        raise Missing(" or ".join(f"`benchmarks/results/{n}`" for n in DRAWINGS))
    out = table(("drawn at", "cells met", "on the issue's objects",
                 "missed (seen on target: given / recognition)"), rows, left=4)  # fmt: skip
    out += (
        "\n\n*The rendered matrix above with its frames drawn at 2 (saved), 4 and 8 "
        "times their resolution and reduced by area (`--supersample`): the same "
        "trajectories, noise and conditions; on the issue's objects: the cells of the "
        "objects the issue names (the photo-textured box and the prism; the flat box is "
        "the project's own harder variant); `-`: met from that start.*"
    )
    command = "python -m benchmarks.track_rendered --supersample N"
    return out + "\n\n" + caption(data, *names, command=command)


def _recognised(d: dict) -> str:
    """What each object's runs from recognition recognised it from (the cells'
    `recognition`, absent from results saved before it was recorded)."""
    by: dict[str, list[str]] = {}
    for c in d["cells"]:
        if c["start"] == "recognition" and "recognition" in c:
            label = OBJECTS.get(c["object"], c["object"])
            names = by.setdefault(c["recognition"], [])
            if label not in names:
                names.append(label)
    if not by:
        return ""
    said = {"textured": "from the textured model's keypoints (then the mesh)",
            "mesh": "from the mesh alone"}  # fmt: skip
    parts = [f"{', '.join(names)} {said.get(kind, kind)}" for kind, names in by.items()]
    return (" The runs from recognition recognise the object (on the first frame and after "
            f"a lost one): {'; '.join(parts)}; the runs from the given pose re-initialise "
            "from the mesh alone.")  # fmt: skip
