"""Formatting and loading for the documentation's benchmark tables (`tables.py`)."""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path

# ----------------------------------------------------------------------------- formatting


def table(header: Sequence[str], rows: Sequence[Sequence[object]], left: int = 1) -> str:
    """A Markdown table; the first `left` columns left-aligned, the others right-aligned."""
    align = [":--"] * left + ["--:"] * (len(header) - left)
    lines = ["| " + " | ".join(header) + " |", "| " + " | ".join(align) + " |"]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


# Between a figure and its unit: a table's narrow column wraps around "1.5 ms" as a whole.
NBSP = "\u00a0"


def duration(seconds: float | None) -> str:
    """`seconds` in the unit that keeps three significant digits readable."""
    if seconds is None or not math.isfinite(seconds):
        return "-"
    for unit, scale in (("s", 1.0), ("ms", 1e-3), ("us", 1e-6)):
        if abs(seconds) >= scale:
            return f"{seconds / scale:.3g}{NBSP}{unit}"
    return f"{seconds / 1e-9:.3g}{NBSP}ns"


def share(x: float | None, digits: int = 2) -> str:
    return "-" if x is None else f"{100 * x:.{digits}f}%"


def number(x: float | None) -> str:
    if x is None:
        return "-"
    if not math.isfinite(x):
        return "inf" if x > 0 else "-inf" if x < 0 else "nan"
    return f"{x:.2g}" if x != 0 and (abs(x) < 1e-3 or abs(x) >= 1e5) else f"{x:.3g}"


def megabytes(n_bytes: float | None) -> str:
    return "-" if n_bytes is None else f"{n_bytes / 1e6:.3g}{NBSP}MB"


def verdict(value: float, target: float, higher_is_better: bool) -> str:
    """`met`, or by what factor the value misses its target."""
    met = value >= target if higher_is_better else value <= target
    if met:
        return "met"
    factor = target / value if higher_is_better else value / target
    return f"missed by {factor:.1f}x"


def machine(data: dict) -> str:
    """One line on the machine and library versions stored with a result (load figures,
    which describe one moment of a shared machine, are left out)."""
    m = data.get("machine")
    m = dict(m) if isinstance(m, dict) else {"platform": m} if m else {}
    parts = []
    if m.get("cpu"):
        # the widest vector instructions recorded (`benchmarks._harness.machine`): the
        # machines here come with AVX-512 or with AVX2 only, and the figures differ
        simd = {"avx512f": "AVX-512", "avx2": "AVX2 only"}.get(m.get("simd") or "")
        parts.append(str(m["cpu"]) + (f" with {simd}" if simd else ""))
    cores = m.get("cores", m.get("cpu_count", data.get("cpu_count")))
    if cores:
        parts.append(f"{cores} cores")
    if m.get("memory_gb"):
        parts.append(f"{m['memory_gb']:g} GB")
    devices = m.get("devices", m.get("jax_devices", data.get("device")))
    if devices:
        devices = [devices] if isinstance(devices, str) else devices
        parts.append("devices " + ", ".join(devices))
    platform = m.get("platform", data.get("platform"))
    if platform:
        parts.append(str(platform))
    versions = dict(data.get("versions") or {})
    for key in ("python", "jax", "jaxpose", "numpy", "opencv", "poselib"):
        if m.get(key):
            versions.setdefault(key, m[key])
    for key in ("jax", "jax_version"):
        if isinstance(data.get(key), str):
            versions.setdefault("jax", data[key])
    versions = {k: v for k, v in versions.items() if v and not k.endswith("_commit")}
    line = "Machine: " + (", ".join(parts) if parts else "not recorded") + "."
    if versions:
        line += " Versions: " + ", ".join(f"{k} {v}" for k, v in versions.items()) + "."
    return line


def source(*names: str) -> str:
    return "Source: " + ", ".join(f"`benchmarks/results/{n}`" for n in names)


def caption(data: dict, *names: str, command: str) -> str:
    return f"*{source(*names)} (`{command}`). {machine(data)}*"


# ----------------------------------------------------------------------------- loading


class Missing(Exception):
    """No saved result for a table."""


def load(results: Path, *names: str) -> tuple[dict, str]:
    """The first of `names` saved in `results` (the full run's before the quick one's)."""
    for name in names:
        path = results / name
        if path.is_file():
            return json.loads(path.read_text()), name
    raise Missing(" or ".join(f"`benchmarks/results/{n}`" for n in names))


# ----------------------------------------------------------------------------- speed
