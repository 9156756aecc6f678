"""Open pages of the built site in headless Chromium and fail on any console error.

Usage: ``python3 docs/check_site.py docs/_build/html index.html auto_examples/01_pair.html``

Chromium is driven through the DevTools protocol over a pipe
(``--remote-debugging-pipe``: messages are JSON, each ended by a NUL byte, on file
descriptors 3 and 4), so that nothing beyond the standard library is needed. A page
fails on an uncaught exception, a ``console.error``, or a log entry of level error
(a resource that could not be loaded, such as a script from a network the site must
not need). The browser runs offline: a page that fetches anything fails.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

# Seconds a page may take to load and run its scripts: the site's pages are static.
_LOAD_TIMEOUT = 30.0
# Seconds left to scripts after the load event (MathJax typesets then).
_SETTLE = 1.5


def _onto_3_and_4(read_end: int, write_end: int) -> None:
    """In the child: the pipe ends on fds 3 and 4, through copies, since either may
    already be 3 or 4."""
    r, w = os.dup(read_end), os.dup(write_end)
    os.dup2(r, 3)
    os.dup2(w, 4)


class _Browser:
    """A headless Chromium driven over the DevTools pipe."""

    def __init__(self, chromium: str):
        self._profile = tempfile.mkdtemp(prefix="gridstrain-docs-chromium-")
        to_browser_r, self._to_browser = os.pipe()
        self._from_browser, from_browser_w = os.pipe()
        # the browser reads commands on fd 3 and writes replies on fd 4
        self._proc = subprocess.Popen(
            [chromium, "--headless", "--no-sandbox", "--disable-gpu",
             "--remote-debugging-pipe", "--no-first-run", "--disable-extensions",
             "--proxy-server=127.0.0.1:9", f"--user-data-dir={self._profile}",
             "about:blank"],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            close_fds=False, preexec_fn=lambda: _onto_3_and_4(to_browser_r, from_browser_w))
        os.close(to_browser_r)
        os.close(from_browser_w)
        self._buffer = b""
        self._next_id = 0
        self.events: list[dict] = []

    def send(self, method: str, params: dict | None = None, session: str | None = None):
        self._next_id += 1
        msg = {"id": self._next_id, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        os.write(self._to_browser, json.dumps(msg).encode() + b"\0")
        mid = self._next_id
        while True:
            reply = self._read(_LOAD_TIMEOUT)
            if reply is None:
                raise TimeoutError(f"no reply from Chromium to {method}")
            if reply.get("id") == mid:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply.get("result", {})
            self.events.append(reply)

    def _read(self, timeout: float) -> dict | None:
        import select

        end = time.monotonic() + timeout
        while b"\0" not in self._buffer:
            left = end - time.monotonic()
            if left <= 0 or not select.select([self._from_browser], [], [], left)[0]:
                return None
            chunk = os.read(self._from_browser, 1 << 16)
            if not chunk:
                raise RuntimeError("Chromium closed its DevTools pipe")
            self._buffer += chunk
        msg, self._buffer = self._buffer.split(b"\0", 1)
        return json.loads(msg)

    def wait_for(self, method: str, timeout: float) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if any(e.get("method") == method for e in self.events):
                return True
            msg = self._read(end - time.monotonic())
            if msg is not None:
                self.events.append(msg)
        return False

    def drain(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while (left := end - time.monotonic()) > 0:
            msg = self._read(left)
            if msg is not None:
                self.events.append(msg)

    def close(self) -> None:
        try:
            self._proc.terminate()
            self._proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self._proc.kill()
        os.close(self._to_browser)
        os.close(self._from_browser)
        shutil.rmtree(self._profile, ignore_errors=True)


def _errors(events: list[dict]) -> list[str]:
    out = []
    for e in events:
        m, p = e.get("method"), e.get("params", {})
        if m == "Runtime.exceptionThrown":
            d = p.get("exceptionDetails", {})
            out.append("uncaught: " + d.get("exception", {}).get("description", d.get("text", "")))
        elif m == "Runtime.consoleAPICalled" and p.get("type") in ("error", "assert"):
            args = " ".join(str(a.get("value", a.get("description", ""))) for a in p["args"])
            out.append(f"console.{p['type']}: {args}")
        elif m == "Log.entryAdded" and p.get("entry", {}).get("level") == "error":
            entry = p["entry"]
            out.append(f"{entry.get('source')}: {entry.get('text')} {entry.get('url', '')}")
    return out


def check(site: Path, pages: list[str], chromium: str) -> int:
    browser = _Browser(chromium)
    failed = 0
    try:
        for page in pages:
            path = (site / page).resolve()
            if not path.is_file():
                print(f"{page}: not in the built site {site}")
                failed += 1
                continue
            target = browser.send("Target.createTarget", {"url": "about:blank"})
            session = browser.send("Target.attachToTarget",
                                   {"targetId": target["targetId"], "flatten": True})
            sid = session["sessionId"]
            for domain in ("Runtime", "Log", "Page"):
                browser.send(f"{domain}.enable", session=sid)
            browser.events.clear()
            browser.send("Page.navigate", {"url": path.as_uri()}, session=sid)
            loaded = browser.wait_for("Page.loadEventFired", _LOAD_TIMEOUT)
            browser.drain(_SETTLE)
            errors = _errors([e for e in browser.events if e.get("sessionId") == sid])
            if not loaded:
                errors.append(f"the page did not load within {_LOAD_TIMEOUT:g} s")
            browser.send("Target.closeTarget", {"targetId": target["targetId"]})
            for err in errors:
                print(f"{page}: {err}")
            print(f"{page}: {'FAILED' if errors else 'no console error'}")
            failed += bool(errors)
    finally:
        browser.close()
    return 1 if failed else 0


def main(argv: list[str]) -> int:
    if len(argv) < 2:
        print(__doc__.strip().splitlines()[2])
        return 2
    chromium = os.environ.get("CHROMIUM") or shutil.which("chromium") \
        or shutil.which("chromium-browser") or shutil.which("google-chrome")
    if chromium is None:
        # as the test suite does for the HTML report: a machine without a browser
        # still builds the site with warnings as errors, and says what it skipped
        print("check_site: SKIPPED, no Chromium found (apt-get install chromium, or set "
              "CHROMIUM to its path)")
        return 0
    return check(Path(argv[0]), argv[1:], chromium)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
