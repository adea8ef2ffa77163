"""Headless Chromium driven over the Chrome DevTools Protocol on a pipe (`--remote-debugging-pipe`:
JSON messages separated by NUL on file descriptors 3 and 4), so no websocket or browser-driver
package is needed; and Rerun's web viewer served from the rerun-sdk wheel.

Used by tests/runtime/test_view_browser.py and to make the README's screenshot:

    python -m tests.runtime.browser FILE.rrd OUT.png
"""

from __future__ import annotations

import base64
import contextlib
import json
import os
import select
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync",
                  "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--disable-dev-shm-usage",
                  "--mute-audio", "--hide-scrollbars")


def find_chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        p = shutil.which(name)
        if p:
            return p
    return None


class Chromium:
    """One headless Chromium process and one page, driven over CDP on a pipe."""

    def __init__(self, user_data_dir: Path, width: int = 1600, height: int = 1000, binary: str | None = None) -> None:
        exe = binary or find_chromium()
        if exe is None:
            raise FileNotFoundError("no chromium binary on PATH")
        to_chrome_r, self._w = (self._high(fd) for fd in os.pipe())
        self._r, from_chrome_w = (self._high(fd) for fd in os.pipe())

        def fds() -> None:  # in the child: CDP reads fd 3 and writes fd 4
            os.dup2(to_chrome_r, 3)
            os.dup2(from_chrome_w, 4)

        self.proc = subprocess.Popen(
            [exe, *CHROMIUM_FLAGS, f"--user-data-dir={user_data_dir}", f"--window-size={width},{height}",
             "--remote-debugging-pipe", "about:blank"],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            preexec_fn=fds, close_fds=False)
        os.close(to_chrome_r)
        os.close(from_chrome_w)
        self._buf = b""
        self._id = 0
        self.width, self.height = width, height
        self.session: str | None = None

    @staticmethod
    def _high(fd: int) -> int:
        """The same pipe end moved to a descriptor >= 10 (close-on-exec), so dup2 onto 3 and 4 in
        the child never overwrites one of the four pipe ends (and makes 3 and 4 inheritable)."""
        import fcntl

        hi = fcntl.fcntl(fd, fcntl.F_DUPFD_CLOEXEC, 10)
        os.close(fd)
        return hi

    def call(self, method: str, params: dict[str, Any] | None = None, timeout: float = 30.0,
             session: bool = True) -> dict[str, Any]:
        self._id += 1
        msg: dict[str, Any] = {"id": self._id, "method": method, "params": params or {}}
        if session and self.session is not None:
            msg["sessionId"] = self.session
        os.write(self._w, json.dumps(msg).encode() + b"\0")
        deadline = time.monotonic() + timeout
        while True:
            while b"\0" in self._buf:
                raw, self._buf = self._buf.split(b"\0", 1)
                reply = json.loads(raw)
                if reply.get("id") == self._id:
                    if "error" in reply:
                        raise RuntimeError(f"CDP {method}: {reply['error']}")
                    return dict(reply.get("result", {}))
            left = deadline - time.monotonic()
            if left <= 0 or self.proc.poll() is not None:
                raise TimeoutError(f"CDP {method}: no reply (chromium exit code {self.proc.poll()})")
            ready, _, _ = select.select([self._r], [], [], min(left, 1.0))
            if ready:
                chunk = os.read(self._r, 1 << 20)
                if not chunk:
                    raise RuntimeError("chromium closed the DevTools pipe")
                self._buf += chunk

    def open(self, url: str) -> None:
        target = self.call("Target.createTarget", {"url": "about:blank"}, session=False)["targetId"]
        self.session = self.call("Target.attachToTarget", {"targetId": target, "flatten": True},
                                 session=False)["sessionId"]
        self.call("Page.enable")
        self.call("Emulation.setDeviceMetricsOverride", {"width": self.width, "height": self.height,
                                                         "deviceScaleFactor": 1, "mobile": False})
        self.call("Page.navigate", {"url": url})

    def screenshot(self) -> bytes:
        return base64.b64decode(self.call("Page.captureScreenshot", {"format": "png"}, timeout=60)["data"])

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.call("Browser.close", session=False, timeout=5)
        with contextlib.suppress(Exception):
            self.proc.wait(5)
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(5)
        for fd in (self._r, self._w):
            with contextlib.suppress(OSError):
                os.close(fd)


def image_stats(png: bytes, box: tuple[float, float, float, float] | None = None) -> dict[str, float]:
    """Colours and coverage of a screenshot (or of `box` = (x0, y0, x1, y1) in fractions of its
    size): `distinct` colours (quantised to 4 bits per channel) and `content` = fraction of
    pixels that differ from the most common colour by > 24 levels."""
    import cv2

    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    if img is None:
        raise ValueError("not a PNG image")
    if box is not None:
        h, w = img.shape[:2]
        img = img[int(box[1] * h):int(box[3] * h), int(box[0] * w):int(box[2] * w)]
    q = (img >> 4).reshape(-1, 3).astype(np.int32)
    keys = q[:, 0] * 256 + q[:, 1] * 16 + q[:, 2]
    vals, counts = np.unique(keys, return_counts=True)
    bg = vals[np.argmax(counts)]
    bg_rgb = np.array([bg // 256, (bg // 16) % 16, bg % 16]) * 16 + 8
    diff = np.abs(img.reshape(-1, 3).astype(np.int32) - bg_rgb[None, :]).max(axis=1)
    return {"distinct": float(len(vals)), "content": float(np.mean(diff > 24)), "width": float(img.shape[1]),
            "height": float(img.shape[0])}


@contextlib.contextmanager
def rerun_web_viewer(rrd: Path, web_port: int, grpc_port: int) -> Iterator[str]:
    """Serve `rrd` with the rerun-sdk wheel's own CLI (`rerun FILE --serve-web`, loopback only);
    yields the viewer URL that connects to it."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "rerun_cli", str(rrd), "--serve-web", "--bind", "127.0.0.1", "--web-viewer-port",
         str(web_port), "--port", str(grpc_port), "--hide-welcome-screen"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        start_new_session=True)  # its own process group: `rerun_cli` starts the native viewer as a child
    try:
        import urllib.request

        deadline = time.monotonic() + 60
        while True:
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{web_port}/", timeout=2) as r:
                    if r.status == 200:
                        break
            except OSError:
                if proc.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(f"rerun web viewer did not start (exit code {proc.poll()})") from None
                time.sleep(0.3)
        yield f"http://127.0.0.1:{web_port}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{grpc_port}%2Fproxy"
    finally:
        # The whole group: terminating the Python wrapper alone left the native server running
        # (serving and burning a core) after the test or the screenshot.
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(5)


def screenshot_rrd(rrd: Path, out_png: Path, user_data_dir: Path, web_port: int, grpc_port: int,
                   timeout_s: float = 120.0, settle_s: float = 4.0, width: int = 1600,
                   height: int = 1000) -> dict[str, float]:
    """Open `rrd` in Rerun's web viewer in headless Chromium; poll screenshots until the page
    shows content (many colours) and has settled; write the last one; return its stats."""
    with rerun_web_viewer(rrd, web_port, grpc_port) as url:
        browser = Chromium(user_data_dir, width, height)
        try:
            browser.open(url)
            t_end = time.monotonic() + timeout_s
            stats: dict[str, float] = {}
            png = b""
            good_since: float | None = None
            while time.monotonic() < t_end:
                time.sleep(2.0)
                png = browser.screenshot()
                stats = image_stats(png)
                if stats["distinct"] >= 150 and stats["content"] >= 0.05:
                    good_since = good_since or time.monotonic()
                    if time.monotonic() - good_since >= settle_s:
                        break
                else:
                    good_since = None
            out_png.parent.mkdir(parents=True, exist_ok=True)
            out_png.write_bytes(png)
            return stats
        finally:
            browser.close()


if __name__ == "__main__":
    import tempfile

    from tests.runtime.zenoh_helpers import free_port

    with tempfile.TemporaryDirectory() as d:
        print(screenshot_rrd(Path(sys.argv[1]), Path(sys.argv[2]), Path(d), free_port(), free_port()))
