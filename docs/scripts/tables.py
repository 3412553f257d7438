"""Markdown tables of the saved benchmark results, for the documentation.

    python docs/scripts/tables.py [--results benchmarks/results] [--out docs/generated]

Reads the JSON files that the benchmark scripts save in `benchmarks/results/` (and, from
the package's source, the status codes and the paper's Table 1) and writes one Markdown
table per entry of `TABLES` into `docs/generated/<name>.md`, plus a copy of each plot of
`PLOTS` saved beside the JSON. The documentation pages include the tables
(`pymdownx.snippets`), and the documentation build runs this script first
(`docs/scripts/hooks.py`), so a table always shows the saved result it is read from: its
figures, the ratios to the peers, the targets stored with it, and the machine it ran on.
A file is rewritten only when its content changes. A missing result gives a one-line
note that names the script to run, never a stale table.
"""

from __future__ import annotations

import argparse
import ast
import sys
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from tables_accuracy import (  # noqa: E402
    accuracy,
    accuracy_medians,
    chessboard,
    distortion,
    float32,
    float32_cells,
    gradients,
    p3p,
    recognition,
    robust_bench,
    robust_random,
)
from tables_format import Missing, table  # noqa: E402
from tables_opencv import opencv_cases  # noqa: E402
from tables_speed import (  # noqa: E402
    costs,
    device,
    scale_batch,
    scale_cache,
    scale_n,
    speed,
    speed_batch,
    speed_classes,
    speed_phases,
    startup,
)
from tables_track import track_box, track_drawings, track_rendered  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "benchmarks" / "results"
OUT = ROOT / "docs" / "generated"

# Plots saved by the benchmark scripts beside their JSON (the full run's, else the quick one's).
PLOTS = {
    # `jaxpose reproduce --out benchmarks/results/experiment` (the paper's Figures 3-4)
    "experiment_figure3.png": ("experiment/figure3_histogram.png",),
    "experiment_figure4.png": ("experiment/figure4_cumulative.png",),
    "accuracy_ordinary.png": ("accuracy_ordinary.png",),
    "accuracy_quasi_singular.png": ("accuracy_quasi_singular.png",),
    "accuracy_planar.png": ("accuracy_planar.png",),
    "batch.png": ("batch.png", "batch_quick.png"),
    "scale.png": ("scale.png", "scale_quick.png"),
}


PACKAGE = ROOT / "jaxpose"
_STATUS_BASES = {"StatusCode", "IntEnum"}


def _status_members(cls: ast.ClassDef, messages: dict[str, str]) -> list[tuple[int, str, str]]:
    """`(code, name, message)` of an enumeration written `NAME = code, "message"` (or
    `NAME = code` with a module-level `_MESSAGES = {Status.NAME: "message"}`)."""
    members = []
    for st in cls.body:
        if not (isinstance(st, ast.Assign) and isinstance(st.targets[0], ast.Name)):
            continue
        try:
            value = ast.literal_eval(st.value)
        except ValueError:
            continue
        name = st.targets[0].id
        if isinstance(value, int) and not isinstance(value, bool):
            members.append((value, name, messages.get(name, "")))
        elif isinstance(value, tuple) and len(value) == 2 and isinstance(value[0], int):
            members.append((value[0], name, str(value[1])))
    return sorted(members)


def _status_enums() -> list[tuple[str, str, list[tuple[int, str, str]]]]:
    """Every status enumeration of the package, the solvers' `Status` first:
    `(class, source file, members)`."""
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        tree = ast.parse(path.read_text())
        messages = {}
        for node in tree.body:
            target = getattr(node, "target", None) or (getattr(node, "targets", None) or [None])[0]
            value = getattr(node, "value", None)
            if isinstance(target, ast.Name) and target.id == "_MESSAGES":
                if isinstance(value, ast.Dict):
                    for k, v in zip(value.keys, value.values, strict=True):
                        if isinstance(k, ast.Attribute) and isinstance(v, ast.Constant):
                            messages[k.attr] = v.value
        module = path.relative_to(ROOT).as_posix()
        for node in tree.body:
            if not isinstance(node, ast.ClassDef) or not node.name.endswith("Status"):
                continue
            bases = {getattr(b, "id", getattr(b, "attr", None)) for b in node.bases}
            members = _status_members(node, messages)
            if bases & (_STATUS_BASES | {"Status"}) and members:
                found.append((node.name, module, members))
    return sorted(found, key=lambda e: (e[0] != "Status", e[1], e[0]))


def statuses(results: Path) -> str:
    """The status codes and their messages, read from the package's source (no import)."""
    enums = _status_enums()
    if not enums:
        raise Missing(f"status enumerations in `{PACKAGE.relative_to(ROOT)}/`")
    parts = []
    for name, module, members in enums:
        rows = [(code, f"`{member}`", message) for code, member, message in members]
        header = ("code", "member", "message")
        parts.append(f"`{name}` (`{module}`)\n\n" + table(header, rows, left=3))
    return "\n\n".join(parts)


EXPERIMENT_SOURCE = ROOT / "jaxpose" / "apps" / "_experiment.py"


def _constants(path: Path, *names: str) -> dict[str, object]:
    """Module-level literal constants of a source file, read without importing it."""
    if not path.is_file():
        raise Missing(f"`{path.relative_to(ROOT)}`")
    found = {}
    for node in ast.parse(path.read_text()).body:
        target = getattr(node, "target", None) or (getattr(node, "targets", None) or [None])[0]
        if isinstance(target, ast.Name) and target.id in names and node.value is not None:
            found[target.id] = ast.literal_eval(node.value)
    if set(found) != set(names):
        raise Missing(f"{sorted(set(names) - set(found))} in `{path.relative_to(ROOT)}`")
    return found


def paper_table1(results: Path) -> str:
    """Table 1 of the paper as jaxpose stores it to compare with (`jaxpose reproduce`)."""
    c = _constants(EXPERIMENT_SOURCE, "PAPER_TABLE1", "PAPER_MIXED_AT_OPTIMUM", "PAPER_COUNTS")
    table1 = c["PAPER_TABLE1"]
    methods = list(table1)
    labels = {"three_point": "3-segment", "nonlinear": "non-linear"}
    stats = (
        ("mean", "mean"),
        ("std", "standard deviation"),
        ("mean_deviation", "mean deviation"),
        ("min", "minimum"),
    )
    rows = [(label, *(f"{table1[m][key]:.3f}" for m in methods)) for key, label in stats]
    header = ("pose error (mm)", *(labels.get(m, m) for m in methods))
    counts, at_optimum = c["PAPER_COUNTS"], c["PAPER_MIXED_AT_OPTIMUM"]
    return (
        table(header, rows)
        + f"\n\n*The paper's Table 1. Mixed at the optimum: {100 * at_optimum:.2f}%"
        + f" of samples. Triplets: {counts['triplets']}, aligned {counts['aligned']}, used "
        + f"{counts['used']}. Read from `{EXPERIMENT_SOURCE.relative_to(ROOT)}`.*"
    )


# ----------------------------------------------------------------------------- writing

TABLES: dict[str, Callable[[Path], str]] = {
    "speed": speed,
    "speed_phases": speed_phases,
    "speed_batch": speed_batch,
    "speed_classes": speed_classes,
    "device": device,
    "costs": costs,
    "startup": startup,
    "scale_n": scale_n,
    "scale_batch": scale_batch,
    "scale_cache": scale_cache,
    "p3p": p3p,
    "accuracy": accuracy,
    "accuracy_medians": accuracy_medians,
    "chessboard": chessboard,
    "distortion": distortion,
    "recognition": recognition,
    "float32": float32,
    "float32_cells": float32_cells,
    "robust_bench": robust_bench,
    "robust_random": robust_random,
    "gradients": gradients,
    "opencv_cases": opencv_cases,
    "track_box": track_box,
    "track_rendered": track_rendered,
    "track_drawings": track_drawings,
    "statuses": statuses,
    "paper_table1": paper_table1,
}


# Tables read from the package's source rather than from `benchmarks/results/`.
FROM_SOURCE = ("statuses", "paper_table1")


def build(results: Path = RESULTS) -> dict[str, str]:
    """Every table as Markdown, by name; a missing result gives a note naming the script."""
    out = {}
    for name, make in TABLES.items():
        try:
            out[name] = make(results)
        except Missing as exc:
            out[name] = f"*No saved result yet ({exc}): run the benchmark script that writes it.*"
    return out


def outputs() -> list[str]:
    """The file names `write` produces (tables and plots)."""
    return [f"{name}.md" for name in TABLES] + list(PLOTS)


def _write_if_changed(path: Path, data: bytes) -> bool:
    if path.is_file() and path.read_bytes() == data:
        return False
    path.write_bytes(data)
    return True


#: The tables the README holds between `<!-- table: NAME -->` and `<!-- end table -->`.
README = ROOT / "README.md"
README_TABLES = ("costs",)


def readme_with_tables(text: str, tables: dict[str, str]) -> str:
    """`text` (the README) with each `README_TABLES` region holding its table."""
    for name in README_TABLES:
        begin, end = f"<!-- table: {name} -->\n", "<!-- end table -->"
        i = text.index(begin) + len(begin)
        j = text.index(end, i)
        text = text[:i] + "\n" + tables[name].rstrip() + "\n\n" + text[j:]
    return text


def write(results: Path = RESULTS, out: Path = OUT, readme: Path | None = README) -> list[Path]:
    """Write the tables and copy the plots into `out`, and the README's tables into
    `readme` (`None`: not); return the files that changed."""
    out.mkdir(parents=True, exist_ok=True)
    changed = []
    tables = build(results)
    for name, text in tables.items():
        path = out / f"{name}.md"
        if _write_if_changed(path, (text.rstrip() + "\n").encode()):
            changed.append(path)
    if readme is not None and readme.is_file():
        text = readme.read_text()
        if _write_if_changed(readme, readme_with_tables(text, tables).encode()):
            changed.append(readme)
    for target, candidates in PLOTS.items():
        found = next((results / c for c in candidates if (results / c).is_file()), None)
        if found is not None and _write_if_changed(out / target, found.read_bytes()):
            changed.append(out / target)
    return changed


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--results", type=Path, default=RESULTS)
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args(argv)
    changed = write(args.results, args.out)
    print(f"{len(changed)} file(s) written to {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
