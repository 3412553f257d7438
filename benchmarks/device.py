"""The batch benchmarks on whatever device JAX uses by default (a GPU where there is one).

    python -m benchmarks.device --out benchmarks/results/device_h100.json
    python -m benchmarks.device --quick            # smaller sizes, to try it on a CPU

Sections, each written to the output file as soon as it is done (a run cut short keeps
what it finished):

- `classes`: `speed.classes`, `solve_pnp_batch` with its defaults on each problem class
  at two batch sizes, beside the SQPnP + RefineLM loop run on the same machine's CPU
  (one core, as a user's loop runs).
- `large`: `solve_pnp_batch` on 10^5 ordinary problems in one call and in chunks
  (`chunk_size`), the time per problem beside the loop's.
- `p3p`: the three-point kernel over 10^6 triplets in one call, per triplet, beside
  `cv2.solveP3P` per triplet on the CPU.

The output names the device (`jax.devices()`) and the host CPU beside every figure.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

if __name__ == "__main__" and not __package__:  # run as `python benchmarks/device.py`
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import jax

jax.config.update("jax_enable_x64", True)

import cv2  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import jaxpose as jp  # noqa: E402
from benchmarks import speed  # noqa: E402
from benchmarks._harness import K_PIXELS, machine, opencv_block, timeit  # noqa: E402


def large(B: int, chunk: int, repeat: int) -> dict:
    """`solve_pnp_batch` on `B` ordinary problems, in one call and in chunks of `chunk`."""
    K, obj, img = speed.class_problems("ordinary", B, seed=3)
    count = 100
    starts = iter(range(0, B - count + 1, count))
    blocks = timeit(
        lambda: opencv_block(obj, img, K, next(starts), count),
        warmup=0,
        repeat=10,
        block=False,
    )
    per_cv = blocks.best / count
    out: dict = {"B": B, "opencv_us": 1e6 * per_cv}
    for name, kw in (("one_call", {}), ("chunked", {"chunk_size": chunk})):
        t = timeit(lambda kw=kw: jp.solve_pnp_batch(obj, img, K, **kw), warmup=2, repeat=repeat)
        ok = np.asarray(t.result[0])
        out[name] = {
            "seconds": t.best,
            "compile_s": None if t.first is None else max(0.0, t.first - t.best),
            "per_problem_us": 1e6 * t.best / B,
            "vs_opencv": per_cv * B / t.best,
            "ok": float(np.mean(ok)),
        }
        if name == "chunked":
            out[name]["chunk_size"] = chunk
        print(f"  large {name}: {out[name]['per_problem_us']:.2f} us/problem", flush=True)
    return out


def p3p(count: int, repeat: int, peer_count: int = 2000) -> dict:
    """The three-point kernel over `count` triplets in one call, beside `cv2.solveP3P`."""
    from jaxpose.solvers._kernel_p3p import three_point_batch

    C, model, uv = speed._triplets(count, seed=2)
    args = tuple(jnp.asarray(a, jnp.float64) for a in (C, model, uv))
    t = timeit(jax.jit(three_point_batch), *args, warmup=3, repeat=repeat)
    k = min(peer_count, count)

    def opencv():
        for i in range(k):
            cv2.solveP3P(model[i], uv[i], K_PIXELS, None, flags=cv2.SOLVEPNP_P3P)

    cv = timeit(opencv, warmup=0, repeat=3, block=False).best
    out = {
        "triplets": count,
        "ns_per_triplet": 1e9 * t.best / count,
        "solved": float(np.mean(np.asarray(t.result.valid).any(axis=-1))),
        "opencv_ns_per_triplet": 1e9 * cv / k,
    }
    print(f"  p3p: {out['ns_per_triplet']:.2f} ns/triplet", flush=True)
    return out


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="benchmarks/results/device.json")
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--sections", nargs="+", default=["classes", "large", "p3p"])
    args = parser.parse_args(argv)
    out_path = Path(args.out)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    dev = jax.devices()[0]
    info = machine()
    info["devices"] = info["jax_devices"] = [f"{d.device_kind} ({d})" for d in jax.devices()]
    res: dict = {
        "machine": info,
        "device": {"platform": dev.platform, "kind": dev.device_kind, "count": jax.device_count()},
        "quick": args.quick,
    }
    print(f"device: {dev.platform} {dev.device_kind}; host: {res['machine']['cpu']}", flush=True)

    def save():
        out_path.write_text(json.dumps(res, indent=1))

    save()
    start = time.perf_counter()
    if "classes" in args.sections:
        sizes = (200, 1000) if args.quick else (2000, 10_000)
        res["classes"] = speed.classes(sizes, repeat=3 if args.quick else 5)
        save()
    if "large" in args.sections:
        B = 4000 if args.quick else 100_000
        res["large"] = large(B, chunk=1000 if args.quick else 25_000, repeat=3)
        save()
    if "p3p" in args.sections:
        res["p3p"] = p3p(20_000 if args.quick else 1_000_000, repeat=10)
        save()
    res["seconds"] = time.perf_counter() - start
    save()
    print(f"wrote {out_path} ({res['seconds']:.0f} s)", flush=True)
    return res


if __name__ == "__main__":
    main()
