"""Screenshots of recordings in Rerun's web viewer, under headless Chromium.

Usage (after ``pip install -e '.[screenshots]'`` and Debian's ``chromium chromium-driver``)::

    .venv/bin/python tools/screenshots.py OUT_DIR FILE.rrd [FILE.rrd ...] [--wait 90] [--size 1600x1000]

For each recording: ``rerun --serve-web`` serves it on 127.0.0.1, headless Chromium
(software WebGL: SwiftShader through ANGLE) opens the viewer, waits ``--wait`` seconds
for the data to load and the layout to settle, and saves ``OUT_DIR/<stem>.png``.
(egui draws into a canvas, so a tab is clicked at its position: ``--click X,Y=NAME``
clicks window pixel (X, Y) and saves ``<stem>-NAME.png``).
A plain ``chromium --screenshot`` is not enough: it captures the loading screen.
"""

from __future__ import annotations

import argparse
import re
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

CHROMIUM_FLAGS = (
    "--headless=new", "--no-sandbox", "--disable-dev-shm-usage",
    "--use-gl=angle", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist",
    "--disable-background-networking", "--disable-component-update", "--disable-sync", "--no-first-run",
    "--disable-default-apps", "--disable-extensions",
)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_port(port: int, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=1.0):
                return
        except OSError:
            time.sleep(0.3)
    raise TimeoutError(f"nothing listens on 127.0.0.1:{port} after {timeout:.0f} s")


def _rerun_executable() -> str:
    found = shutil.which("rerun") or str(Path(sys.executable).parent / "rerun")
    if not Path(found).exists():
        sys.exit("tools/screenshots.py: the rerun executable is not found (install rerun-sdk)")
    return found


def _driver(width: int, height: int):
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
    service = Service(driver_path) if driver_path else Service()
    return webdriver.Chrome(service=service, options=options)


def _click_at(driver, x: int, y: int) -> None:
    """Click window pixel (x, y) through the DevTools protocol (the viewer is one canvas)."""
    for kind in ("mousePressed", "mouseReleased"):
        driver.execute_cdp_cmd("Input.dispatchMouseEvent",
                               {"type": kind, "x": x, "y": y, "button": "left", "clickCount": 1})


def _save(driver, path: Path, attempts: int = 8) -> None:
    """Save a screenshot, retrying: on a loaded machine the software-rendered page may not
    answer chromedriver within its fixed 10 s."""
    from selenium.common.exceptions import TimeoutException

    import base64

    for attempt in range(attempts):
        try:
            if attempt % 2 == 0:
                driver.save_screenshot(str(path))
            else:  # straight through the DevTools protocol, without chromedriver's renderer round trip
                shot = driver.execute_cdp_cmd("Page.captureScreenshot", {"format": "png"})
                path.write_bytes(base64.b64decode(shot["data"]))
            return
        except TimeoutException:
            if attempt == attempts - 1:
                raise
            time.sleep(5.0)


def screenshot(rrd: Path, out: Path, wait_s: float, width: int, height: int, clicks: list[str]) -> list[Path]:
    web_port, grpc_port = _free_port(), _free_port()
    server = subprocess.Popen(
        [_rerun_executable(), "--serve-web", "--bind", "127.0.0.1", "--web-viewer-port", str(web_port),
         "--port", str(grpc_port), str(rrd)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    saved: list[Path] = []
    try:
        _wait_port(web_port, 60.0)
        _wait_port(grpc_port, 60.0)
        driver = _driver(width, height)
        driver.set_page_load_timeout(300)
        try:
            url = f"http://127.0.0.1:{web_port}/?url=rerun%2Bhttp://127.0.0.1:{grpc_port}/proxy"
            driver.get(url)
            time.sleep(wait_s)
            path = out / f"{rrd.stem}.png"
            _save(driver, path)
            saved.append(path)
            for spec in clicks:
                where, _, name = spec.partition("=")
                x, y = (int(v) for v in where.split(","))
                _click_at(driver, x, y)
                time.sleep(max(10.0, wait_s / 4))
                path = out / f"{rrd.stem}-{re.sub(r'[^a-z0-9]+', '_', (name or where).lower())}.png"
                _save(driver, path)
                saved.append(path)
        finally:
            driver.quit()
    finally:
        server.terminate()
        try:
            server.wait(timeout=10)
        except subprocess.TimeoutExpired:
            server.kill()
    return saved


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="directory for the PNGs")
    parser.add_argument("recordings", type=Path, nargs="+", help=".rrd files")
    parser.add_argument("--wait", type=float, default=90.0, help="seconds to let the viewer load (default 90)")
    parser.add_argument("--size", default="1600x1000", help="window size WxH (default 1600x1000)")
    parser.add_argument("--click", action="append", default=[], metavar="X,Y=NAME",
                        help="then click window pixel X,Y (a tab) and save <stem>-NAME.png; repeatable")
    args = parser.parse_args(argv)
    width, height = (int(v) for v in args.size.lower().split("x"))
    args.out.mkdir(parents=True, exist_ok=True)
    for rrd in args.recordings:
        if not rrd.is_file():
            print(f"tools/screenshots.py: no such recording: {rrd}", file=sys.stderr)
            return 2
    for rrd in args.recordings:
        for path in screenshot(rrd, args.out, args.wait, width, height, args.click):
            print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
