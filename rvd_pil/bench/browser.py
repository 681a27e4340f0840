"""Open a page in headless Chromium and ask it questions over the DevTools protocol.

    python -m rvd_pil.bench.browser reports/pil/report.html --width 1400 --screenshot report-1400px.png

Chromium (Debian package `chromium`, installed by tools/install-deps) is driven over
--remote-debugging-pipe: commands are JSON objects, each terminated by a NUL byte, written to the
browser's file descriptor 3; replies and events come back on its descriptor 4. No server, no port,
no Python package beyond the standard library. Script errors (uncaught exceptions, console.error,
errors the browser logs itself) are collected while the page loads and after every evaluation.
"""
from __future__ import annotations

import argparse
import base64
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CANDIDATES = ("chromium", "chromium-browser", "google-chrome", "chrome")


def find_chromium() -> str | None:
    for name in CANDIDATES:
        path = shutil.which(name)
        if path:
            return path
    return None


class BrowserError(RuntimeError):
    pass


class Page:
    """One headless Chromium with one page of `width` x `height` CSS pixels."""

    def __init__(self, width: int = 1400, height: int = 900, timeout_s: float = 60.0):
        exe = find_chromium()
        if exe is None:
            raise BrowserError("no chromium on PATH (Debian package chromium: tools/install-deps test)")
        self.timeout_s = timeout_s
        self.errors: list[str] = []
        self._id = 0
        self._buf = b""
        self._profile = tempfile.TemporaryDirectory(prefix="rvd-chromium-")
        to_child_r, self._to_child = os.pipe()
        self._from_child, from_child_w = os.pipe()

        def fds():  # the protocol's descriptors in the child: 3 reads commands, 4 writes replies
            # via high numbers first: a pipe end may itself be 3 or 4 (dup2 onto itself would keep
            # it close-on-exec, and the first dup2 could overwrite the other end)
            high_r, high_w = 200, 201
            os.dup2(to_child_r, high_r)
            os.dup2(from_child_w, high_w)
            os.dup2(high_r, 3)
            os.dup2(high_w, 4)
            os.set_inheritable(3, True)
            os.set_inheritable(4, True)

        args = [exe, "--headless=new", "--remote-debugging-pipe", "--disable-gpu", "--no-first-run",
                "--no-default-browser-check", "--disable-extensions", "--allow-file-access-from-files",
                f"--user-data-dir={self._profile.name}", f"--window-size={width},{height}"]
        if os.geteuid() == 0:  # Chromium refuses to run its sandbox as root
            args.append("--no-sandbox")
        # close_fds=False: descriptors 3 and 4 are made by dup2 in the child (inheritable); every other
        # descriptor of this process is close-on-exec (Python's default), so nothing else leaks.
        self._proc = subprocess.Popen(args + ["about:blank"], close_fds=False, preexec_fn=fds, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                      stderr=subprocess.DEVNULL)
        os.close(to_child_r)
        os.close(from_child_w)
        target = self.call("Target.createTarget", url="about:blank")["targetId"]
        self._session = self.call("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
        for domain in ("Page", "Runtime", "Log"):
            self.call(f"{domain}.enable", session=True)
        self.call("Emulation.setDeviceMetricsOverride", session=True, width=width, height=height,
                  deviceScaleFactor=1, mobile=False)

    # -- protocol ---------------------------------------------------------------------------------
    def _send(self, method: str, params: dict, session: bool) -> int:
        self._id += 1
        msg = {"id": self._id, "method": method, "params": params}
        if session:
            msg["sessionId"] = self._session
        os.write(self._to_child, json.dumps(msg).encode() + b"\0")
        return self._id

    def _read(self, deadline: float) -> dict:
        while b"\0" not in self._buf:
            if time.monotonic() > deadline:
                raise BrowserError("chromium did not answer in time")
            import select

            ready, _, _ = select.select([self._from_child], [], [], 0.5)
            if ready:
                chunk = os.read(self._from_child, 1 << 20)
                if not chunk:
                    raise BrowserError(f"chromium exited (code {self._proc.poll()})")
                self._buf += chunk
        raw, self._buf = self._buf.split(b"\0", 1)
        return json.loads(raw)

    def _event(self, msg: dict) -> None:
        method, p = msg.get("method"), msg.get("params", {})
        if method == "Runtime.exceptionThrown":
            d = p["exceptionDetails"]
            self.errors.append((d.get("exception") or {}).get("description") or d.get("text", "exception"))
        elif method == "Runtime.consoleAPICalled" and p.get("type") in ("error", "assert"):
            self.errors.append("console." + p["type"] + ": " + " ".join(str(a.get("value", a.get("description")))
                                                                     for a in p.get("args", [])))
        elif method == "Log.entryAdded" and p["entry"].get("level") == "error":
            self.errors.append(f"{p['entry'].get('source')}: {p['entry'].get('text')} {p['entry'].get('url', '')}")

    def call(self, method: str, session: bool = False, **params) -> dict:
        want = self._send(method, params, session)
        deadline = time.monotonic() + self.timeout_s
        while True:
            msg = self._read(deadline)
            if msg.get("id") == want:
                if "error" in msg:
                    raise BrowserError(f"{method}: {msg['error'].get('message')}")
                return msg.get("result", {})
            self._event(msg)

    def wait_for(self, event: str) -> dict:
        deadline = time.monotonic() + self.timeout_s
        while True:
            msg = self._read(deadline)
            self._event(msg)
            if msg.get("method") == event:
                return msg.get("params", {})

    # -- what a test needs ------------------------------------------------------------------------
    def open(self, path: Path | str) -> None:
        url = Path(path).resolve().as_uri() if "://" not in str(path) else str(path)
        self.call("Page.navigate", session=True, url=url)
        self.wait_for("Page.loadEventFired")

    def eval(self, expression: str):
        r = self.call("Runtime.evaluate", session=True, expression=expression, returnByValue=True)
        if "exceptionDetails" in r:
            raise BrowserError(f"{expression!r}: {r['exceptionDetails'].get('text')}")
        return r["result"].get("value")

    def screenshot(self, path: Path | str, full_page: bool = False) -> Path:
        params = {"format": "png"}
        if full_page:
            params["captureBeyondViewport"] = True
        data = self.call("Page.captureScreenshot", session=True, **params)["data"]
        Path(path).write_bytes(base64.b64decode(data))
        return Path(path)

    def close(self) -> None:
        try:
            self.call("Browser.close")
        except (BrowserError, OSError):
            pass
        try:
            self._proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()
        for fd in (self._to_child, self._from_child):
            try:
                os.close(fd)
            except OSError:
                pass
        self._profile.cleanup()

    def __enter__(self) -> "Page":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m rvd_pil.bench.browser", description=__doc__.split("\n\n")[0])
    ap.add_argument("page", help="HTML file")
    ap.add_argument("--width", type=int, default=1400)
    ap.add_argument("--height", type=int, default=900)
    ap.add_argument("--screenshot", default=None, help="PNG of the viewport")
    a = ap.parse_args(argv)
    if not Path(a.page).is_file():
        print(f"browser: {a.page}: no such file", file=sys.stderr)
        return 2
    try:
        with Page(a.width, a.height) as page:
            page.open(a.page)
            overflow = page.eval("document.documentElement.scrollWidth - window.innerWidth")
            if a.screenshot:
                page.screenshot(a.screenshot)
            print(f"{a.page}: horizontal overflow {overflow} px at {a.width} px, {len(page.errors)} script error(s)")
            for err in page.errors:
                print(f"  {err}")
            return 1 if page.errors else 0
    except BrowserError as exc:
        print(f"browser: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
