"""The rerun recording options of the subcommands (`--rrd`, `--spawn`, `--serve`,
`--port`): declared, checked before any long computation, and the recording made."""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from ._common import CliError

__all__ = [
    "add_recording_options",
    "check_recording_args",
    "finish_recording",
    "make_recording",
    "open_recording",
    "wants_recording",
]


def add_recording_options(p: argparse.ArgumentParser) -> None:
    """Add the recording options to a subcommand's parser `p`."""
    g = p.add_argument_group("rerun recording (open a .rrd file with `rerun FILE`)")
    g.add_argument(
        "--rrd", metavar="PATH", help="write a rerun recording of the run to PATH (.rrd)"
    )
    g.add_argument(
        "--spawn",
        action="store_true",
        help="also stream the recording to a new native rerun viewer (needs a display)",
    )
    g.add_argument(
        "--serve",
        action="store_true",
        help="also serve the recording to the rerun web viewer, until Ctrl-C",
    )
    g.add_argument(
        "--port", type=int, default=9876, help="gRPC port for --spawn/--serve (default 9876)"
    )


def wants_recording(args) -> bool:
    """Whether the command line asks for a recording."""
    return bool(args.rrd or args.spawn or args.serve)


def check_recording_args(args) -> None:
    """Fail fast (before any long computation) on recording options that cannot work."""
    if args.rrd:
        path = Path(args.rrd)
        if path.suffix != ".rrd":
            raise CliError(f"--rrd must name a .rrd file, got {path}")
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise CliError(f"cannot write --rrd {path}: {exc.strerror or exc}") from None
        if path.is_dir() or not os.access(path if path.exists() else path.parent, os.W_OK):
            raise CliError(f"cannot write --rrd {path}: not writable")
    if args.spawn and sys.platform.startswith("linux"):
        if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
            raise CliError(
                "--spawn needs a display (DISPLAY is not set): use --serve, or --rrd and "
                "open the file where there is one"
            )
    if not 0 < args.port < 65536:
        raise CliError(f"--port must be in 1..65535, got {args.port}")


def open_recording(args, name: str, blueprint=None):
    """The recording stream asked for by --rrd / --spawn / --serve (`blueprint`: its
    layout, the default one when None), to log into as the command goes (finish it
    with `finish_recording`)."""
    from ..viz._rerun_recording import rerun_recording

    return rerun_recording(args.rrd, name=name, blueprint=blueprint, spawn=args.spawn,
                           serve=args.serve, port=args.port)  # fmt: skip


def finish_recording(args, console, rec) -> None:
    """Flush `rec`, say where it went, serve it until Ctrl-C with --serve, close it."""
    from ..viz._rerun_recording import close_recording, serve_web_viewer

    rec.flush()
    if args.rrd:
        console.print(f"wrote {args.rrd} (open it with: rerun {args.rrd})")
    if args.spawn:
        console.print("streamed the recording to the rerun viewer")
    if args.serve:
        url = serve_web_viewer(args.port)
        console.print(
            f"serving the recording: web viewer at {url} ; native viewer: "
            f"rerun rerun+http://127.0.0.1:{args.port}/proxy ; Ctrl-C to stop"
        )
        try:
            while True:
                time.sleep(1.0)
        except KeyboardInterrupt:
            pass
    close_recording(rec)


def make_recording(args, console, name: str, log) -> None:
    """Make the recording asked for by --rrd / --spawn / --serve; `log(rec)` fills it."""
    with console.status("writing the rerun recording..."):
        rec = open_recording(args, name)
        log(rec)
        rec.flush()
    finish_recording(args, console, rec)
