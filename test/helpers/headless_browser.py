"""A real headless browser for the browser-view tests and benchmark: Debian's ``chromium``
driven over the DevTools protocol (a websocket, `websockets`' sync client). It keeps the page's
network log (every request the page made, websockets included) and takes screenshots as RGB
arrays. WebGL runs on SwiftShader (the CPU), so no GPU is needed."""
import base64
import io
import itertools
import json
import os
import shutil
import subprocess
import tempfile
import threading
import time

import numpy as np
from PIL import Image
from websockets.sync.client import connect

from waiting import wait_for

WIDTH, HEIGHT = 960, 640
START_TIMEOUT = 60.0   # s: chromium up and its DevTools endpoint answering (a loaded machine)


def chromium() -> str:
    found = shutil.which("chromium") or shutil.which("chromium-browser")
    if found is None:
        raise FileNotFoundError("chromium is not installed (apt-get install chromium; "
                                ".ci/run installs it)")
    return found


class Browser:
    """One headless chromium with one page (``WIDTH`` × ``HEIGHT``). ``open(url)`` loads it;
    ``requests`` is every URL the page asked for, in order; ``screenshot()`` an (H, W, 3) uint8
    array. A context manager: leaving it ends chromium (its process id only)."""

    def __init__(self):
        self._profile = tempfile.mkdtemp(prefix="browser-view-")
        self.process = subprocess.Popen(
            [chromium(), "--headless=new", "--no-sandbox", "--disable-gpu-sandbox",
             "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
             "--no-first-run", "--no-default-browser-check", "--disable-extensions",
             "--disable-background-networking", "--disable-component-update",
             "--disable-sync", "--disable-default-apps", "--metrics-recording-only",
             f"--window-size={WIDTH},{HEIGHT}", "--remote-debugging-port=0",
             f"--user-data-dir={self._profile}", "about:blank"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        port_file = os.path.join(self._profile, "DevToolsActivePort")
        wait_for(lambda: os.path.exists(port_file) and open(port_file).read().count("\n") >= 1,
                 "chromium's DevTools port", START_TIMEOUT)
        port, path = open(port_file).read().split()[:2]
        # The browser's own endpoint, and a page attached to it in "flat" mode: commands carry
        # the page's session, which survives the renderer swap of a navigation.
        self._socket = connect(f"ws://127.0.0.1:{port}{path}", max_size=None,
                               open_timeout=START_TIMEOUT)
        self._ids = itertools.count(1)
        self._replies: dict[int, dict] = {}
        self._lock = threading.Condition()
        self.requests: list[str] = []
        self.loaded = threading.Event()
        self.frames: list[tuple[float, str]] = []   # (monotonic s, PNG base64) of a screencast
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        self._session = None
        target = self.call("Target.createTarget", url="about:blank")["targetId"]
        self._session = self.call("Target.attachToTarget", targetId=target,
                                  flatten=True)["sessionId"]
        self.call("Network.enable")
        self.call("Page.enable")
        self.call("Target.setAutoAttach", autoAttach=True, waitForDebuggerOnStart=True,
                  flatten=True)
        self.call("Emulation.setDeviceMetricsOverride", width=WIDTH, height=HEIGHT,
                  deviceScaleFactor=1, mobile=False)

    def _read(self) -> None:
        try:
            for text in self._socket:
                message = json.loads(text)
                if "id" in message:
                    with self._lock:
                        self._replies[message["id"]] = message
                        self._lock.notify_all()
                    continue
                method, params = message.get("method"), message.get("params", {})
                if method == "Target.attachedToTarget":   # a worker of the page: log it too
                    self._attached(params["sessionId"])
                elif method == "Network.requestWillBeSent":
                    self.requests.append(params["request"]["url"])
                elif method == "Network.webSocketCreated":
                    self.requests.append(params["url"])
                elif method == "Page.loadEventFired":
                    self.loaded.set()
                elif method == "Page.screencastFrame":   # a frame as drawn: keep it, ack it
                    self.frames.append((time.monotonic(), params["data"]))
                    self._socket.send(json.dumps({
                        "id": next(self._ids), "method": "Page.screencastFrameAck",
                        "params": {"sessionId": params["sessionId"]},
                        "sessionId": message.get("sessionId")}))
        except Exception:   # the browser went away: callers time out on their replies
            with self._lock:
                self._lock.notify_all()

    def _attached(self, session: str) -> None:
        """A target the page started (a web worker: viser's websocket runs in one): its network
        log too, then let it run. Sent from the reader thread, whose replies nobody awaits."""
        for method in ("Network.enable", "Runtime.runIfWaitingForDebugger"):
            self._socket.send(json.dumps({"id": next(self._ids), "method": method,
                                          "params": {}, "sessionId": session}))

    def call(self, method: str, timeout: float = 60.0, **params) -> dict:
        """One DevTools command; its result (AssertionError on an error reply or no reply)."""
        key = next(self._ids)
        message = {"id": key, "method": method, "params": params}
        if self._session is not None:
            message["sessionId"] = self._session
        self._socket.send(json.dumps(message))
        end = time.monotonic() + timeout
        with self._lock:
            while key not in self._replies:
                left = end - time.monotonic()
                assert left > 0 and self.process.poll() is None, f"no reply to {method}"
                self._lock.wait(left)
            reply = self._replies.pop(key)
        assert "error" not in reply, f"{method}: {reply['error']}"
        return reply["result"]

    def open(self, url: str) -> None:
        """Load ``url`` and wait for its load event."""
        self.loaded.clear()
        self.call("Page.navigate", url=url)
        assert self.loaded.wait(START_TIMEOUT), f"{url} did not load"

    def screenshot(self) -> np.ndarray:
        data = self.call("Page.captureScreenshot", format="png")["data"]
        return np.asarray(Image.open(io.BytesIO(base64.b64decode(data))).convert("RGB"))

    def screencast(self) -> None:
        """From now on every frame the page draws lands in ``frames``, with the time it came
        (a screenshot takes a second of SwiftShader's time; a frame of the screencast none)."""
        self.frames.clear()
        self.call("Page.startScreencast", format="png", everyNthFrame=1)

    @staticmethod
    def image(data: str) -> np.ndarray:
        return np.asarray(Image.open(io.BytesIO(base64.b64decode(data))).convert("RGB"))

    def evaluate(self, expression: str):
        return self.call("Runtime.evaluate", expression=expression,
                         returnByValue=True)["result"].get("value")

    def close(self) -> None:
        try:
            self._socket.close()
        except Exception:
            pass
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        shutil.rmtree(self._profile, ignore_errors=True)

    def __enter__(self) -> "Browser":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
