"""`jaxpose bench`: the paper protocol on the bench, timed against OpenCV's loop."""

from __future__ import annotations

import time

from ._common import new_console, setup_jax

__all__ = ["cmd_bench"]


def cmd_bench(args) -> int:
    """Run `jaxpose bench` with the parsed `args`; returns the exit code."""
    from rich.table import Table

    console = new_console()
    setup_jax(True)
    import cv2
    import jax
    import jax.numpy as jnp
    import numpy as np

    from ..api._solve import solve
    from ..apps import _bench as _bench

    bench = _bench.default_bench(seed=args.seed)
    C, M, I = (jnp.asarray(x) for x in (bench.camera, bench.model_points, bench.image_points))
    f = jax.jit(lambda C, M, I: solve(C, M, I, method="mixed"))
    with console.status("compiling the mixed algorithm..."):
        t0 = time.perf_counter()
        jax.block_until_ready(f(C, M, I))
        compile_s = time.perf_counter() - t0
    times = []
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        jax.block_until_ready(f(C, M, I))
        times.append(time.perf_counter() - t0)
    ours = float(np.median(times))

    # The equivalent OpenCV loop: P3P per triplet, best root over all matches, LM refine.
    from ..strategy import triplet_indices

    K = bench.K
    world = np.asarray(bench.model_points)
    img = np.asarray(bench.image_points)
    trip = triplet_indices(len(world))

    def opencv_loop():
        best = None
        for ijk in trip:
            try:
                n, rvecs, tvecs = cv2.solveP3P(
                    world[ijk], img[ijk], K, None, flags=cv2.SOLVEPNP_P3P
                )
            except cv2.error:
                continue
            for rv, tv in zip(rvecs[:n], tvecs[:n]):
                proj, _ = cv2.projectPoints(world, rv, tv, K, None)
                e = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - img) ** 2, 1))))
                if np.isfinite(e) and (best is None or e < best[0]):
                    best = (e, rv, tv)
            if best is not None:
                cv2.solvePnPRefineLM(world, img, K, None, best[1].copy(), best[2].copy())
        return best

    t0 = time.perf_counter()
    for _ in range(max(1, args.repeat // 10)):
        opencv_loop()
    cv = (time.perf_counter() - t0) / max(1, args.repeat // 10)
    table = Table(title=f"paper protocol: all {len(trip)} triplets of the bench")
    table.add_column("solver")
    table.add_column("time", justify="right")
    table.add_column("ratio", justify="right")
    table.add_row("jaxpose mixed (compiled)", f"{1e3 * ours:.2f} ms", "1.0x")
    table.add_row(
        "OpenCV loop (solveP3P, best root, RefineLM)",
        f"{1e3 * cv:.2f} ms",
        f"{cv / ours:.1f}x slower",
    )
    console.print(table)
    console.print(
        f"compile (first call): {compile_s:.1f} s. For the full benchmark suite: `make bench`."
    )
    return 0
