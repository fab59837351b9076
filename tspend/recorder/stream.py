"""Recording streams: :func:`open_recording` (file, spawned or connected viewer, and the
fallbacks when a viewer cannot be reached) and :func:`close_recording`, which says
whether the saved file is complete (the CLI writes to a partial file and renames it
into place only then, see :mod:`tspend.runtime.outputs`)."""

from __future__ import annotations

import os
import shutil
import socket
import sys
import uuid
from pathlib import Path
from urllib.parse import urlparse

import rerun as rr


DEFAULT_VIEWER_PORT = 9876
VIEWER_SCHEMES = ("rerun+http", "rerun+https", "rerun", "http", "https")
#: longest wait for data to reach the sink at finish/close
FLUSH_TIMEOUT_S = 30.0


def _warn(message: str) -> None:
    print(f"tspend: warning: {message}", file=sys.stderr)


def _viewer_executable() -> str | None:
    """``rerun`` on PATH, else the one installed beside this interpreter (an unactivated venv)."""
    found = shutil.which("rerun")
    if found:
        return found
    sibling = Path(sys.executable).parent / ("rerun.exe" if os.name == "nt" else "rerun")
    return str(sibling) if sibling.exists() else None


def _port_open(host: str, port: int, timeout: float = 1.0) -> bool:
    try:
        with socket.create_connection((host, port), timeout=timeout):
            return True
    except OSError:
        return False


def viewer_url_problem(url: str) -> str:
    """Why ``url`` cannot address a Rerun viewer (``rerun+http://HOST:PORT/proxy``), or ""."""
    if any(ord(c) < 32 or ord(c) == 127 for c in url):
        return "contains control characters"
    try:
        parsed = urlparse(url)
    except ValueError as exc:  # e.g. an unclosed IPv6 bracket
        return str(exc)
    if parsed.scheme not in VIEWER_SCHEMES:
        return f"scheme must be one of {', '.join(VIEWER_SCHEMES)}, e.g. rerun+http://127.0.0.1:9876/proxy"
    try:
        parsed.port
    except ValueError:
        return "the port must be a number from 1 to 65535"
    if not parsed.hostname:
        return "no host name"
    return ""


def _grpc_endpoint(url: str | None) -> tuple[str, int]:
    parsed = urlparse(url or f"rerun+http://127.0.0.1:{DEFAULT_VIEWER_PORT}/proxy")
    default = 443 if parsed.scheme.endswith("https") else DEFAULT_VIEWER_PORT
    return parsed.hostname or "127.0.0.1", parsed.port or default


PathLike = str | os.PathLike[str]


def _file_sink(path: PathLike, write_footer: bool) -> rr.FileSink:
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    return rr.FileSink(str(path), write_footer=write_footer)


def _viewer_sink(rec: rr.RecordingStream, kind: str, url: str | None, port: int) -> tuple[rr.GrpcSink | None, str]:
    """A gRPC sink to a viewer (``kind`` "spawn": start one; "connect": reach ``url``), or why not."""
    if kind == "connect":
        host, grpc_port = _grpc_endpoint(url)
        if not _port_open(host, grpc_port):
            return None, f"no Rerun viewer at {url or f'{host}:{grpc_port}'}"
        return rr.GrpcSink(url), ""
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        # the viewer would start, fail to open a window, and leave us waiting ~10 s
        return None, "no display for the Rerun viewer"
    exe = _viewer_executable()
    if exe is None:
        return None, "Rerun viewer executable not found"
    try:
        rr.spawn(port=port, connect=False, executable_path=exe, recording=rec)
    except Exception as exc:  # noqa: BLE001 - any failure means: no viewer
        return None, f"cannot start the Rerun viewer ({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})"
    if not _port_open("127.0.0.1", port, timeout=2.0):
        return None, f"the Rerun viewer did not come up on port {port}"
    return rr.GrpcSink(f"rerun+http://127.0.0.1:{port}/proxy"), ""


def open_recording(app_id: str, mode: str | None = None, path: PathLike | None = None, url: str | None = None, *,
                   spawn: bool = False, connect: str | bool | None = None, recording_id: str | None = None,
                   port: int = DEFAULT_VIEWER_PORT, write_footer: bool = True) -> rr.RecordingStream | None:
    """A new recording stream (never the global one) with its sinks attached, or ``None``.

    With ``mode``: ``"save"`` streams to the ``.rrd`` at ``path`` as data comes;
    ``"spawn"`` starts a viewer on ``port``; ``"connect"`` connects to ``url`` (default
    ``rerun+http://127.0.0.1:9876/proxy``); ``"none"`` returns ``None`` (record nothing:
    don't add a sink).  When the viewer cannot be reached, a one-line warning goes to
    stderr and the recording is saved to ``path`` if given, else ``None`` is returned.

    Without ``mode`` (the CLI's form): save to ``path`` if given and *also* stream to a
    spawned viewer (``spawn``) and/or the viewer at ``connect`` (a URL, or True for the
    default one); viewers that cannot be reached are dropped with a one-line warning.

    ``write_footer``: the ``.rrd`` footer (a chunk index, needed by
    ``RrdReader.store()``; ``stream()`` works without it) is kept in memory until the
    file is closed, ~3 kB per chunk, i.e. ~20-40 kB per 1000-step block here.  Pass
    ``False`` for very long runs to keep memory strictly flat.
    """
    if mode == "none":
        return None
    if mode not in (None, "save", "spawn", "connect"):
        raise ValueError(f"unknown recording mode {mode!r} (save, spawn, connect, none)")
    if mode == "save" and path is None:
        raise ValueError("mode 'save' needs a path")
    rec = rr.RecordingStream(app_id, recording_id=recording_id or uuid.uuid4())
    viewers: list[rr.GrpcSink] = []
    if mode in ("spawn", "connect"):
        viewer, why = _viewer_sink(rec, mode, url, port)
        if viewer is not None:
            path = None  # the file is only the fallback of these modes
            viewers.append(viewer)
        elif path is not None:
            _warn(f"{why}; saving the recording to {path} instead")
        else:
            _warn(f"{why}; recording nothing")
            return None
    elif mode is None:
        wanted = ([("spawn", None)] if spawn else []) + \
                 ([("connect", None if connect is True else str(connect))] if connect else [])
        for kind, viewer_url in wanted:
            viewer, why = _viewer_sink(rec, kind, viewer_url, port)
            if viewer is not None:
                viewers.append(viewer)
            else:
                _warn(f"{why}; " + (f"recording to {path} only" if path is not None else "not streaming to it"))
    if viewers:
        rec.set_sinks(*viewers, *([_file_sink(path, write_footer)] if path is not None else []))
    elif path is not None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        rec.save(path, write_footer=write_footer)  # streams to disk as data comes
    else:
        return None
    return rec


def flush(rec: rr.RecordingStream, timeout_s: float = FLUSH_TIMEOUT_S) -> str:
    """Flush, bounded in time: a vanished viewer must not hang the end of a run.

    Returns "" when every sink took the data, else what went wrong.
    """
    try:
        rec.flush(timeout_sec=timeout_s)
    except Exception as exc:  # noqa: BLE001 - the caller decides what the failure means
        return str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    return ""


#: how a complete ``.rrd`` saved with a footer ends: the footer's magic and its version
_FOOTER_MAGIC = b"RRF2FOOT"


def saved_file_problem(path: PathLike) -> str:
    """Why the ``.rrd`` at ``path`` (saved with a footer) is not complete, or "".

    The footer is written last, when the file sink closes; a writer that failed on the
    way (disk full, I/O error, a file size limit) never writes it.
    """
    try:
        with open(path, "rb") as f:
            f.seek(0, os.SEEK_END)
            size = f.tell()
            f.seek(max(0, size - 12))
            tail = f.read()
    except OSError as exc:
        return exc.strerror or str(exc)
    if len(tail) < 12 or tail[:8] != _FOOTER_MAGIC:
        return "the file ends before the recording's footer"
    return ""


def close_recording(rec: rr.RecordingStream, path: PathLike | None = None) -> str:
    """Flush and close every sink of ``rec`` (writes the ``.rrd`` footer).

    With ``path``, the file the recording was saved to with a footer: returns why that
    file is incomplete ("" when it is whole), so the caller never presents a truncated
    file as a result.  A viewer that could not take the data only earns a warning.
    """
    problem = flush(rec)
    rec.disconnect()
    incomplete = saved_file_problem(path) if path is not None else ""
    if incomplete:
        return f"{problem}; {incomplete}" if problem else incomplete
    if problem:
        _warn(f"Rerun flush did not complete ({problem})")
    return ""
