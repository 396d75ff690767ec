#!/usr/bin/env python3
"""Drive headless Chromium over the DevTools protocol (CDP) through --remote-debugging-pipe.

Standard library only. Chromium reads NUL-terminated JSON commands on its fd 3 and writes
NUL-terminated JSON answers and events on its fd 4; one page target is attached in flat mode
and every page command carries its session ID.

    with Browser() as b:
        b.open("http://127.0.0.1:8080/index.html")
        b.wait_for("window.skinbusView && window.skinbusView.summary().robot_loaded", 20)
        print(b.evaluate("window.skinbusView.summary()"))
        b.screenshot("/tmp/view.png")

Command line (prints window.skinbusView.summary() as JSON when the page has it):

    cdp.py URL OUT.png [--wait EXPR] [--timeout S]

WebGL runs on SwiftShader (the CPU): --use-angle=swiftshader --enable-unsafe-swiftshader.
"""

import argparse
import base64
import fcntl
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time


class CdpError(RuntimeError):
    """A protocol error, a page exception, a timeout or a browser that went away."""


class Browser:
    """One headless Chromium with one page. Always close() it (or use it as a context manager):
    the process is killed and its temporary profile removed."""

    # Seconds a single protocol command may take before CdpError.
    COMMAND_TIMEOUT_S = 30.0

    def __init__(self, chromium="chromium", width=1280, height=800):
        self._width, self._height = width, height
        self._profile = tempfile.mkdtemp(prefix="cdp-profile-")
        self._lock = threading.Condition()
        self._answers = {}          # command id -> answer message
        self._errors = []           # console errors and page exceptions, as strings
        self._loads = 0             # Page.loadEventFired events seen
        self._next_id = 0
        self._closed = False
        self._session = None
        self._proc = None
        try:
            self._start(chromium)
            self._attach_page()
        except BaseException:
            self.close()
            raise

    # -- process and pipe ----------------------------------------------------------------------

    def _start(self, chromium):
        # to_browser: we write, Chromium reads on fd 3; from_browser: Chromium writes on fd 4.
        to_r, to_w = os.pipe()
        from_r, from_w = os.pipe()
        # The child's ends are moved above fd 10 first so that placing them on 3 and 4 in the
        # child cannot overwrite one with the other.
        child_in = fcntl.fcntl(to_r, fcntl.F_DUPFD_CLOEXEC, 10)
        child_out = fcntl.fcntl(from_w, fcntl.F_DUPFD_CLOEXEC, 10)
        os.close(to_r)
        os.close(from_w)

        def place_fds():
            os.dup2(child_in, 3)
            os.dup2(child_out, 4)

        args = [
            chromium,
            "--headless=new",
            "--no-sandbox",
            "--remote-debugging-pipe",
            "--user-data-dir=" + self._profile,
            "--no-first-run",
            "--no-default-browser-check",
            "--disable-extensions",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--disable-dev-shm-usage",
            "--hide-scrollbars",
            "--mute-audio",
            # WebGL without a GPU: ANGLE on SwiftShader.
            "--use-angle=swiftshader",
            "--enable-unsafe-swiftshader",
            "--ignore-gpu-blocklist",
            "--window-size=%d,%d" % (self._width, self._height),
            "about:blank",
        ]
        self._log_path = os.path.join(self._profile, "chromium.log")
        log = open(self._log_path, "wb")
        try:
            self._proc = subprocess.Popen(
                args, stdin=subprocess.DEVNULL, stdout=log, stderr=log,
                pass_fds=(3, 4), preexec_fn=place_fds, start_new_session=True)
        finally:
            log.close()
            os.close(child_in)
            os.close(child_out)
        self._to = to_w
        self._from = from_r
        self._reader = threading.Thread(target=self._read_loop, daemon=True)
        self._reader.start()

    def _read_loop(self):
        buf = b""
        while True:
            try:
                chunk = os.read(self._from, 1 << 16)
            except OSError:
                chunk = b""
            if not chunk:
                with self._lock:
                    self._closed = True
                    self._lock.notify_all()
                return
            buf += chunk
            while b"\0" in buf:
                raw, buf = buf.split(b"\0", 1)
                try:
                    msg = json.loads(raw)
                except ValueError:
                    continue
                self._dispatch(msg)

    def _dispatch(self, msg):
        with self._lock:
            if "id" in msg:
                self._answers[msg["id"]] = msg
            elif msg.get("sessionId") == self._session and self._session is not None:
                method, params = msg.get("method", ""), msg.get("params", {})
                if method == "Page.loadEventFired":
                    self._loads += 1
                error = _error_text(method, params)
                if error is not None:
                    self._errors.append(error)
            self._lock.notify_all()

    def _log_tail(self):
        try:
            with open(self._log_path, "rb") as f:
                return f.read()[-2000:].decode("utf-8", "replace")
        except OSError:
            return ""

    # -- protocol ------------------------------------------------------------------------------

    def send(self, method, params=None, session=True, timeout_s=None):
        """Send one command (to the page session unless session=False); return its result."""
        timeout_s = self.COMMAND_TIMEOUT_S if timeout_s is None else timeout_s
        with self._lock:
            if self._closed:
                raise CdpError("the browser is gone (%s)\n%s" % (method, self._log_tail()))
            self._next_id += 1
            cid = self._next_id
        msg = {"id": cid, "method": method, "params": params or {}}
        if session and self._session is not None:
            msg["sessionId"] = self._session
        try:
            os.write(self._to, json.dumps(msg).encode() + b"\0")
        except OSError as e:
            raise CdpError("cannot write to the browser: %s" % e) from e
        deadline = time.monotonic() + timeout_s
        with self._lock:
            while cid not in self._answers:
                left = deadline - time.monotonic()
                if self._closed:
                    raise CdpError("the browser went away during %s\n%s"
                                   % (method, self._log_tail()))
                if left <= 0:
                    raise CdpError("%s: no answer in %.0f s" % (method, timeout_s))
                self._lock.wait(left)
            answer = self._answers.pop(cid)
        if "error" in answer:
            raise CdpError("%s: %s" % (method, answer["error"].get("message", answer["error"])))
        return answer.get("result", {})

    def _attach_page(self):
        target = self.send("Target.createTarget", {"url": "about:blank"},
                           session=False)["targetId"]
        self._session = self.send("Target.attachToTarget", {
            "targetId": target, "flatten": True}, session=False)["sessionId"]
        for domain in ("Page", "Runtime", "Log"):
            self.send(domain + ".enable")
        self.send("Emulation.setDeviceMetricsOverride", {
            "width": self._width, "height": self._height, "deviceScaleFactor": 1,
            "mobile": False})

    @property
    def pid(self):
        """The browser's process ID; it leads its own session, which holds its renderer and GPU
        processes (for accounting their CPU time)."""
        return self._proc.pid

    # -- page ----------------------------------------------------------------------------------

    def open(self, url, timeout_s=30.0):
        """Navigate to url and wait for its load event."""
        with self._lock:
            loads = self._loads
        result = self.send("Page.navigate", {"url": url}, timeout_s=timeout_s)
        if result.get("errorText"):
            raise CdpError("cannot open %s: %s" % (url, result["errorText"]))
        deadline = time.monotonic() + timeout_s
        with self._lock:
            while self._loads == loads:
                left = deadline - time.monotonic()
                if self._closed:
                    raise CdpError("the browser went away opening %s" % url)
                if left <= 0:
                    raise CdpError("%s: no load event in %.0f s" % (url, timeout_s))
                self._lock.wait(left)

    def evaluate(self, expression, timeout_s=None):
        """The value of a JavaScript expression (promises awaited), as JSON-able Python.
        Raises CdpError with the exception's message when it throws."""
        timeout_s = self.COMMAND_TIMEOUT_S if timeout_s is None else timeout_s
        result = self.send("Runtime.evaluate", {
            "expression": expression, "returnByValue": True, "awaitPromise": True,
            "timeout": int(timeout_s * 1000)}, timeout_s=timeout_s + 5)
        if "exceptionDetails" in result:
            details = result["exceptionDetails"]
            exc = details.get("exception", {})
            raise CdpError("%s: %s" % (expression[:80],
                                        exc.get("description") or details.get("text")))
        return result.get("result", {}).get("value")

    def wait_for(self, expression, timeout_s=10.0, interval_s=0.1):
        """Poll expression until it is truthy; return its value. CdpError after timeout_s (the
        last exception the expression threw, if any, is in the message)."""
        deadline = time.monotonic() + timeout_s
        last_error = None
        while True:
            try:
                value = self.evaluate(expression, timeout_s=max(1.0, min(10.0, timeout_s)))
                if value:
                    return value
                last_error = None
            except CdpError as e:
                if self._closed:
                    raise
                last_error = e
            if time.monotonic() >= deadline:
                raise CdpError("timed out after %.1f s waiting for %s%s" % (
                    timeout_s, expression, "" if last_error is None else " (%s)" % last_error))
            time.sleep(interval_s)

    def screenshot(self, path):
        """Write a PNG of the page's viewport to path."""
        data = self.send("Page.captureScreenshot", {"format": "png"})["data"]
        with open(path, "wb") as f:
            f.write(base64.b64decode(data))

    def console_errors(self):
        """Page exceptions, console.error calls and error log entries seen so far."""
        with self._lock:
            return list(self._errors)

    # -- end -----------------------------------------------------------------------------------

    def close(self):
        """End the browser (politely, then killed) and remove its profile. Idempotent."""
        proc, self._proc = self._proc, None
        if proc is not None:
            if proc.poll() is None and not self._closed:
                try:
                    self.send("Browser.close", session=False, timeout_s=5)
                except CdpError:
                    pass
            try:
                proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                pass
            # Chromium runs in its own session (process group): its renderer and GPU processes
            # go with it, whatever state it was left in.
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass
            proc.wait(timeout=5)
            for fd in (self._to, self._from):
                try:
                    os.close(fd)
                except OSError:
                    pass
        shutil.rmtree(self._profile, ignore_errors=True)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


def _error_text(method, params):
    """The error an event reports, as one line, or None."""
    if method == "Runtime.exceptionThrown":
        d = params.get("exceptionDetails", {})
        return "exception: " + (d.get("exception", {}).get("description") or d.get("text", ""))
    if method == "Runtime.consoleAPICalled" and params.get("type") == "error":
        parts = [a.get("value", a.get("description", "")) for a in params.get("args", [])]
        return "console.error: " + " ".join(str(p) for p in parts)
    if method == "Log.entryAdded" and params.get("entry", {}).get("level") == "error":
        e = params["entry"]
        return "log: %s%s" % (e.get("text", ""), " (%s)" % e["url"] if e.get("url") else "")
    return None


def main():
    ap = argparse.ArgumentParser(description="Open a page in headless Chromium, wait for an "
                                 "expression, print the skinbus view's summary, screenshot.")
    ap.add_argument("url")
    ap.add_argument("out_png")
    ap.add_argument("--wait", default=None, help="JavaScript expression to wait for (truthy)")
    ap.add_argument("--timeout", type=float, default=30.0, help="seconds (default 30)")
    ap.add_argument("--chromium", default="chromium")
    args = ap.parse_args()
    status = 0
    with Browser(chromium=args.chromium) as b:
        b.open(args.url, timeout_s=args.timeout)
        if args.wait:
            try:
                b.wait_for(args.wait, args.timeout)
            except CdpError as e:
                print(e, file=sys.stderr)
                status = 1
        if b.evaluate("typeof window.skinbusView === 'object' && window.skinbusView !== null"):
            print(json.dumps(b.evaluate("window.skinbusView.summary()"), indent=1))
        b.screenshot(args.out_png)
        for error in b.console_errors():
            print(error, file=sys.stderr)
    return status


if __name__ == "__main__":
    sys.exit(main())
