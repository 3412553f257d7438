"""What every `jaxpose` subcommand shares: the one-line error, the console, JAX's setup."""

from __future__ import annotations

import sys

__all__ = ["CliError", "camera_option", "new_console", "setup_jax", "write_report"]


class CliError(Exception):
    """An error to report as one line, without a traceback."""


def new_console():
    """A `rich` console for a subcommand's output."""
    from rich.console import Console

    # Table 1 needs about 100 columns; rich falls back to 80 when output is not a terminal.
    return Console(width=None if sys.stdout.isatty() else 110)


def setup_jax(x64: bool = True) -> None:
    """Configure JAX for this process: float64 when `x64`, and JAX's persistent
    compilation cache in `cache_dir()/xla` (`$JAXPOSE_CACHE_DIR` moves it or turns it
    off), unless the user configured one already."""
    import jax

    from ..api._programs import cache_dir

    # The command line owns its process: float64 (OpenCV-level accuracy) unless asked not
    # to, and JAX's persistent compilation cache so that a second run starts fast.
    jax.config.update("jax_enable_x64", x64)
    root = cache_dir()
    if root is None or getattr(jax.config, "jax_compilation_cache_dir", None):
        return
    try:
        (root / "xla").mkdir(parents=True, exist_ok=True)
        jax.config.update("jax_compilation_cache_dir", str(root / "xla"))
        # every program, the small ones of eager operations too: a command runs dozens,
        # each compiled in 10-40 ms, read back in well under 1 ms
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    except OSError:  # pragma: no cover - read-only home
        pass


def camera_option(path):
    """`(K, dist)` of the OpenCV camera file given as `--camera` (`jaxpose.features.read_camera`);
    a file that cannot be read is a `CliError` naming the option."""
    from ..features._files import read_camera

    try:
        return read_camera(path)
    except ValueError as exc:
        raise CliError(f"--camera {path}: {exc}") from None


def write_report(path, report: dict, option: str, console) -> None:
    """Write a command's JSON `report` to `path` (its folder made), saying so on
    `console`; a path that cannot be written is a `CliError` naming `option`."""
    from pathlib import Path

    from ._problem_write import dumps

    out = Path(path)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(dumps(report) + "\n")
    except OSError as exc:
        raise CliError(f"cannot write {option} {out}: {exc.strerror or exc}") from None
    console.print(f"wrote {out}")
