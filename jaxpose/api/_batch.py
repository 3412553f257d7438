"""Batches at scale: the batch axis sharded over devices, streamed in fixed-size chunks.

A batch of `B` independent problems is cut into chunks of `chunk_size` problems (the
last one padded by repeating its final problem, so that every chunk has the same shape
and one compiled program serves them all), and each chunk is split over the devices of
a one-axis `jax.sharding.Mesh` named `"batch"`: its batched inputs are placed with
`NamedSharding(mesh, P("batch"))`, the shared ones (the camera) replicated, and the
per-chunk function runs under `jax.shard_map`, every device solving its own rows with no
communication. Results are copied to the host chunk by chunk (the next chunk is already
dispatched while one is copied), so device memory holds about two chunks whatever `B`.

Every problem is computed by the same per-row program whatever the chunking or the
number of devices, so the results equal those of one unchunked call on one device
(`tests/test_sharding.py` checks it on 8 forced host devices).

On several hosts (`jax.distributed.initialize()` in every process first), `jax.devices()`
lists the devices of all processes; every process calls the same function with the same
full inputs, keeps only the rows its own devices hold (`jax.make_array_from_callback`),
and receives the full results (`multihost_utils.process_allgather`).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from ..geometry import no_type_check
from ._programs import Program, program_name

__all__ = ["batch_mesh", "batch_devices", "run_batched"]

#: The mesh axis that the batch is split over.
AXIS = "batch"


# (jaxlib ships no type stubs: pyright cannot see that `jax.Device` is a class.)
def batch_devices(devices=None) -> tuple[jax.Device, ...]:  # pyright: ignore[reportInvalidTypeForm]
    """The devices a batch is split over.

    **Arguments:**
    - `devices`: `None` (every device of the default backend, `jax.devices()`: on several
      hosts, those of all processes), an `int` `k` (the first `k` of them), or a sequence
      of `jax.Device`.

    **Returns:** a non-empty tuple of devices.

    **Raises:** `ValueError` naming `devices` for anything else.
    """
    available = jax.devices()
    if devices is None:
        return tuple(available)
    if isinstance(devices, (int, np.integer)) and not isinstance(devices, bool):
        if not 1 <= devices <= len(available):
            raise ValueError(
                f"devices must be between 1 and the {len(available)} available, got {devices}"
            )
        return tuple(available[: int(devices)])
    if isinstance(devices, jax.Device):
        return (devices,)
    if isinstance(devices, Sequence) and not isinstance(devices, str) and len(devices) > 0:
        if all(isinstance(d, jax.Device) for d in devices):
            if len(set(devices)) != len(devices):
                raise ValueError("devices must not repeat a device")
            return tuple(devices)
    raise ValueError(
        f"devices must be None, a positive int or a sequence of jax devices, got {devices!r}"
    )


def batch_mesh(devices=None) -> Mesh:
    """A one-axis mesh named `"batch"` over `devices` (see `batch_devices`)."""
    return Mesh(np.array(batch_devices(devices), dtype=object), (AXIS,))


def _check_chunk_size(chunk_size) -> int | None:
    if chunk_size is None:
        return None
    if isinstance(chunk_size, bool) or not isinstance(chunk_size, (int, np.integer)):
        raise ValueError(f"chunk_size must be a positive int or None, got {chunk_size!r}")
    if chunk_size < 1:
        raise ValueError(f"chunk_size must be >= 1, got {chunk_size}")
    return int(chunk_size)


@functools.lru_cache(maxsize=64)
def _compiled(
    fn: Callable, trailing: tuple, keywords: tuple, mesh: Mesh | None, n_shared: int, n_batched: int
):
    """`fn(*shared, *batched, *trailing, **keywords)`, jitted; under `shard_map` over `mesh`
    if given. Cached on its arguments, so that repeated calls reuse one compiled program;
    on one device a `Program`, whose executables are kept on disk too."""

    def call(*arrays):
        return fn(*arrays, *trailing, **dict(keywords))

    if mesh is None:
        return Program(call, program_name(fn, trailing, keywords))
    specs = (P(),) * n_shared + (P(AXIS),) * n_batched
    return jax.jit(
        jax.shard_map(call, mesh=mesh, in_specs=specs, out_specs=P(AXIS), check_vma=False)
    )


def _place(x: np.ndarray, sharding: NamedSharding | None) -> jax.Array:
    if sharding is None:
        return jnp.asarray(x)
    if jax.process_count() == 1:
        return jax.device_put(x, sharding)
    return jax.make_array_from_callback(x.shape, sharding, lambda index: x[index])


def _fetch(x: jax.Array) -> np.ndarray:
    if getattr(x, "is_fully_addressable", True):
        return np.asarray(x)
    return np.asarray(multihost_utils.process_allgather(x, tiled=True))


def _tail_size(rows: int, chunk: int, smallest: int, devices: int) -> int:
    """The padded size of a chunk of `rows` problems: the smallest `smallest * 2^k`
    holding them (a multiple of the device count), at most `chunk`."""
    size = max(1, smallest)
    while size < rows:
        size *= 2
    return min(chunk, math.ceil(size / devices) * devices)


def _pad_rows(x: np.ndarray, size: int) -> np.ndarray:
    """`x` with its last row repeated up to `size` rows (a valid problem, not zeros)."""
    if x.shape[0] == size:
        return x
    return np.concatenate([x, np.repeat(x[-1:], size - x.shape[0], axis=0)])


# `run_batched` checks its arguments itself (a `ValueError` naming the argument, whatever
# its type), so no run-time type check comes before its own.
@no_type_check
def run_batched(
    fn: Callable,
    shared: Sequence[Any],
    batched: Sequence[Any],
    *,
    static: Mapping[str, Any] | tuple = (),
    chunk_size: int | None = None,
    devices=None,
    min_tail: int | None = None,
) -> Any:
    """Run a batched function over a large batch: sharded over devices, chunk by chunk.

    `fn(*shared, *batched, *static)` (or `fn(*shared, *batched, **static)` when `static` is
    a mapping) must compute `B` independent problems: every output
    leaf has the batch axis first and row `i` depends on row `i` of the batched inputs
    only (a `jax.vmap` of a one-problem function, e.g. `jaxpose.api._pnp._batched_opencv`).

    **Arguments:**
    - `fn`: the batched function (hashable: a module-level or jitted function; compiled
      programs are cached on it and on `static`).
    - `shared`: arrays given whole to every chunk and device (replicated).
    - `batched`: arrays with the batch axis first, all of the same length `B >= 1`.
    - `static`: further arguments passed to `fn` as they are, not traced (hashable values):
      a tuple of trailing positional arguments or a mapping of keyword arguments.
    - `chunk_size`: at most this many problems per compiled call (rounded up to a multiple
      of the device count); `None`: the whole batch in one call. Memory on the devices
      scales with the chunk, not with `B`; the last chunk is padded by repeating its last
      problem, so every chunk has one shape (one compilation).
    - `devices`: see `batch_devices` (default: all devices). With one device the chunks
      run as plain jitted calls; with several, each chunk is split over them.
    - `min_tail`: `None` (the last chunk is padded to `chunk_size`; a batch of fewer
      problems than that runs as it is, a program per batch size), or a size: the last
      chunk, or a batch smaller than a chunk, is padded only to the smallest
      `min_tail * 2^k` that holds it (a few compiled shapes in all, whatever the batch
      sizes, and less padding for a remainder much smaller than the chunk).

    **Returns:** `fn`'s output pytree as numpy arrays of `B` rows (on every process).

    **Raises:** `ValueError` naming `chunk_size`, `devices` or `batched`.
    """
    chunk_size = _check_chunk_size(chunk_size)
    devs = batch_devices(devices)
    batched = [np.asarray(x) for x in batched]
    if not batched:
        raise ValueError("batched must hold at least one array")
    sizes = {x.shape[0] if x.ndim else None for x in batched}
    B = sizes.pop() if len(sizes) == 1 else None
    if B is None:
        shapes = [x.shape for x in batched]
        raise ValueError(f"batched arrays must share their first (batch) axis, got {shapes}")
    if B < 1:
        raise ValueError("batched arrays hold no problem (batch size 0)")
    shared = [np.asarray(x) for x in shared]
    if isinstance(static, Mapping):
        trailing, keywords = (), tuple(sorted(static.items()))
    else:
        trailing, keywords = tuple(static), ()
    k = len(devs)
    # With `min_tail`, a batch smaller than a chunk is padded like a tail (to a bucket of
    # sizes, one compiled program for every batch size in it); without, it runs whole.
    chunk = (chunk_size or B) if min_tail is not None else min(B, chunk_size or B)
    chunk = math.ceil(chunk / k) * k
    if k == 1:
        mesh, row_sharding, whole = None, None, None
        shared_dev = [jax.device_put(x, devs[0]) for x in shared]
        put = lambda x: jax.device_put(x, devs[0])
    else:
        mesh = batch_mesh(devs)
        row_sharding = NamedSharding(mesh, P(AXIS))
        whole = NamedSharding(mesh, P())
        shared_dev = [_place(x, whole) for x in shared]
        put = lambda x: _place(x, row_sharding)
    call = _compiled(fn, trailing, keywords, mesh, len(shared), len(batched))

    outputs: list[np.ndarray] = []  # filled by the first chunk's results
    treedef = None

    def collect(start: int, stop: int, result) -> None:
        nonlocal treedef
        leaves, tdef = jax.tree.flatten(result)
        if treedef is None:
            treedef = tdef
            outputs.extend(np.empty((B, *leaf.shape[1:]), leaf.dtype) for leaf in leaves)
        for out, leaf in zip(outputs, leaves, strict=True):
            out[start:stop] = _fetch(leaf)[: stop - start]

    pending = None
    for start in range(0, B, chunk):
        stop = min(start + chunk, B)
        size = chunk if min_tail is None else _tail_size(stop - start, chunk, min_tail, k)
        rows = [put(_pad_rows(x[start:stop], size)) for x in batched]
        result = call(*shared_dev, *rows)  # dispatched asynchronously
        if pending is not None:
            collect(*pending)
        pending = (start, stop, result)
    if pending is not None:  # always: B >= 1
        collect(*pending)
    return jax.tree.unflatten(treedef, outputs)
