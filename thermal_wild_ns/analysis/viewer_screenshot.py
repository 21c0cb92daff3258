"""`wild-thermal-viewer-screenshot`: look at a trained scene in ns-viewer as a person would.

Starts `ns-viewer` on the run's config.yml, opens its page in headless Chromium (Debian's
`chromium` package; software WebGL), waits until the viewer has drawn the model's render, and
saves a screenshot PNG. The viewer opens looking through the first training camera, in the
model's thermal colormap, with the plugin's controls (colormap, frame embedding, colour bar) in
its "Custom Elements" panel.
"""

from __future__ import annotations

import base64
import json
import shutil
import socket
import subprocess
import sys
import time
import urllib.request
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import tyro
from websockets.sync.client import connect


@dataclass
class ScreenshotArgs:
    load_config: Path
    """config.yml of a trained run."""
    output: Path = Path("outputs/viewer.png")
    width: int = 1500
    height: int = 900
    timeout: float = 240.0
    """Seconds to wait for the viewer to start and draw before giving up."""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_http(url: str, deadline: float, process: subprocess.Popen, what: str) -> None:
    while time.time() < deadline:
        if process.poll() is not None:
            raise RuntimeError(f"{what} exited with code {process.returncode} before serving {url}")
        try:
            urllib.request.urlopen(url, timeout=2).read()
            return
        except OSError:
            time.sleep(1.0)
    raise TimeoutError(f"{what} did not serve {url} within the timeout")


def _drawn(png: bytes, width: int) -> bool:
    """Whether the 3D view (left of the control panel) shows an image: many distinct colours."""

    image = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    view = image[80:-80, : int(width * 0.6)]
    return len(np.unique(view.reshape(-1, 3), axis=0)) > 200


def screenshot(args: ScreenshotArgs) -> Path:
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        raise RuntimeError("no chromium on PATH: install Debian's package (apt-get install chromium)")
    if not args.load_config.is_file():
        raise FileNotFoundError(f"{args.load_config}: no such run config")

    deadline = time.time() + args.timeout
    port, debug_port = _free_port(), _free_port()
    viewer_cmd = [
        sys.executable,
        "-m",
        "nerfstudio.scripts.viewer.run_viewer",
        "--load-config",
        str(args.load_config),
        "--viewer.websocket-port",
        str(port),
    ]
    viewer = subprocess.Popen(viewer_cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    browser = None
    try:
        _wait_http(f"http://127.0.0.1:{port}/", deadline, viewer, "ns-viewer")
        browser = subprocess.Popen(
            [
                chromium,
                "--headless=new",
                "--no-sandbox",
                "--disable-dev-shm-usage",
                "--enable-unsafe-swiftshader",
                "--use-angle=swiftshader",
                f"--window-size={args.width},{args.height}",
                f"--remote-debugging-port={debug_port}",
                "about:blank",
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        _wait_http(f"http://127.0.0.1:{debug_port}/json/version", deadline, browser, "chromium")
        page = next(
            t
            for t in json.loads(urllib.request.urlopen(f"http://127.0.0.1:{debug_port}/json").read())
            if t["type"] == "page"
        )
        with connect(page["webSocketDebuggerUrl"], max_size=None) as ws:
            ids = iter(range(1, 1 << 30))

            def call(method: str, **params):
                message_id = next(ids)
                ws.send(json.dumps({"id": message_id, "method": method, "params": params}))
                while True:
                    reply = json.loads(ws.recv())
                    if reply.get("id") == message_id:
                        return reply.get("result", {})

            call("Page.navigate", url=f"http://127.0.0.1:{port}/")
            png = b""
            while time.time() < deadline:
                time.sleep(3.0)
                png = base64.b64decode(call("Page.captureScreenshot", format="png")["data"])
                if _drawn(png, args.width):
                    time.sleep(5.0)  # the viewer refines its render at full resolution once the camera rests
                    png = base64.b64decode(call("Page.captureScreenshot", format="png")["data"])
                    break
            else:
                raise TimeoutError("the viewer did not draw the scene within the timeout")
        args.output.parent.mkdir(parents=True, exist_ok=True)
        partial = args.output.with_suffix(".partial.png")
        partial.write_bytes(png)
        partial.replace(args.output)  # no half-written screenshot under the final name
        print(f"wrote {args.output}")
        return args.output
    finally:
        for process in (browser, viewer):
            if process is not None:
                process.terminate()
                try:
                    process.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    process.kill()


def entrypoint():
    screenshot(tyro.cli(ScreenshotArgs))


if __name__ == "__main__":
    entrypoint()
