"""Cost of the backward pass through `jaxpose.solve`: forward alone against forward and
backward, on batches of default-bench problems.

Each problem is the default bench (the cross prism 2 m from a 25 mm camera, 16 matches,
all C(16, 3) = 560 triplets through the mixed algorithm) with its own seeded pixel noise
(0.8 px). The loss of one problem is a smooth function of the recovered pose,

    loss = |t - t_true|^2 + |R - R_true|_F^2 * (100 mm)^2,

and the two compiled functions timed are

    forward:            jax.jit(jax.vmap(loss))(cameras, models, images)
    forward + backward: jax.jit(jax.vmap(jax.value_and_grad(loss, argnums=(0, 1, 2))))

(gradients with respect to the camera matrix, the model points and the image points).
A batch larger than `--chunk` (64) runs as `jax.lax.map` over vmapped chunks of that
size, which bounds the memory (a single 1024-wide vmap of 560 triplets each would need
about 16 GB; a chunk of 64 needs about 1.5 GB). Each function is compiled first (a
warm-up call, not timed); then the two are timed alternately `--repeat` times, so that
the load of a shared machine weighs on both alike. The table reports medians (the JSON
every run), and `backward / forward`, the median over the runs of
`(forward+backward) / forward - 1`; the design target is <= 2.

    python benchmarks/gradients.py --batch 64 1024 --repeat 5

Prints a table and writes JSON to benchmarks/results/gradients.json.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
from pathlib import Path

if __name__ == "__main__" and not __package__:  # run as `python benchmarks/gradients.py`
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import jax
import jax.numpy as jnp
import numpy as np

import jaxpose as jp
from benchmarks._harness import RESULTS, timeit_many, write_json


def problems(batch: int):
    """`batch` default-bench problems, one noise seed each: (cameras, models, images,
    true R, true t), numpy float64."""
    benches = [jp.apps.default_bench(seed=s) for s in range(batch)]
    stack = lambda name: np.stack([getattr(b, name) for b in benches])
    return tuple(stack(n) for n in ("camera", "model_points", "image_points", "R", "t"))


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, nargs="+", default=[64, 1024])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--chunk", type=int, default=64)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    jax.config.update("jax_enable_x64", True)  # this script's own choice

    def loss(camera, model, image, R_true, t_true):
        pose = jp.solve(camera, model, image).pose
        return jnp.sum((pose.t - t_true) ** 2) + 1e4 * jnp.sum((pose.R - R_true) ** 2)

    value_and_grad = jax.value_and_grad(loss, argnums=(0, 1, 2))

    def batched(fn, B):
        if B <= args.chunk:
            return jax.jit(jax.vmap(fn))
        return jax.jit(lambda *xs: jax.lax.map(lambda x: fn(*x), xs, batch_size=args.chunk))

    rows = []
    for B in args.batch:
        forward, both = batched(loss, B), batched(value_and_grad, B)
        data = tuple(jnp.asarray(x) for x in problems(B))
        # A warm-up call each (the compile; its time kept as first_call_s), then calls
        # timed alternately: a loaded machine slows both alike.
        tf, tb = timeit_many((forward, both), *data, warmup=1, repeat=args.repeat)
        c_fwd, c_both = tf.first, tb.first
        value, grads = tb.result
        finite = bool(all(np.all(np.isfinite(np.asarray(g))) for g in grads))
        same = float(np.max(np.abs(np.asarray(value) - np.asarray(tf.result))))
        t_fwd, t_both = list(tf.times), list(tb.times)
        ratio = float(np.median(np.array(t_both) / np.array(t_fwd))) - 1
        fwd, fb = statistics.median(t_fwd), statistics.median(t_both)
        rows.append(
            {
                "batch": B,
                "forward_s": {"median": fwd, "best": min(t_fwd), "all": t_fwd},
                "forward_backward_s": {"median": fb, "best": min(t_both), "all": t_both},
                "first_call_s": {"forward": c_fwd, "forward_backward": c_both},
                "backward_over_forward": ratio,
                "per_problem_ms": {"forward": 1e3 * fwd / B, "forward_backward": 1e3 * fb / B},
                "gradients_finite": finite,
                "loss_max_difference": same,
            }
        )

    head = (
        f"{'batch':>6} {'forward (s)':>12} {'fwd+bwd (s)':>12} {'backward/forward':>17}"
        f" {'ms/problem fwd':>15} {'ms/problem f+b':>15}"
    )
    print(head)
    print("-" * len(head))
    for r in rows:
        fwd, fb = r["forward_s"]["median"], r["forward_backward_s"]["median"]
        ms = r["per_problem_ms"]
        print(
            f"{r['batch']:>6} {fwd:>12.3f} {fb:>12.3f} {r['backward_over_forward']:>17.2f}"
            f" {ms['forward']:>15.2f} {ms['forward_backward']:>15.2f}"
        )
    result = {
        "benchmark": "forward vs forward+backward through jaxpose.solve (mixed, default bench)",
        "loss": "|t - t_true|^2 + 1e4 |R - R_true|_F^2, grad w.r.t. camera, model, image",
        "repeat": args.repeat,
        "chunk": args.chunk,
        "dtype": "float64",
        "device": str(jax.devices()[0]),
        "cpu_count": os.cpu_count(),
        "platform": platform.platform(),
        "jax": jax.__version__,
        "rows": rows,
    }
    out = write_json(args.out or RESULTS / "gradients.json", result)
    print(f"wrote {out}")
    return result


if __name__ == "__main__":
    main()
