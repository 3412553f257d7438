"""Strict test configuration: float64, rank promotion raises, warnings are errors; compiled
programs cached for the run."""

import os
from pathlib import Path

os.environ.setdefault(
    "XLA_FLAGS", "--xla_force_host_platform_device_count=1 --xla_cpu_use_fusion_emitters=false"
)
# One compilation of each program for the whole run, shared by the workers (and by the
# command-line subprocesses, which read the same variable): jaxpose's program cache and
# JAX's persistent compilation cache under .pytest_cache/.
CACHE = Path(__file__).resolve().parent.parent / ".pytest_cache" / "jaxpose"
os.environ.setdefault("JAXPOSE_CACHE_DIR", str(CACHE))

import jax  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from hypothesis import HealthCheck, settings  # noqa: E402

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_rank_promotion", "raise")
jax.config.update("jax_numpy_dtype_promotion", "standard")
jax.config.update("jax_compilation_cache_dir", str(CACHE / "xla"))
jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)

settings.register_profile(
    "default",
    deadline=None,
    max_examples=60,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "default"))


@pytest.fixture
def rng():
    return np.random.default_rng(0)


# The slowest files first (compile-bound; measured on 2 cores: 30-140 s each). With
# `--dist loadfile --no-loadscope-reorder` (the Makefile's) the workers take files in
# this order, each taking the next when it is free (longest first), so a long file is
# not left to run alone at the end while the other worker idles. (xdist's default
# reorders files by their number of tests instead.)
SLOW_FIRST = (
    "test_gradients.py",
    "test_fuzz.py",
    "test_best.py",
    "test_api.py",
    "test_programs.py",
    "test_mixed.py",
    "test_kernel_p3p.py",
    "test_sharding.py",
    "test_recognition.py",
    "test_kernel_linear.py",
    "test_mixed_planar.py",
    "test_rerun.py",
    "test_cli_warmup.py",
)


def pytest_collection_modifyitems(items):
    rank = {name: i for i, name in enumerate(SLOW_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))


# The count of XLA compilations of the run (JAX's `backend_compile_duration` events,
# which the persistent cache's hits do not raise), per worker, written to
# `$JAXPOSE_COMPILE_LOG` when set: a clean clone's count is the suite's program count.
_COMPILES = {"count": 0, "seconds": 0.0}
# With `$JAXPOSE_COMPILE_DETAIL` set too, every compilation is written there, one line
# each: worker, test, program name, seconds; and each tracing and lowering, named
# `trace:` and `lower:` and the function.
_DETAIL = {"test": "collection", "lines": []}


#: JAX's events of the steps before compilation: tracing to a jaxpr, lowering it to MLIR.
_STEPS = {
    "/jax/core/compile/jaxpr_trace_duration": "trace",
    "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower",
}


def _count_compile(event, duration, **kwargs):
    if event == "/jax/core/compile/backend_compile_duration":
        _COMPILES["count"] += 1
        _COMPILES["seconds"] += duration
        name = _DETAIL.get("program") or kwargs.get("fun_name", "?")
        _DETAIL["lines"].append(f"{_DETAIL['test']}\t{name}\t{duration:.3f}")
    elif event in _STEPS and os.environ.get("JAXPOSE_COMPILE_DETAIL"):
        name = f"{_STEPS[event]}:{kwargs.get('fun_name', '?')}"
        _DETAIL["lines"].append(f"{_DETAIL['test']}\t{name}\t{duration:.3f}")


if os.environ.get("JAXPOSE_COMPILE_LOG"):
    jax.monitoring.register_event_duration_secs_listener(_count_compile)

if os.environ.get("JAXPOSE_COMPILE_DETAIL"):
    # A stored program's compilation is named by its file (the hash of its key), so that
    # one built twice (by both workers, or again in a later test) shows.
    from jaxpose.api import _programs

    _compile_and_store = _programs.Program._compile_and_store

    def _named_compile(self, args, path, key):
        _DETAIL["program"] = "program:" + (path.name if path is not None else self.name[:60])
        try:
            return _compile_and_store(self, args, path, key)
        finally:
            _DETAIL["program"] = None

    _programs.Program._compile_and_store = _named_compile


@pytest.hookimpl(wrapper=True)
def pytest_runtest_protocol(item, nextitem):
    _DETAIL["test"] = item.nodeid
    return (yield)


def pytest_sessionfinish(session):
    log = os.environ.get("JAXPOSE_COMPILE_LOG")
    if log:
        worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
        with open(log, "a") as f:
            f.write(f"{worker} {_COMPILES['count']} {_COMPILES['seconds']:.1f}\n")
    detail = os.environ.get("JAXPOSE_COMPILE_DETAIL")
    if detail:
        worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
        with open(detail, "a") as f:
            f.writelines(f"{worker}\t{line}\n" for line in _DETAIL["lines"])
