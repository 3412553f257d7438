"""Compiled programs that outlive the process, and the shape buckets that bound them.

The numpy-in, numpy-out entry points (`solve_pnp`, `solve_pnp_batch`) run through a
`Program`: a function compiled once per input signature (shapes, dtypes), whose XLA
executables are kept

- in the process, one per signature;
- on disk, serialized (`jax.experimental.serialize_executable`), so that a new process
  skips tracing, lowering and XLA compilation alike: loading a program takes
  milliseconds where compiling it takes seconds.

**Buckets.** The number of points `n` is padded (the padding masked out) to
`bucket_points(n)`: 8, 16, 32, 64, ... points, so that every `n` from 4 to 40 runs one
of four programs; batches run in chunks of `16 * 2^k` problems (`jaxpose.api._pnp`).

**Where.** `$JAXPOSE_CACHE_DIR` when set (`off`, `0`, `false`, `no` or empty: no disk
cache), else `$XDG_CACHE_HOME/jaxpose`, else `~/.cache/jaxpose`; programs live in
`programs/<fingerprint>/` under it. The fingerprint hashes jaxpose's own source files,
the versions of jax and jaxlib, the backend, its devices and the processor: after an
upgrade, an edit of the sources or on another machine a new folder is read, never an old
program; when a new one is made, the folders of all but the `KEEP_BUILDS` builds used most
recently are removed. A file that cannot be read back (truncated, or from an incompatible
build) is compiled again and replaced. JAX's global configuration (its own persistent
cache included) is never touched.

`warm_up` (`jaxpose warmup` on the command line) builds the standard programs ahead of
time.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import inspect
import os
import pickle
import platform
import shutil
import tempfile
import threading
from collections.abc import Callable, Hashable
from pathlib import Path
from typing import Any

import jax
import numpy as np
from jax.core import Tracer


def _version(package: str) -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(package)
    except PackageNotFoundError:  # pragma: no cover
        return "?"


__all__ = [
    "CACHE_ENV",
    "CPU_COMPILER_OPTIONS",
    "KEEP_BUILDS",
    "POINT_BUCKETS",
    "Program",
    "bucket_points",
    "cache_dir",
    "compiler_options",
    "fingerprint",
    "program",
    "program_name",
    "stored_jit",
]

#: The environment variable that moves (a folder) or turns off (`off`) the disk cache.
CACHE_ENV = "JAXPOSE_CACHE_DIR"
_OFF = {"", "0", "off", "false", "no", "none"}

#: Point-count buckets: `n` runs the program of the smallest bucket holding it; above the
#: last one, the next power of two.
POINT_BUCKETS = (8, 16, 32, 64, 128, 256, 512, 1024)

# The serialized program's header: a file from another layout is never unpickled as one.
_MAGIC = b"jaxpose-program-2\n"


def bucket_points(n: int) -> int:
    """The padded point count of a problem with `n` points (`POINT_BUCKETS`)."""
    for size in POINT_BUCKETS:
        if n <= size:
            return size
    return 1 << (int(n) - 1).bit_length()


def cache_dir() -> Path | None:
    """The disk cache's root folder (read from the environment at each call), or `None`
    when it is turned off."""
    env = os.environ.get(CACHE_ENV)
    if env is not None:
        return None if env.strip().lower() in _OFF else Path(env).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg).expanduser() if xdg else Path.home() / ".cache"
    return base / "jaxpose"


def _processor() -> str:
    """The processor's model name and feature flags (a program compiled for one need not
    run on another)."""
    with contextlib.suppress(OSError):
        text = Path("/proc/cpuinfo").read_text()
        keep = [line for line in text.splitlines() if line.startswith(("model name", "flags"))]
        return "\n".join(sorted(set(keep)))
    return f"{platform.machine()} {platform.processor()}"


_FINGERPRINT: str | None = None


def fingerprint() -> str:
    """A hash of what a compiled program depends on beyond its own inputs: jaxpose's
    source files, jax and jaxlib, the backend and its devices, the processor."""
    global _FINGERPRINT
    if _FINGERPRINT is None:
        h = hashlib.sha256()
        package = Path(__file__).resolve().parents[1]
        for path in sorted(package.rglob("*.py")):
            h.update(str(path.relative_to(package)).encode())
            h.update(path.read_bytes())
        h.update(f"{jax.__version__} {_version('jaxlib')}".encode())
        h.update(" ".join(f"{d.platform}:{d.device_kind}" for d in jax.devices()).encode())
        h.update(_processor().encode())
        h.update(os.environ.get("XLA_FLAGS", "").encode())
        _FINGERPRINT = h.hexdigest()[:20]
    return _FINGERPRINT


#: Program folders kept: this build's and those of the builds used most recently before
#: it (processes with other `XLA_FLAGS`, another virtual environment), so that two of
#: them on one machine do not delete each other's programs; older folders are removed.
KEEP_BUILDS = 4

_TOUCHED: set[Path] = set()


def _folder() -> Path | None:
    """This build's program folder (made on first use; when made, the folders of all but
    the `KEEP_BUILDS` most recently used builds removed), or `None` when the disk cache
    is off or cannot be written."""
    root = cache_dir()
    if root is None:
        return None
    programs = root / "programs"
    here = programs / fingerprint()
    if here.is_dir():
        if here not in _TOUCHED:  # used: its age counts from now
            _TOUCHED.add(here)
            with contextlib.suppress(OSError):
                os.utime(here)
        return here
    try:
        here.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    _TOUCHED.add(here)
    with contextlib.suppress(OSError):
        others = [p for p in programs.iterdir() if p != here and p.is_dir()]
        others.sort(key=lambda p: p.stat().st_mtime, reverse=True)
        for other in others[KEEP_BUILDS - 1 :]:  # builds not used for longest
            shutil.rmtree(other, ignore_errors=True)
    return here


_RUNTIME_READY = False


def _prepare_runtime() -> None:
    """Load what a deserialized program calls into: the CPU's LAPACK kernels are set up
    by JAX when it first lowers a linear-algebra operation, not when it loads a program
    that uses them (which would crash). jaxlib's own initialisation does it (0.3 s);
    should that entry point move, lowering a tiny solve does it too (1-2 s)."""
    global _RUNTIME_READY
    with _RUNTIME_LOCK:
        if not _RUNTIME_READY:
            _initialise_runtime()
            _RUNTIME_READY = True


_RUNTIME_LOCK = threading.Lock()


def _initialise_runtime() -> None:
    try:
        from jaxlib import lapack

        lapack._lapack.initialize()  # type: ignore[attr-defined]
    except Exception:  # pragma: no cover - another jaxlib layout
        import jax.numpy as jnp

        jax.jit(jnp.linalg.solve).lower(jnp.eye(2), jnp.ones(2))


def _signature(args) -> tuple:
    """The arguments' structure (pytrees: tuples, named tuples, `None`) and the shape and
    dtype of each array."""
    leaves, tree = jax.tree.flatten(args)
    return (str(tree), *((tuple(np.shape(a)), str(a.dtype)) for a in map(_array, leaves)))


def _array(a):
    return a if hasattr(a, "dtype") else np.asarray(a)


def _read_program(path: Path, key: bytes | None = None) -> tuple[bytes, Any] | None:
    """The key and the loaded executable of the program file `path`, or `None` (no such
    file, a broken or foreign one, or one whose key is not `key` when given: compiled
    again and replaced by its `Program`)."""
    from jax.experimental.serialize_executable import deserialize_and_load

    try:
        data = path.read_bytes()
        if not data.startswith(_MAGIC):
            return None
        stored_key, lapack, payload, in_tree, out_tree = pickle.loads(data[len(_MAGIC) :])
        if key is not None and stored_key != key:
            return None
        if lapack:
            _prepare_runtime()
        return stored_key, deserialize_and_load(payload, in_tree, out_tree)
    except Exception:
        return None


# ------------------------------------------------- a command's programs, loaded ahead

#: The program files this process loaded or compiled, in order (`remember`).
_USED: list[Path] = []
#: Where each tag's use began in `_USED` (its `prefetch`).
_SINCE: dict[str, int] = {}
#: Program files being loaded by `prefetch`: path -> future of `_read_program`'s result.
_PREFETCHED: dict[Path, Any] = {}


def prefetch(tag: str) -> None:
    """Start loading, in background threads (one a program), the programs that the last process of
    `tag` (a command, e.g. `"recognize"`) used (`remember`), so that loading them (XLA's
    own work, which leaves Python free) overlaps what the process does before it needs
    them (reading and preparing its inputs, detecting an image's primitives). A
    `Program` that needs one of them waits for it instead of loading it again; one
    not needed is loaded for nothing, off the main thread. Nothing when the disk cache
    is off or `tag` has no list yet."""
    from concurrent.futures import Future

    _SINCE[tag] = len(_USED)
    folder = _folder()
    if folder is None:
        return
    try:
        names = (folder / f"used-{tag}.txt").read_text().split()
    except OSError:
        return
    # (not those this process has already used, nor those under way)
    used = set(_USED)
    paths = [folder / name for name in names if name.endswith(".bin")]
    paths = [p for p in paths if p not in used and p not in _PREFETCHED and p.is_file()]
    futures = {p: Future() for p in paths}
    _PREFETCHED.update(futures)

    def load(path: Path, future: Future) -> None:
        if future.set_running_or_notify_cancel():
            try:
                future.set_result(_read_program(path))
            except BaseException as exc:  # pragma: no cover - reported to the waiter
                future.set_exception(exc)

    # (one thread a program: XLA loads them side by side, on the machine's cores)
    for path, future in futures.items():
        name = "jaxpose-prefetch"
        threading.Thread(target=load, args=(path, future), name=name, daemon=True).start()


def remember(tag: str) -> None:
    """Write the program files this process used since `tag`'s `prefetch` (or since it
    started) as `tag`'s list, when it changed."""
    folder = _folder()
    if folder is None:
        return
    names = dict.fromkeys(p.name for p in _USED[_SINCE.get(tag, 0) :] if p.parent == folder)
    if not names:
        return
    path = folder / f"used-{tag}.txt"
    text = "\n".join(names) + "\n"
    with contextlib.suppress(OSError):
        if not path.is_file() or path.read_text() != text:
            path.write_text(text)


class Program:
    """`fn(*arrays)` compiled once per input signature, its executables kept in the
    process and on disk (see the module docstring). The arguments and the result may be
    pytrees of arrays (tuples, named tuples, `None`).

    `name` identifies the program on disk together with the signature: it must name
    the function and every value closed over it (e.g. the `Options`), as `program` does.
    `compiled` counts the XLA compilations this object ran, `loaded` the programs it read
    from disk.
    """

    def __init__(self, fn: Callable, name: str):
        self._jit = jax.jit(fn)
        self.name = name
        self._memo: dict[tuple, Any] = {}
        self._lock = threading.Lock()
        self.compiled = 0
        self.loaded = 0
        self._unproven: set[tuple] = set()  # loaded from disk, not yet run

    @staticmethod
    def _path(key: bytes) -> Path | None:
        folder = _folder()
        if folder is None:
            return None
        return folder / f"{hashlib.sha256(key).hexdigest()[:32]}.bin"

    def _load(self, path: Path | None, key: bytes):
        if path is None:
            return None
        pending = _PREFETCHED.pop(path, None)
        if pending is not None:  # being loaded by `prefetch`: its result, when it is ours
            loaded = pending.result()
            if loaded is not None and loaded[0] == key:
                return loaded[1]
        loaded = _read_program(path, key)
        return None if loaded is None else loaded[1]

    def _store(self, path: Path | None, key: bytes, compiled) -> None:
        from jax.experimental.serialize_executable import serialize

        if path is None:
            return
        tmp = None
        try:
            payload, in_tree, out_tree = serialize(compiled)
            lapack = "lapack_" in compiled.as_text()  # calls LAPACK (see `_prepare_runtime`)
            data = _MAGIC + pickle.dumps((key, lapack, payload, in_tree, out_tree))
            fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".part-")
            with os.fdopen(fd, "wb") as f:
                f.write(data)
            os.replace(tmp, path)  # atomic: a reader sees the whole file or none
        except Exception:  # a cache that cannot be written costs speed, never an answer
            if tmp is not None:
                with contextlib.suppress(OSError):
                    os.unlink(tmp)

    def executable(self, *args):
        """The compiled program for `args` (loaded from disk, or compiled and stored)."""
        return self._executable(args, _signature(args))

    def _executable(self, args: tuple, signature: tuple):
        exe = self._memo.get(signature)
        if exe is not None:
            return exe
        with self._lock:
            exe = self._memo.get(signature)
            if exe is not None:
                return exe
            path, key = self._where(signature)
            if path is not None:
                _USED.append(path)
            exe = self._load(path, key)
            if exe is not None:
                self.loaded += 1
                self._unproven.add(signature)
            else:
                exe = self._compile_and_store(args, path, key)
            self._memo[signature] = exe
            return exe

    def _where(self, signature: tuple) -> tuple[Path | None, bytes]:
        x64 = jax.dtypes.canonicalize_dtype(np.float64) == np.float64
        key = repr((self.name, signature, bool(x64))).encode()
        return self._path(key), key

    def _compile_and_store(self, args, path: Path | None, key: bytes):
        exe = _compile(self._jit.lower(*args), fresh=path is not None)
        self.compiled += 1
        self._store(path, key, exe)
        return exe

    def __call__(self, *args):
        signature = _signature(args)
        exe = self._executable(args, signature)
        if signature not in self._unproven:
            return exe(*args)
        # The first run of a program read from disk: one that cannot run in this process
        # (its machine code incomplete) is compiled again and its file replaced.
        try:
            out = jax.block_until_ready(exe(*args))
        except jax.errors.JaxRuntimeError:
            with self._lock:
                exe = self._compile_and_store(args, *self._where(signature))
                self._memo[signature] = exe
            out = exe(*args)
        self._unproven.discard(signature)
        return out


#: XLA options of the programs compiled for the CPU. XLA:CPU's element-wise emitters
#: (not its newer MLIR fusion emitters) compile the standard programs in about 25% less
#: time (the `solve_pnp` program: 4.3 -> 3.2 s) and run them as fast (one problem: 0.37
#: vs 0.36 ms; 4,096: 8.0 vs 8.2 us per problem), measured with `benchmarks.startup`
#: and `benchmarks.speed`. Per program: JAX's global configuration is not touched.
CPU_COMPILER_OPTIONS = {"xla_cpu_use_fusion_emitters": False}


def compiler_options() -> dict:
    """The XLA options of `Program`'s compilations on this backend."""
    return dict(CPU_COMPILER_OPTIONS) if jax.default_backend() == "cpu" else {}


def _compile(lowered, fresh: bool):
    """`lowered.compile()` with `compiler_options()`; `fresh`: bypassing JAX's persistent
    compilation cache (when one is configured). An executable that cache hands back
    serializes without its machine code on the CPU (jax 0.10: the stored program, once
    loaded, fails with "Function ... not found"), so a program that will be stored is
    always compiled."""
    with _without_jax_cache() if fresh else contextlib.nullcontext():
        return lowered.compile(compiler_options=compiler_options())


_BYPASS = threading.Lock()


@contextlib.contextmanager
def _without_jax_cache():
    """JAX's persistent compilation cache neither read nor written inside. Its switch
    (`enable_compilation_cache`) alone is not enough: JAX decides whether the cache is
    used at its first compilation in the process and keeps the answer, so after any
    compilation with the cache on (an eager operation, e.g. under a plain `jax.grad`) a
    program would still be taken from it; that decision is set aside here too, and put
    back after."""
    try:
        from jax._src import compilation_cache as cache
        from jax._src.config import enable_compilation_cache
    except ImportError:  # pragma: no cover - a jax without the switch
        yield
        return
    with _BYPASS, enable_compilation_cache(False):
        decided = (getattr(cache, "_cache_checked", None), getattr(cache, "_cache_used", None))
        if None in decided:  # pragma: no cover - another jax: the switch alone
            yield
            return
        cache._cache_checked, cache._cache_used = True, False
        try:
            yield
        finally:
            cache._cache_checked, cache._cache_used = decided


def program_name(fn: Callable, static: tuple = (), keywords: tuple = ()) -> str:
    """The name of `fn(*arrays, *static, **dict(keywords))` on disk: the function's
    module and qualified name and the `repr` of the static values (e.g. an `Options`)."""
    target = getattr(fn, "__wrapped__", fn)
    return f"{target.__module__}.{target.__qualname__}{static!r}{keywords!r}"


_PROGRAMS: dict[tuple, Program] = {}


def program(fn: Callable, *static: Hashable) -> Program:
    """The `Program` of `lambda *arrays: fn(*arrays, *static)` (one per `fn` and
    `static`, for the life of the process). `fn` is a module-level function; `static`
    values are hashable and their `repr` names them (e.g. an `Options`)."""
    key = (fn, static)
    found = _PROGRAMS.get(key)
    if found is None:
        name = program_name(fn, static)
        found = _PROGRAMS[key] = Program(lambda *arrays: fn(*arrays, *static), name)
    return found


_KEYWORD_PROGRAMS: dict[tuple, Program] = {}


def stored_jit(fn: Callable | None = None, *, static_argnames: tuple[str, ...] = ()) -> Any:
    """`jax.jit(fn, static_argnames=...)` whose calls on concrete arrays run a stored
    `Program` (compiled once per signature and static values, loaded by later processes);
    traced calls (under the caller's `jit`, `vmap` or `grad`) run `jax.jit(fn)`. Static
    arguments may be given by position or keyword; their `repr` names the program on
    disk. Usable as a decorator, with or without arguments."""
    if fn is None:
        return functools.partial(stored_jit, static_argnames=static_argnames)
    jitted = jax.jit(fn, static_argnames=static_argnames)
    signature = inspect.signature(fn)
    names = tuple(static_argnames)

    @functools.wraps(fn)
    def call(*args, **kwargs):
        bound = signature.bind(*args, **kwargs)
        bound.apply_defaults()
        static = tuple((k, bound.arguments[k]) for k in names)
        arrays = tuple(v for k, v in bound.arguments.items() if k not in names)
        if any(isinstance(x, Tracer) for x in jax.tree.leaves(arrays)):
            return jitted(*args, **kwargs)
        key = (fn, static)
        found = _KEYWORD_PROGRAMS.get(key)
        if found is None:
            keys = tuple(k for k in bound.arguments if k not in names)

            def run(*values, keys=keys, static=static):
                return fn(**dict(zip(keys, values, strict=True)), **dict(static))

            name = program_name(fn, (), static)
            found = _KEYWORD_PROGRAMS[key] = Program(run, name)
        return found(*arrays)

    return call
