"""A rerun recording stream for jaxpose: made (to a file, a viewer, a server), closed,
and served to the web viewer."""

from __future__ import annotations

import urllib.parse
import uuid
from pathlib import Path
from typing import TYPE_CHECKING

from ._rerun_common import _rr
from ._rerun_layout import rerun_blueprint

if TYPE_CHECKING:  # pragma: no cover
    import rerun as rr
    import rerun.blueprint as rrb

__all__ = ["close_recording", "rerun_recording", "serve_web_viewer"]

APPLICATION_ID = "jaxpose"


def rerun_recording(
    path: str | Path | None = None,
    *,
    name: str | None = None,
    blueprint: rrb.Blueprint | None = None,
    spawn: bool = False,
    serve: bool = False,
    port: int = 9876,
) -> rr.RecordingStream:
    """A new, independent recording stream (not the global one) for `jaxpose`.

    Everything logged to it afterwards goes to the sinks chosen here; with none, it is
    buffered in memory (e.g. for `RecordingStream.notebook_show`). Finish it with
    `close_recording` so that files get their footer.

    **Arguments:**
    - `path`: stream to this `.rrd` file.
    - `name`: the recording's name shown in the viewer.
    - `blueprint`: the default layout (`rerun_blueprint()` when None).
    - `spawn`: start the native rerun viewer (it needs a display) and stream to it.
    - `serve`: host a gRPC server on `port` that viewers can connect to (see
      `serve_web_viewer`); it lives as long as the recording and the process.

    **Returns:** a `rerun.RecordingStream`.
    """
    rr = _rr()
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=uuid.uuid4())
    rec.set_log_time_enabled(False)  # the `triplet` timeline is the one that means something
    blueprint = rerun_blueprint() if blueprint is None else blueprint
    sinks = []
    if path is not None:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        sinks.append(rr.FileSink(path))
    if spawn:
        rec.spawn(port=port, connect=False)
        sinks.append(rr.GrpcSink(f"rerun+http://127.0.0.1:{port}/proxy"))
    if serve:
        sinks.append(rr.GrpcServerSink(port=port))
    if sinks:
        rec.set_sinks(*sinks, default_blueprint=blueprint)
    else:
        rec.send_blueprint(blueprint, make_active=True, make_default=True)
    if name:
        rec.send_recording_name(name)
    return rec


def close_recording(rec: rr.RecordingStream) -> None:
    """Flush `rec` and close its sinks (finishing `.rrd` files and stopping servers)."""
    rec.flush()
    rec.disconnect()


def serve_web_viewer(port: int = 9876, *, web_port: int = 9090) -> str:
    """Host the rerun web viewer on `web_port`, connected to the gRPC server of a
    recording made with `rerun_recording(serve=True, port=port)`. Returns its address."""
    rr = _rr()
    uri = f"rerun+http://127.0.0.1:{port}/proxy"
    rr.serve_web_viewer(web_port=web_port, open_browser=False, connect_to=uri)
    return f"http://127.0.0.1:{web_port}/?url={urllib.parse.quote(uri, safe='')}"
