"""Tables of the speed and scaling benchmarks (`benchmarks/run.py`, `benchmarks/scale.py`)."""

from __future__ import annotations

from pathlib import Path

from tables_format import (
    NBSP,
    Missing,
    caption,
    duration,
    load,
    megabytes,
    share,
    table,
    verdict,
)


def _run_command(data: dict, only: str) -> str:
    return f"python benchmarks/run.py --only {only}" + (" --quick" if data.get("quick") else "")


_SCALE = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}


def _figure(value: float | None, unit: str | None) -> str:
    """A figure of the targets table in its unit (`"%"`: a share in [0, 1])."""
    if value is None:
        return "-"
    if unit in _SCALE:
        return duration(value * _SCALE[unit])
    if unit == "%":
        return share(value)
    if unit == "x":
        return f"{value:.1f}x"
    return f"{value:.3g} {unit}"


def _bound(row: dict) -> str:
    sign = ">=" if row["higher_is_better"] else "<="
    unit = row["unit"]
    if unit == "%":
        return f"{sign}{NBSP}{100 * row['target']:g}%"
    return f"{sign}{NBSP}{row['target']:g}{'x' if unit == 'x' else NBSP + unit}"


def speed(results: Path) -> str:
    """The targets table of the speed benchmark: each target beside its figure, measured
    in one run (`benchmarks/speed.py`, `TARGETS`)."""
    d, name = load(results, "speed.json", "speed_quick.json")
    rows = []
    for key, r in d["targets"].items():
        peer = "-"
        if r.get("peer") is not None:
            peer = f"{_figure(r['peer_figure'], r['peer_unit'])} ({r['peer']})"
        rows.append(
            (
                f"`{key}`",
                r["what"],
                _figure(r["figure"], r["unit"]),
                _bound(r),
                r["verdict"],
                peer,
                duration(r.get("compile_s")),
            )
        )
    header = ("target", "what", "jaxpose", "bound", "verdict", "peer", "compile")
    return table(header, rows, left=2) + "\n\n" + caption(d, name, command=_run_command(d, "speed"))


def speed_phases(results: Path) -> str:
    d, name = load(results, "speed.json", "speed_quick.json")
    ph = d["paper_phases"]
    rows = [
        ("three-point roots of every triplet", ph["three_point_ms"]),
        ("step 1: the roots and the Eq. 8 error of each over all matches", ph["step1_ms"]),
        ("step 2: the linear method from every triplet's pose", ph["step2_linear_ms"]),
        ("the mixed algorithm (`jaxpose.mixed`)", ph["mixed_ms"]),
        ("`jaxpose.solve` (mixed, then the final polish)", ph["solve_ms"]),
    ]
    out = table(
        (f"phase ({ph['triplets']} triplets, each compiled and timed alone)", "time"),
        [(what, duration(1e-3 * ms)) for what, ms in rows],
    )
    la = d.get("linalg")
    if la:
        out += "\n\n" + table(
            (f"6x6 normal equations ({la['systems']} systems at once)", "per system"),
            [
                ("`jnp.linalg.solve` (LAPACK)", duration(1e-6 * la["lapack_us_per_system"])),
                ("unrolled Cholesky", duration(1e-6 * la["unrolled_us_per_system"])),
            ],
        )
    return out + "\n\n" + caption(d, name, command=_run_command(d, "speed"))


def speed_batch(results: Path) -> str:
    d, name = load(results, "speed.json", "speed_quick.json")
    T = d["targets"]
    optimum, speedup = T["batch_at_optimum"]["target"], T["batch_vs_loop"]["target"]
    rows = [
        (
            r["B"],
            duration(r["jaxpose_s"]),
            duration(1e-6 * r["per_problem_us"]),
            duration(r["opencv_s"] / r["B"]),
            f"{r['vs_opencv']:.2f}x",
            share(r["at_optimum"]),
            verdict(r["at_optimum"], optimum, True),
            duration(r.get("compile_s")),
        )
        for r in d["batch"]
    ]
    header = (
        "B",
        "jaxpose call",
        "per problem",
        "OpenCV loop, per problem",
        "ratio (OpenCV / jaxpose)",
        "at the ML optimum",
        f"target >= {share(optimum, 1)}",
        "compile",
    )
    note = (
        "`solve_pnp_batch` with its default options, n = 16, against a loop of "
        "`cv2.solvePnP` (SQPNP) and `solvePnPRefineLM` over the same problems; at the ML "
        "optimum: the RMS reprojection error within 1e-6 (relative) of the refined OpenCV "
        f"answer's, or lower. Speed target: >= {speedup:g}x the OpenCV loop at the largest B."
    )
    return (
        note
        + "\n\n"
        + table(header, rows)
        + "\n\n"
        + caption(d, name, command=_run_command(d, "speed"))
    )


def speed_classes(results: Path) -> str:
    """`solve_pnp_batch` on each problem class at two batch sizes (the `classes`
    section of `benchmarks/speed.py`): a table for each saved run that has it (the full
    run's and that of the section alone, `--sections classes`, often on another kind of
    machine), else the quick run's."""
    runs = _with_classes(results, "speed.json", "speed_partial.json") or _with_classes(
        results, "speed_quick.json"
    )
    if not runs:
        raise Missing("the `classes` section in `benchmarks/results/speed.json`")
    T = runs[0][0]["targets"]
    note = (
        "`solve_pnp_batch` with its default options on each problem class of the accuracy "
        "protocol (n = 16, 1 px) and on the bench's own model at random poses (its 16 "
        "matched vertices, 0.7 px), against the loop of `cv2.solvePnP` (SQPNP) and "
        "`solvePnPRefineLM` over the same problems. Growth: the time per problem at the "
        f"larger batch over the smaller (target <= {T['classes_growth']['target']:g}x); "
        f"ratio target >= {T['classes_vs_loop']['target']:g}x on every class."
    )
    return "\n\n".join([note, *(_classes_table(d, name) for d, name in runs)])


def _with_classes(results: Path, *names: str) -> list[tuple[dict, str]]:
    """The saved runs among `names` that have the `classes` section, with their names."""
    runs = []
    for name in names:
        try:
            d, _ = load(results, name)
        except Missing:
            continue
        if "classes" in d:
            runs.append((d, name))
    return runs


def _classes_table(d: dict, name: str) -> str:
    small, large = d["classes"]["sizes"]
    rows = []
    for kind, r in d["classes"]["classes"].items():
        lo, hi = r[str(small)], r[str(large)]
        rows.append(
            (
                kind.replace("_", " "),
                duration(1e-6 * lo["per_problem_us"]),
                duration(1e-6 * hi["per_problem_us"]),
                f"{r['growth']:.2f}x",
                duration(1e-6 * r["opencv_us"]),
                f"{hi['vs_opencv']:.2f}x",
                share(min(lo["at_optimum"], hi["at_optimum"])),
            )
        )
    header = (
        "class",
        f"per problem, B = {small:,}",
        f"per problem, B = {large:,}",
        "growth",
        "OpenCV loop, per problem",
        f"ratio at B = {large:,}",
        "at the ML optimum",
    )
    command = _run_command(d, "speed") + (" --sections classes" if "partial" in name else "")
    return table(header, rows) + "\n\n" + caption(d, name, command=command)


# ----------------------------------------------------------------------------- scaling


def _strategy(r: dict) -> str:
    if r.get("triplet_budget"):
        return f"`triplet_budget={r['triplet_budget']}`"
    if r.get("strategy") == "sampled":
        return f"sample of {r.get('max_triplets')}"
    return "all" if r.get("strategy") == "exhaustive" else str(r.get("strategy"))


def scale_n(results: Path) -> str:
    d, name = load(results, "scale.json", "scale_quick.json")
    targets = d.get("targets", {})
    names = [name]
    rows = list(d["n"]["rows"])
    try:
        large, large_name = load(results, "scale_large_n.json")
        rows += large["rows"]
        names.append(large_name)
    except Missing:
        pass
    lat = targets.get("latency_ms")
    out_rows = []
    for r in sorted(rows, key=lambda r: r["n"]):
        if "warm_s" not in r:
            out_rows.append(
                (r["n"], _strategy(r), f"{r['triplets_exhaustive']:,}", "not run", "", "", "", "")
            )
            continue
        out_rows.append(
            (
                r["n"],
                _strategy(r),
                f"{r['triplets_solved']:,} of {r['triplets_exhaustive']:,}",
                f"{duration(r['warm_s'])} ({duration(r['warm_cpu_s'])})",
                verdict(1e3 * r["warm_s"], lat, False) if lat else "",
                f"{duration(r['compile_s'])} ({duration(r['lower_s'])} + "
                f"{duration(r['xla_compile_s'])})",
                megabytes(r["memory"]["peak_bytes"]),
                f"{r['run_rss_growth_mb']:.3g} MB",
            )
        )
    header = (
        "n",
        "triplets",
        "solved",
        "warm call, wall (CPU)",
        f"latency target <= {lat:g} ms" if lat else "latency target",
        "cold compile (trace + XLA)",
        "XLA memory",
        "RSS while running",
    )
    text = [table(header, out_rows)]
    for c in d["n"].get("switch", {}).get("compared", []):
        text.append(
            f"At n = {c['n']}, all triplets cost {c['exhaustive_over_sampled']:.1f}x the "
            f"sample in wall time ({c['exhaustive_over_sampled_cpu']:.1f}x in CPU time), "
            + ("for the same answer." if c.get("same_answer") else "for a different answer.")
        )
    text.append(caption(d, *names, command=_run_command(d, "scale")))
    return "\n\n".join(text)


def scale_batch(results: Path) -> str:
    d, name = load(results, "scale.json", "scale_quick.json")
    names = [name]
    rows = list(d["batch"]["rows"])
    try:
        big, big_name = load(results, "scale_batch_1e5.json")
        rows.append(big)
        names.append(big_name)
    except Missing:
        pass
    cpu_peer = d["batch"].get("opencv_per_problem_cpu_us")
    try:
        target = load(results, "speed.json", "speed_quick.json")[0]["targets"]
        target = target["batch_vs_loop"]["target"]
    except (Missing, KeyError, TypeError):
        target = None
    out_rows = []
    for r in rows:
        ratio = cpu_peer / r["per_problem_cpu_us"] if cpu_peer else None
        out_rows.append(
            (
                f"{r['B']:,}",
                str(r["chunk_size"]) if r.get("chunk_size") else "-",
                f"{duration(1e-6 * r['per_problem_us'])} / "
                f"{duration(1e-6 * r['per_problem_cpu_us'])}",
                "-" if ratio is None else f"{ratio:.2f}x",
                verdict(ratio, target, True) if target and ratio and r["B"] >= 10_000 else "",
                megabytes(r["memory"]["peak_bytes"]),
                f"{r['run_rss_growth_mb']:.3g} MB",
                f"{r['input_mb']:.3g} MB",
                share(r.get("ok")),
            )
        )
    header = (
        "B",
        "`chunk_size`",
        "per problem, wall / CPU",
        "ratio (OpenCV CPU / jaxpose CPU)",
        f"target >= {target:g}x at B >= 10^4" if target else "target",
        "XLA memory per chunk",
        "RSS while running",
        "inputs",
        "accepted",
    )
    note = (
        "`solve_pnp_batch(triplet_budget=8)`, n = 16, one fresh process per row; the OpenCV "
        "loop (`cv2.solvePnP` SQPNP and `solvePnPRefineLM`) takes "
        + (f"{duration(1e-6 * cpu_peer)} of CPU per problem." if cpu_peer else "-")
    )
    return (
        note
        + "\n\n"
        + table(header, out_rows)
        + "\n\n"
        + caption(d, *names, command=_run_command(d, "scale"))
    )


def scale_cache(results: Path) -> str:
    d, name = load(results, "scale.json", "scale_quick.json")
    target = d["cache"].get("target_s")
    rows = []
    for r in d["cache"]["rows"]:
        if r["kind"] == "single":
            what = f"`solve`, n = {r['config'][0]} ({r['config'][1]})"
        else:
            what = f"`solve_pnp_batch`, B = {r['config'][0]:,}, `chunk_size={r['config'][1]}`"
        split = (
            f" ({duration(r['cached_lower_s'])} + {duration(r['cached_xla_s'])})"
            if "cached_lower_s" in r
            else ""
        )
        rows.append(
            (
                what,
                duration(r["cold_compile_s"]),
                duration(r["cached_compile_s"]) + split,
                verdict(r["cached_compile_s"], target, False) if target else "",
            )
        )
    header = (
        "program",
        "cold compile",
        "with the persistent cache (trace + XLA)",
        f"target <= {target:g} s" if target else "target",
    )
    return table(header, rows) + "\n\n" + caption(d, name, command=_run_command(d, "scale"))


# ----------------------------------------------------------------------------- accuracy


def startup(results: Path) -> str:
    """The start-up targets (`benchmarks/startup.py`): each figure measured in a fresh
    process, beside its target."""
    d, name = load(results, "startup.json", "startup_quick.json")
    rows = []
    for key, r in d["targets"].items():
        figure = r["figure_s"]
        bound = r["target_s"]
        rows.append(
            (
                f"`{key}`",
                r["what"],
                "-" if figure is None else duration(figure),
                f"<= {duration(bound)}",
                r["verdict"],
            )
        )
    parts = [table(("target", "what", "jaxpose", "bound", "verdict"), rows, left=2)]
    for key in ("cold", "warm"):
        r = d.get(key, {})
        if "calls" in r:
            parts.append(
                f"`{key}`: import {duration(r['import_s'])}, first `solve_pnp` "
                f"{duration(r['calls'][0]['s'])} (programs compiled: {r['compiled']}, "
                f"loaded from the cache: {r['loaded']})."
            )
    command = "python -m benchmarks.startup" + (" --quick" if "quick" in name else "")
    return "\n\n".join(parts) + "\n\n" + caption(d, name, command=command)


def device(results: Path) -> str:
    """The batch benchmarks on an accelerator (`benchmarks/device.py`): each problem
    class at two batch sizes, 10^5 problems, the three-point kernel; the OpenCV loop on
    the same machine's CPU."""
    d, name = load(results, "device_h100.json", "device_h200.json", "device.json")
    kind = d["device"]["kind"]
    small, large = d["classes"]["sizes"]
    rows = []
    for cls, r in d["classes"]["classes"].items():
        lo, hi = r[str(small)], r[str(large)]
        rows.append(
            (
                f"{cls.replace('_', ' ')}, B = {small:,} / {large:,}",
                f"{duration(1e-6 * lo['per_problem_us'])} / "
                f"{duration(1e-6 * hi['per_problem_us'])}",
                duration(1e-6 * r["opencv_us"]),
                f"{hi['vs_opencv']:.1f}x",
                share(min(lo["at_optimum"], hi["at_optimum"])),
            )
        )
    big = d.get("large")
    if big:
        for how, label in (("one_call", "one call"), ("chunked", "chunks of")):
            r = big[how]
            what = f"{label} {r['chunk_size']:,}" if how == "chunked" else label
            rows.append(
                (
                    f"ordinary, B = {big['B']:,}, {what}",
                    duration(1e-6 * r["per_problem_us"]),
                    duration(1e-6 * big["opencv_us"]),
                    f"{r['vs_opencv']:.1f}x",
                    "-",
                )
            )
    p = d.get("p3p")
    if p:
        rows.append(
            (
                f"three-point kernel, {p['triplets']:,} triplets",
                duration(1e-9 * p["ns_per_triplet"]) + " a triplet",
                duration(1e-9 * p["opencv_ns_per_triplet"]) + " (`solveP3P`)",
                f"{p['opencv_ns_per_triplet'] / p['ns_per_triplet']:.0f}x",
                "-",
            )
        )
    header = ("workload", f"jaxpose on the {kind}", "OpenCV on its CPU", "ratio", "at optimum")
    note = (
        f"`solve_pnp_batch` with its defaults on one {kind}, beside the loop of "
        "`cv2.solvePnP` (SQPNP) and `solvePnPRefineLM` on one core of the same machine's "
        "CPU (time per problem). Float64 throughout."
    )
    return (
        note
        + "\n\n"
        + table(header, rows)
        + "\n\n"
        + caption(d, name, command=f"python -m benchmarks.device --out benchmarks/results/{name}")
    )


def costs(results: Path) -> str:
    """What a call costs beside OpenCV's (the README's table, also `docs/generated/`):
    `solve_pnp` on one problem, `solve_pnp_batch` per problem, `solve_pnp_ransac`, each
    from its saved benchmark, with the machine it ran on."""
    speed_d, speed_name = load(results, "speed.json")
    rows = []

    def row(what, ours_s, peer, peer_s, data):
        m = data.get("machine")
        cpu = m.get("cpu") if isinstance(m, dict) else None
        ratio = ours_s / peer_s
        says = f"{ratio:.1f}x slower" if ratio >= 1 else f"{1 / ratio:.1f}x faster"
        rows.append((what, duration(ours_s), f"{duration(peer_s)} ({peer})", says, cpu or "-"))

    sqpnp = "`solvePnP` SQPNP + `solvePnPRefineLM`"
    lat = speed_d["latency"]["bench"]
    row(
        "`solve_pnp`, one problem (n = 16)",
        1e-3 * lat["ms"],
        sqpnp,
        1e-6 * lat["sqpnp_lm_us"],
        speed_d,
    )
    big = speed_d["batch"][-1]
    row(
        f"`solve_pnp_batch`, per problem of {big['B']:,} (n = 16)",
        1e-6 * big["per_problem_us"],
        "the same, in a loop",
        big["opencv_s"] / big["B"],
        speed_d,
    )
    try:
        rob, _ = load(results, "robust.json")
        cell = rob["cells"]["bench"]["0.30"]
        row(
            "`solve_pnp_ransac`, n = 16, 30% wrong matches",
            cell["jaxpose"]["per_call_s_median"],
            "`solvePnPRansac`",
            cell["cv2"]["per_call_s_median"],
            rob,
        )
    except (Missing, KeyError):
        pass
    header = ("call", "jaxpose", "OpenCV", "jaxpose is", "CPU")
    return (
        table(header, rows)
        + "\n\n"
        + caption(speed_d, speed_name, "robust.json", command="make bench")
    )
