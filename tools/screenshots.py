"""Screenshots of recordings in Rerun's web viewer, under headless Chromium.

Usage (after ``pip install -e '.[screenshots]'`` and Debian's ``chromium chromium-driver``)::

    .venv/bin/python tools/screenshots.py OUT_DIR FILE.rrd [FILE.rrd ...] [--wait 90]
        [--size 1280x800] [--click X,Y=NAME] [--timeout 600]
    .venv/bin/python tools/screenshots.py docs/img --docs [--wait 120]

``--docs`` makes the recordings the documentation shows first (:data:`DOCS_RUNS`: the
default run, a cross-check, the swing-up and the Furuta pendulum, each by its ``tspend``
command, in a temporary directory removed afterwards) and captures each as
``OUT_DIR/<name>.png``.

For each recording: a ``rerun --serve-web`` of its own serves it on 127.0.0.1, headless
Chromium (software WebGL: SwiftShader through ANGLE) opens the viewer with a viewport of
exactly ``--size`` (set through the DevTools protocol: ``--window-size`` alone leaves the
browser's own frame out of it), waits ``--wait`` seconds for the data to load and the
layout to settle, and saves ``OUT_DIR/<stem>.png``; the PNG's real size is checked
against the size asked for.  egui draws into a canvas, so a tab is clicked at its
position: ``--click X,Y=NAME`` clicks viewport pixel (X, Y) and saves ``<stem>-NAME.png``.
A plain ``chromium --screenshot`` is not enough: it captures the loading screen.

Every process this script starts (the Rerun server, chromedriver and the Chromium it
starts) runs in a process group of its own and is ended by that group's id when the
recording is done, on an error, on Ctrl-C or SIGTERM and at ``--timeout``: nothing is
left behind.  Each PNG is written to a partial file and renamed when complete.
"""

from __future__ import annotations

import argparse
import base64
import contextlib
import os
import re
import shutil
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Iterator

CHROMIUM_FLAGS = (
    "--headless=new", "--no-sandbox", "--disable-dev-shm-usage",
    "--use-gl=angle", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist",
    "--disable-background-networking", "--disable-component-update", "--disable-sync", "--no-first-run",
    "--disable-default-apps", "--disable-extensions", "--hide-scrollbars", "--force-device-scale-factor=1",
)
PROG = "tools/screenshots.py"


#: the pictures of the documentation (docs/recordings.md): PNG name -> tspend arguments
DOCS_RUNS = {
    "after-default": ["run", "pendulum_mujoco"],
    "after-crosscheck": ["crosscheck", "pendulum_mujoco"],
    "swingup": ["run", "swingup_mujoco"],
    "furuta": ["run", "furuta_mujoco"],
}


class Timeout(Exception):
    """The whole job ran past ``--timeout``."""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_port(port: int, timeout: float, proc: subprocess.Popen | None = None) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc is not None and proc.poll() is not None:
            raise RuntimeError(f"the Rerun server ended (status {proc.returncode}) before listening on {port}")
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=1.0):
                return
        except OSError:
            time.sleep(0.3)
    raise TimeoutError(f"nothing listens on 127.0.0.1:{port} after {timeout:.0f} s")


def _rerun_executable() -> str:
    found = shutil.which("rerun") or str(Path(sys.executable).parent / "rerun")
    if not Path(found).exists():
        raise SystemExit(f"{PROG}: the rerun executable is not found (install rerun-sdk)")
    return found


def end_group(proc: subprocess.Popen | None, grace_s: float = 5.0) -> None:
    """End ``proc`` and every process of its group (it was started as a group leader):
    SIGTERM, then SIGKILL after ``grace_s``."""
    if proc is None:
        return
    for sig, wait in ((signal.SIGTERM, grace_s), (signal.SIGKILL, grace_s)):
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(proc.pid, sig)
        try:
            proc.wait(timeout=wait)
        except subprocess.TimeoutExpired:
            continue
        # the leader is gone; its group may still hold children: SIGKILL them too
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(proc.pid, signal.SIGKILL)
        return


@contextlib.contextmanager
def rerun_server(rrd: Path) -> Iterator[tuple[int, int]]:
    """(web port, gRPC port) of a ``rerun --serve-web`` serving ``rrd``, ended on exit."""
    web_port, grpc_port = _free_port(), _free_port()
    server = subprocess.Popen(
        [_rerun_executable(), "--serve-web", "--bind", "127.0.0.1", "--web-viewer-port", str(web_port),
         "--port", str(grpc_port), str(rrd)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        _wait_port(web_port, 60.0, server)
        _wait_port(grpc_port, 60.0, server)
        yield web_port, grpc_port
    finally:
        end_group(server)


@contextlib.contextmanager
def browser(width: int, height: int) -> Iterator[object]:
    """A headless Chromium whose viewport is ``width`` x ``height`` CSS pixels at scale 1."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    for flag in CHROMIUM_FLAGS:
        options.add_argument(flag)
    options.add_argument(f"--window-size={width},{height}")
    binary = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
    if binary:
        options.binary_location = binary
    driver_path = shutil.which("chromedriver")
    # chromedriver leads a group of its own, which Chromium and its helpers join
    service = Service(driver_path, popen_kw={"start_new_session": True})
    driver = None
    try:
        driver = webdriver.Chrome(service=service, options=options)
        driver.set_page_load_timeout(300)
        driver.execute_cdp_cmd("Emulation.setDeviceMetricsOverride",
                               {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False})
        yield driver
    finally:
        if driver is not None:
            with contextlib.suppress(Exception):
                driver.quit()
        end_group(getattr(service, "process", None))


def _click_at(driver, x: int, y: int) -> None:
    """Click viewport pixel (x, y) through the DevTools protocol (the viewer is one canvas)."""
    for kind in ("mousePressed", "mouseReleased"):
        driver.execute_cdp_cmd("Input.dispatchMouseEvent",
                               {"type": kind, "x": x, "y": y, "button": "left", "clickCount": 1})


def png_size(data: bytes) -> tuple[int, int]:
    """(width, height) from a PNG's IHDR chunk."""
    if data[:8] != b"\x89PNG\r\n\x1a\n" or data[12:16] != b"IHDR":
        raise ValueError("not a PNG")
    return struct.unpack(">II", data[16:24])


def capture(driver, width: int, height: int, attempts: int = 8) -> bytes:
    """A PNG of exactly the viewport, retried: on a loaded machine the software-rendered
    page may not answer within chromedriver's fixed time."""
    from selenium.common.exceptions import TimeoutException

    clip = {"x": 0, "y": 0, "width": width, "height": height, "scale": 1}
    for attempt in range(attempts):
        try:
            shot = driver.execute_cdp_cmd("Page.captureScreenshot", {"format": "png", "clip": clip,
                                                                      "captureBeyondViewport": False})
            return base64.b64decode(shot["data"])
        except TimeoutException:
            if attempt == attempts - 1:
                raise
            time.sleep(5.0)
    raise AssertionError("unreachable")


def write_png(path: Path, data: bytes, width: int, height: int) -> Path:
    """Check the size, then write ``path`` through a partial file renamed when complete."""
    got = png_size(data)
    if got != (width, height):
        raise RuntimeError(f"{path.name}: the capture is {got[0]}x{got[1]}, not the {width}x{height} asked for")
    partial = path.with_name(f".{path.name}.partial")
    partial.write_bytes(data)
    os.replace(partial, path)
    return path


def screenshot(rrd: Path, out: Path, wait_s: float, width: int, height: int, clicks: list[str]) -> list[Path]:
    saved: list[Path] = []
    with rerun_server(rrd) as (web_port, grpc_port), browser(width, height) as driver:
        driver.get(f"http://127.0.0.1:{web_port}/?url=rerun%2Bhttp://127.0.0.1:{grpc_port}/proxy")
        time.sleep(wait_s)
        saved.append(write_png(out / f"{rrd.stem}.png", capture(driver, width, height), width, height))
        for spec in clicks:
            where, _, name = spec.partition("=")
            x, y = (int(v) for v in where.split(","))
            _click_at(driver, x, y)
            time.sleep(max(10.0, wait_s / 4))
            path = out / f"{rrd.stem}-{re.sub(r'[^a-z0-9]+', '_', (name or where).lower())}.png"
            saved.append(write_png(path, capture(driver, width, height), width, height))
    return saved


def record(name: str, args: list[str], directory: Path) -> Path:
    """``directory/<name>.rrd`` made by ``tspend ARGS --out ...`` in a process group of its
    own (ended whole if this job stops); a run the task ends (exit 4) is kept."""
    rrd = directory / f"{name}.rrd"
    proc = subprocess.Popen([sys.executable, "-m", "tspend.cli", *args, "--out", str(rrd)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        _, err = proc.communicate()
    finally:
        end_group(proc)
    if proc.returncode not in (0, 4) or not rrd.is_file():
        raise RuntimeError(f"tspend {' '.join(args)} failed ({proc.returncode}): {err.strip()[-300:]}")
    return rrd


def _on_signal(signum, frame) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


def _on_alarm(signum, frame) -> None:
    raise Timeout()


def _size(text: str) -> tuple[int, int]:
    m = re.fullmatch(r"(\d+)x(\d+)", text.strip().lower())
    if not m or not all(200 <= int(v) <= 8000 for v in m.groups()):
        raise argparse.ArgumentTypeError(f"--size {text!r}: expected WxH in pixels, each 200..8000, e.g. 1280x800")
    return int(m.group(1)), int(m.group(2))


def _click(text: str) -> str:
    if not re.fullmatch(r"\d+,\d+(=[\w-]+)?", text):
        raise argparse.ArgumentTypeError(f"--click {text!r}: expected X,Y or X,Y=NAME")
    return text


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="directory for the PNGs")
    parser.add_argument("recordings", type=Path, nargs="*", help=".rrd files")
    parser.add_argument("--docs", action="store_true",
                        help="record and capture the documentation's runs (" + ", ".join(DOCS_RUNS) + ")")
    parser.add_argument("--wait", type=float, default=90.0, help="seconds to let the viewer load (default 90)")
    parser.add_argument("--size", type=_size, default=(1280, 800), help="viewport WxH (default 1280x800)")
    parser.add_argument("--click", type=_click, action="append", default=[], metavar="X,Y=NAME",
                        help="then click viewport pixel X,Y (a tab) and save <stem>-NAME.png; repeatable")
    parser.add_argument("--timeout", type=float, default=900.0,
                        help="seconds for the whole job; then everything started is ended (default 900)")
    args = parser.parse_args(argv)
    width, height = args.size
    if not args.wait >= 0 or not args.timeout > 0:
        parser.error("--wait must be >= 0 and --timeout > 0")
    if not args.recordings and not args.docs:
        parser.error("give recordings (FILE.rrd ...) or --docs")
    for rrd in args.recordings:
        if not rrd.is_file():
            print(f"{PROG}: no such recording: {rrd}", file=sys.stderr)
            return 2
    args.out.mkdir(parents=True, exist_ok=True)
    scratch = tempfile.TemporaryDirectory(prefix="tspend-screenshots-") if args.docs else None
    previous = {sig: signal.signal(sig, _on_signal) for sig in (signal.SIGTERM, signal.SIGHUP)}
    signal.signal(signal.SIGALRM, _on_alarm)
    signal.alarm(max(1, int(args.timeout)))
    try:
        recordings = list(args.recordings)
        if scratch is not None:
            recordings += [record(name, run, Path(scratch.name)) for name, run in DOCS_RUNS.items()]
        for rrd in recordings:
            for path in screenshot(rrd, args.out, args.wait, width, height, args.click):
                print(path, flush=True)
    except Timeout:
        print(f"{PROG}: stopped after --timeout {args.timeout:g} s; every process started was ended",
              file=sys.stderr)
        return 3
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted; every process started was ended", file=sys.stderr)
        return 130
    finally:
        signal.alarm(0)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        if scratch is not None:
            scratch.cleanup()
    return 0


if __name__ == "__main__":
    sys.exit(main())
