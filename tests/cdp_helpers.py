"""A headless chromium driven through the DevTools protocol over a pipe (--remote-debugging-pipe), stdlib only.

The protocol's messages are JSON objects separated by NUL bytes on file descriptors 3 (to the browser) and 4 (from
it).  The page's clock is put under virtual time (Emulation.setVirtualTimePolicy) so that "within one second" is a
second of the page's own timers, whatever the load on the machine: :meth:`Browser.advance` lets the page run that
long (its polls and renders included; the fetches it waits for are real) and pauses it again.
"""

from __future__ import annotations

import json
import os
import select
import shutil
import subprocess
import tempfile
import time

WAIT_S = 60.0  # the longest any one reply may take before the helper gives up (a safety net, not a measurement)


def chromium_binary() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


class Browser:
    """One headless chromium with one page attached (``with Browser() as b: b.open(url)``)."""

    def __init__(self, binary: str | None = None, *, window=(1280, 800)):
        binary = binary or chromium_binary()
        self.profile = tempfile.TemporaryDirectory(prefix="sonicskin-chromium-")
        to_r, to_w = os.pipe()      # we write, the browser reads on fd 3
        from_r, from_w = os.pipe()  # the browser writes on fd 4, we read
        # out of the way of fds 3 and 4 while the child moves them there
        hi_r, hi_w = os.dup2(to_r, 1000 + to_r), os.dup2(from_w, 1000 + from_w)

        def fds() -> None:
            os.dup2(hi_r, 3)
            os.dup2(hi_w, 4)

        self.proc = subprocess.Popen(
            [binary, "--headless", "--no-sandbox", "--disable-gpu", "--remote-debugging-pipe", "--no-first-run",
             f"--user-data-dir={self.profile.name}", f"--window-size={window[0]},{window[1]}", "about:blank"],
            pass_fds=(3, 4), preexec_fn=fds, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        for fd in (to_r, from_w, hi_r, hi_w):
            os.close(fd)
        self._w, self._r = to_w, from_r
        self._buf = b""
        self._id = 0
        self.events: list[dict] = []
        self.session: str | None = None

    # -- protocol --------------------------------------------------------------------------
    def _recv(self) -> dict:
        deadline = time.monotonic() + WAIT_S
        while b"\0" not in self._buf:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([self._r], [], [], left)[0]:
                raise TimeoutError(f"chromium sent nothing for {WAIT_S:g} s")
            chunk = os.read(self._r, 1 << 16)
            if not chunk:
                raise EOFError("chromium closed the DevTools pipe (it exited)")
            self._buf += chunk
        msg, _, self._buf = self._buf.partition(b"\0")
        return json.loads(msg)

    def call(self, method: str, params: dict | None = None, *, session: str | None | bool = True) -> dict:
        """Send one command (to the page's session unless ``session=None``) and return its result."""
        self._id += 1
        msg = {"id": self._id, "method": method, "params": params or {}}
        sid = self.session if session is True else session
        if sid:
            msg["sessionId"] = sid
        os.write(self._w, json.dumps(msg).encode() + b"\0")
        while True:
            m = self._recv()
            if m.get("id") == self._id:
                if "error" in m:
                    raise RuntimeError(f"{method}: {m['error']}")
                return m.get("result", {})
            self.events.append(m)

    def wait_event(self, method: str) -> dict:
        for i, m in enumerate(self.events):
            if m.get("method") == method:
                return self.events.pop(i)
        while True:
            m = self._recv()
            if m.get("method") == method:
                return m
            self.events.append(m)

    # -- page --------------------------------------------------------------------------------
    def open(self, url: str, ready: str = "true") -> None:
        """Attach to the page, load ``url`` and wait (real time) until the JS expression ``ready`` is true."""
        targets = self.call("Target.getTargets", session=None)["targetInfos"]
        page = next(t for t in targets if t["type"] == "page")
        self.session = self.call("Target.attachToTarget", {"targetId": page["targetId"], "flatten": True},
                                 session=None)["sessionId"]
        self.call("Page.enable")
        self.call("Page.navigate", {"url": url})
        deadline = time.monotonic() + WAIT_S
        while not self.js(f"document.readyState === 'complete' && !!({ready})"):
            if time.monotonic() > deadline:
                raise TimeoutError(f"the page at {url} was not ready ({ready}) after {WAIT_S:g} s")
            time.sleep(0.05)

    def js(self, expression: str):
        """The value of a JS expression in the page (JSON-able)."""
        r = self.call("Runtime.evaluate", {"expression": expression, "returnByValue": True, "awaitPromise": True})
        if "exceptionDetails" in r:
            raise RuntimeError(f"{expression}: {r['exceptionDetails'].get('text')}")
        return r["result"].get("value")

    def advance(self, ms: float) -> None:
        """Let the page run ``ms`` of its own (virtual) time, waiting for its fetches, then pause it."""
        self.call("Emulation.setVirtualTimePolicy", {"policy": "pauseIfNetworkFetchesPending", "budget": float(ms)})
        self.wait_event("Emulation.virtualTimeBudgetExpired")

    def close(self) -> None:
        try:
            self.call("Browser.close", session=None)
        except (EOFError, TimeoutError, OSError, RuntimeError):
            pass
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        os.close(self._w)
        os.close(self._r)
        self.profile.cleanup()

    def __enter__(self) -> Browser:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
