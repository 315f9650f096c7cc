"""The report in real headless Chromium: loads from disk, no console errors, every image loaded.

Chromium is driven over the DevTools protocol on a pipe (``--remote-debugging-pipe``: JSON messages
separated by NUL on fds 3/4), so no driver package is needed. The screenshot is saved to
``$SBCAL_ARTIFACTS`` (default ``artifacts/``) as ``report.png``. Under CI (``CI`` set) a missing
Chromium is a failure: ``.ci/run`` installs Debian's package.
"""

import base64
import json
import os
import select
import shutil
import subprocess
import time
from pathlib import Path

import pytest

from sbcal.cli import main

from .test_report import run_store  # noqa: F401  (fixture)

EXE = next((shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome") if shutil.which(n)), None)


class DevTools:
    def __init__(self, exe, profile):
        self.cmd_r, self.cmd_w = os.pipe()
        self.res_r, self.res_w = os.pipe()
        cmd_r, res_w = self.cmd_r, self.res_w

        def fds():  # the browser reads commands on fd 3 and writes replies on fd 4
            os.dup2(cmd_r, 3)
            os.dup2(res_w, 4)

        self.proc = subprocess.Popen(
            [exe, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
             "--disable-background-networking", "--disable-component-update", "--disable-sync",
             "--remote-debugging-pipe", f"--user-data-dir={profile}", "--window-size=1200,900", "about:blank"],
            preexec_fn=fds, close_fds=False, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        os.close(cmd_r)
        os.close(res_w)
        self.next_id = 0
        self.buf = b""
        self.events = []

    def _read(self, deadline):
        while b"\0" not in self.buf:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([self.res_r], [], [], left)[0]:
                raise TimeoutError("no reply from chromium")
            chunk = os.read(self.res_r, 1 << 16)
            if not chunk:
                raise RuntimeError("chromium closed the pipe")
            self.buf += chunk
        msg, self.buf = self.buf.split(b"\0", 1)
        return json.loads(msg)

    def send(self, method, params=None, session=None, timeout=30):
        self.next_id += 1
        msg = {"id": self.next_id, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        os.write(self.cmd_w, json.dumps(msg).encode() + b"\0")
        deadline = time.monotonic() + timeout
        while True:
            m = self._read(deadline)
            if m.get("id") == self.next_id:
                if "error" in m:
                    raise RuntimeError(f"{method}: {m['error']}")
                return m["result"]
            self.events.append(m)

    def wait_event(self, method, timeout=30):
        deadline = time.monotonic() + timeout
        while not any(e.get("method") == method for e in self.events):
            self.events.append(self._read(deadline))

    def close(self):
        try:
            self.send("Browser.close", timeout=5)
        except Exception:
            pass
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
        os.close(self.cmd_w)
        os.close(self.res_r)


@pytest.mark.skipif(EXE is None and not os.environ.get("CI"), reason="no chromium here (CI installs it)")
def test_report_in_headless_chromium(run_store, tmp_path):  # noqa: F811
    assert EXE, "chromium is not installed: .ci/run should have installed Debian's chromium"
    out = tmp_path / "rep"
    assert main(["report", "--runs", str(run_store), "-o", str(out)]) == 0
    dt = DevTools(EXE, tmp_path / "profile")
    try:
        target = dt.send("Target.createTarget", {"url": "about:blank"})["targetId"]
        session = dt.send("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
        for domain in ("Page", "Runtime", "Log"):
            dt.send(f"{domain}.enable", session=session)
        dt.send("Page.navigate", {"url": (out / "index.html").as_uri()}, session=session)
        dt.wait_event("Page.loadEventFired", timeout=60)
        images = json.loads(dt.send("Runtime.evaluate", {
            "expression": "JSON.stringify(Array.from(document.images).map(i => [i.getAttribute('src'), i.complete, i.naturalWidth]))",
            "returnByValue": True}, session=session)["result"]["value"])
        shot = dt.send("Page.captureScreenshot", {"format": "png", "captureBeyondViewport": False}, session=session)
        errors = [e for e in dt.events
                  if (e.get("method") == "Runtime.consoleAPICalled" and e["params"]["type"] == "error")
                  or e.get("method") == "Runtime.exceptionThrown"
                  or (e.get("method") == "Log.entryAdded" and e["params"]["entry"]["level"] == "error")]
    finally:
        dt.close()
    art = Path(os.environ.get("SBCAL_ARTIFACTS", "artifacts"))
    art.mkdir(parents=True, exist_ok=True)
    (art / "report.png").write_bytes(base64.b64decode(shot["data"]))
    assert not errors, errors
    assert len(images) >= 14
    broken = [src for src, complete, width in images if not (complete and width > 0)]
    assert not broken, broken
