"""`jaxpose warmup`: build the compiled programs of `solve_pnp`, `solve` (and a plain
`jax.grad` of it) and `solve_pnp_batch` ahead of time, into the program cache
(`jaxpose.api._programs`), with a progress bar; with `--track`, the tracker's too
(`jaxpose.apps._track_warmup`: the per-frame solve's buckets and the offline
refinement's that `jaxpose track` runs on a 640 x 480 video)."""

from __future__ import annotations

import time

from ._common import CliError, new_console

__all__ = ["cmd_warmup"]


def cmd_warmup(args) -> int:
    """Run `jaxpose warmup` with the parsed `args`; returns the exit code."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from ..api._programs import cache_dir, fingerprint
    from ..api._warmup import warm_up_plan

    console = new_console()
    if any(p < 3 for p in args.points) or any(b < 1 for b in args.batch):
        raise CliError("--points must be >= 3 and --batch >= 1")
    root = cache_dir()
    if root is None:
        console.print("[yellow]the program cache is off (JAXPOSE_CACHE_DIR): nothing is kept")
    plan = warm_up_plan(args.points, args.batch)
    if args.track:
        from ..apps._track_warmup import track_warm_up_plan

        plan += track_warm_up_plan()
    compiled = 0
    t0 = time.perf_counter()
    with Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total}"),
        TimeElapsedColumn(),
        console=console,
    ) as bar:
        task = bar.add_task("programs", total=len(plan))
        for what, build in plan:
            bar.update(task, description=what)
            compiled += bool(build())
            bar.advance(task)
    where = "nowhere (cache off)" if root is None else str(root / "programs" / fingerprint())
    console.print(
        f"{len(plan)} programs ready ({compiled} compiled, {len(plan) - compiled} found) "
        f"in {time.perf_counter() - t0:.1f} s: {where}"
    )
    return 0
