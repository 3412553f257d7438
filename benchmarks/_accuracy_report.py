"""The tables, Markdown and plots of `benchmarks/accuracy.py`, from its result dict alone
(`python benchmarks/accuracy.py --from-json ...` shows a saved result again)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from benchmarks._protocol import ABS_TOL, LOCAL_MINIMUM, ML


def _table_rows(result: dict, kind: str, sweep: str):
    """(header, rows) of the medians table of one sweep: 'rotation deg / translation %'."""
    block = result["synthetic"][kind][sweep]
    header = [str(v) if sweep == "n" else f"{v:g}" for v in block["values"]]
    names = [ML] + [m for m in block["cells"][0]["methods"] if m != ML]
    rows = []
    for name in names:
        cells = []
        for cell in block["cells"]:
            row = cell["methods"].get(name)
            if not row or not row.get("trials"):
                cells.append("-")
                continue
            rot, tr = row["rotation_deg"]["median"], row["translation_pct"]["median"]
            text = "-" if rot is None else f"{rot:.3f} / {tr:.3f}"
            if row["trials"] != cell["trials"]:
                text += f" [{row['trials']}]"
            if row["failed"]:
                text += f" ({row['failed']} failed)"
            cells.append(text)
        rows.append((name, cells))
    return header, rows


def _sweep_labels(block: dict, sweep: str) -> tuple[str, str, str]:
    """What one sweep holds fixed ('n = 10'), what it varies (the column label) and the
    trials of its cells ('200, 200, 50')."""
    fixed = f"n = {block['n']}" if sweep == "sigma" else f"sigma = {block['sigma']:g} px"
    label = "sigma (px)" if sweep == "sigma" else "n"
    return fixed, label, ", ".join(str(c["trials"]) for c in block["cells"])


def chessboard_cells(
    image: dict, reference: tuple[str, str], cv2: tuple[str, str], joined: str | None = None
) -> list[str]:
    """One found chessboard image as table cells: its name; the rotation (deg) and
    translation (mm) differences of jaxpose to the reference (formats `reference`) and to
    `cv2.solvePnP` (formats `cv2`), each pair one cell `joined` by that text when given;
    then the RMS reprojection errors of the reference, cv2 and jaxpose, and of cv2 and
    jaxpose on undistorted pixels."""
    cells = [image["image"]]
    for diff, formats in (
        (image["jaxpose_vs_reference"], reference),
        (image["jaxpose_vs_cv2"], cv2),
    ):
        pair = [
            format(diff["rotation_deg"], formats[0]),
            format(diff["translation_mm"], formats[1]),
        ]
        cells += pair if joined is None else [joined.join(pair)]
    rms, undistorted = image["rms_px"], image["rms_undistorted_px"]
    cells += [f"{rms[k]:.4f}" for k in ("reference", "cv2", "jaxpose")]
    return cells + [f"{undistorted[k]:.4f}" for k in ("cv2", "jaxpose")]


LEGEND = (
    "[k]: over the first k trials of the cell only; (f failed): no pose returned (left "
    "out of the medians); -: not run"
)


def _optimum_cell(acc: dict | None) -> str:
    if not acc:
        return "-"
    share = 100 * acc["share_abs"]
    text = f"{share:.2f}% ({acc['at_optimum_abs']}/{acc['trials']})"
    notes = []
    if acc["failed"]:
        notes.append(f"{acc['failed']} failed")
    if acc["local_minima"]:
        notes.append(f"{acc['local_minima']} > {LOCAL_MINIMUM:g} px above")
    return text + "".join(f", {x}" for x in notes)


def print_tables(result: dict, console) -> None:
    """The tables, with rich: medians per sweep and kind, the at-the-optimum shares, the
    chessboard images."""
    from rich.table import Table

    for kind, sweeps in result["synthetic"].items():
        for sweep, block in sweeps.items():
            header, rows = _table_rows(result, kind, sweep)
            fixed, label, trials = _sweep_labels(block, sweep)
            table = Table(
                title=f"{kind}, {fixed}: median rotation error (deg) / translation error (%)"
                f"\ntrials per cell: {trials}",
                title_justify="left",
                caption=LEGEND,
                caption_justify="left",
            )
            table.add_column(f"method \\ {label}")
            for h in header:
                table.add_column(h, justify="right")
            for name, cells in rows:
                table.add_row(name, *cells)
            console.print(table)
    table = Table(
        title=f"Trials at the ML optimum (RMS within {ABS_TOL:g} px), all cells of each kind",
        title_justify="left",
    )
    table.add_column("method")
    kinds = list(result["at_optimum"])
    for kind in kinds:
        table.add_column(kind, justify="right")
    names = list(dict.fromkeys(n for k in kinds for n in result["at_optimum"][k]))
    for name in names:
        table.add_row(name, *(_optimum_cell(result["at_optimum"][k].get(name)) for k in kinds))
    console.print(table)
    if "chessboard" in result:
        table = Table(title="OpenCV chessboard images (left camera)", title_justify="left")
        for col in (
            "image",
            "rot. vs ref (deg)",
            "trans. vs ref (mm)",
            "rot. vs cv2 (deg)",
            "trans. vs cv2 (mm)",
            "RMS ref (px)",
            "RMS cv2",
            "RMS jaxpose",
            "undist. cv2",
            "undist. jaxpose",
        ):
            table.add_column(col, justify="right")
        for im in result["chessboard"]["images"]:
            if not im["found"]:
                table.add_row(im["image"], *(["not found"] + ["-"] * 8))
                continue
            table.add_row(*chessboard_cells(im, (".4f", ".3f"), (".2e", ".2e")))
        console.print(table)


def markdown(result: dict) -> str:
    """The tables as Markdown (for the README)."""
    lines = []
    for kind, sweeps in result["synthetic"].items():
        for sweep, block in sweeps.items():
            header, rows = _table_rows(result, kind, sweep)
            fixed, label, trials = _sweep_labels(block, sweep)
            lines += [
                f"**{kind.replace('_', '-')}, {fixed}**: median rotation error (deg) / "
                f"translation error (%); trials per cell: {trials}. {LEGEND}.",
                "",
                f"| method \\ {label} | " + " | ".join(header) + " |",
                "|---|" + "---|" * len(header),
            ]
            lines += [f"| {name} | " + " | ".join(cells) + " |" for name, cells in rows]
            lines.append("")
    kinds = list(result["at_optimum"])
    names = list(dict.fromkeys(n for k in kinds for n in result["at_optimum"][k]))
    lines += [
        f"**At the ML optimum** (RMS reprojection error within {ABS_TOL:g} px of the "
        "reference), over all cells of each kind:",
        "",
        "| method | " + " | ".join(k.replace("_", "-") for k in kinds) + " |",
        "|---|" + "---|" * len(kinds),
    ]
    for name in names:
        cells = [_optimum_cell(result["at_optimum"][k].get(name)) for k in kinds]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines.append("")
    if "chessboard" in result:
        lines += [
            "**OpenCV chessboard images** (jaxpose mixed; reference = OpenCV's calibration "
            "extrinsics; RMS reprojection error in image pixels, and on undistorted pixels, "
            "the criterion jaxpose minimises):",
            "",
            "| image | rotation vs reference (deg) | translation vs reference (mm) | "
            "rotation vs cv2.solvePnP (deg) | translation vs cv2.solvePnP (mm) | "
            "RMS reference | RMS cv2.solvePnP | RMS jaxpose | undistorted: cv2 | "
            "undistorted: jaxpose |",
            "|---|---|---|---|---|---|---|---|---|---|",
        ]
        for im in result["chessboard"]["images"]:
            if not im["found"]:
                lines.append(f"| {im['image']} | corners not found |||||||||")
                continue
            cells = chessboard_cells(im, (".4f", ".3f"), (".1e", ".1e"))
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


def plot(result: dict, out: Path, tag: str = "") -> list[Path]:
    """One figure per kind: median rotation and translation errors versus sigma (n = 10)
    and versus n (sigma = 2 px), every method and the ML optimum (dashed, on top). A
    method that ran on only a prefix of some cell's trials is drawn dotted and hollow."""
    from matplotlib.figure import Figure

    paths = []
    for kind, sweeps in result["synthetic"].items():
        fig = Figure(figsize=(12, 9), layout="constrained")
        axes = fig.subplots(2, 2)
        for col, sweep in enumerate(("sigma", "n")):
            if sweep not in sweeps:
                continue
            block = sweeps[sweep]
            x = np.asarray(block["values"], float)
            names = [m for m in block["cells"][0]["methods"] if m != ML] + [ML]
            for row, (metric, unit) in enumerate(
                (("rotation_deg", "rotation error (deg)"), ("translation_pct", "translation (%)"))
            ):
                ax = axes[row, col]
                for k, name in enumerate(names):
                    y, partial = [], False
                    for cell in block["cells"]:
                        r = cell["methods"].get(name, {})
                        v = r.get(metric, {}).get("median") if r.get("trials") else None
                        y.append(np.nan if v is None else v)
                        partial |= bool(r.get("trials")) and r["trials"] != cell["trials"]
                    if name == ML:
                        style = {"color": "black", "ls": "--", "lw": 2, "zorder": 10}
                    else:
                        style = {"color": f"C{k % 10}", "ls": ":" if partial else "-"}
                        if partial:
                            style["mfc"] = "none"
                    marker = "o" if name.startswith("jaxpose") else "s"
                    ax.plot(x, y, marker=marker, ms=4, label=name, **style)
                if sweep == "n":
                    ax.set_xscale("log")
                    ax.set_xticks(x, [str(int(v)) for v in x])
                    ax.set_xlabel(f"n (sigma = {block['sigma']:g} px)")
                else:
                    ax.set_xlabel(f"sigma (px), n = {block['n']}")
                ax.set_yscale("log")
                ax.set_ylabel(f"median {unit}")
                ax.grid(True, which="both", alpha=0.3)
        axes[0, 0].legend(fontsize=7, ncol=2)
        fig.suptitle(
            f"{kind.replace('_', '-')} scenes: median errors ({result['mode']} run; dotted, "
            "hollow: a method run on the first trials of some cells only)"
        )
        path = out / f"accuracy{tag}_{kind}.png"
        fig.savefig(path, dpi=110)
        paths.append(path)
    return paths
