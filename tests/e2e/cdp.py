#!/usr/bin/python3
"""A small Chrome DevTools Protocol driver for the dashboard's browser tests.

Starts Debian's headless Chromium (WebGL through SwiftShader, so no GPU is needed), opens one page
and drives it over the DevTools websocket:

    from cdp import Browser
    with Browser(width=1280, height=800) as b:
        b.fail_requests("*/tiles/3_-1_0.drc*")        # optional: that tile answers HTTP 500
        b.navigate("http://127.0.0.1:8080/#token=abc")
        state = b.wait_for("window.rimDashboard?.polls >= 2 && window.rimDashboard", 30)
        b.screenshot("dashboard.png")
        print(b.evaluate("document.title"), b.console_messages())

Needs only the standard library and Debian's python3-websocket (websocket-client), which the
system Python has: run it with /usr/bin/python3. Run as a script, it loads one page and prints
the value of an expression (see main()).
"""

from __future__ import annotations

import base64
import itertools
import json
import os
import queue
import re
import shutil
import signal
import subprocess
import tempfile
import threading
import time
from typing import Any, Callable, Dict, List, Optional

import websocket

CHROMIUM = "/usr/bin/chromium"
_DEVTOOLS_RE = re.compile(r"DevTools listening on (ws://\S+)")


class CdpError(RuntimeError):
    """A command failed, the browser went away, or something took too long."""


class Browser:
    """One headless Chromium with one page, driven over CDP.

    Commands are sent from the caller's thread; a reader thread receives replies and events, so
    events (console messages, paused requests) are handled even while the caller sleeps.
    """

    def __init__(self, width: int = 1280, height: int = 800, chromium: str = CHROMIUM,
                 extra_args: Optional[List[str]] = None, start_timeout_s: float = 30.0):
        self._tmp = tempfile.mkdtemp(prefix="rim-cdp-")
        self._proc: Optional[subprocess.Popen] = None
        self._ws: Optional[websocket.WebSocket] = None
        self._ids = itertools.count(1)
        self._replies: Dict[int, "queue.Queue[dict]"] = {}
        self._lock = threading.Lock()
        self._closed = False
        self._stderr_tail: List[str] = []
        self._console: List[Dict[str, Any]] = []
        self._failed: List[str] = []         # URLs answered by fail_requests
        self._fail_patterns: List[Dict[str, Any]] = []
        self._fail_status = 500
        self._load_fired = threading.Event()
        self._listeners: List[Callable[[dict], None]] = []
        self.session_id: Optional[str] = None
        self._size = (width, height)
        try:
            self._launch(width, height, chromium, extra_args or [], start_timeout_s)
            self._open_page()
        except BaseException:
            self.close()
            raise

    # ---- lifecycle --------------------------------------------------------------------------

    def _launch(self, width: int, height: int, chromium: str, extra_args: List[str],
                timeout_s: float) -> None:
        args = [
            chromium,
            "--headless=new",
            "--use-angle=swiftshader",
            "--enable-unsafe-swiftshader",
            "--no-sandbox",
            "--remote-debugging-port=0",
            f"--user-data-dir={self._tmp}",
            f"--window-size={width},{height}",
            "--no-first-run",
            "--no-default-browser-check",
            "--disable-extensions",
            "--disable-component-update",
            "--disable-background-networking",
            "--disable-dev-shm-usage",
            "--enable-precise-memory-info",  # performance.memory without rounding
            "--mute-audio",
            "--hide-scrollbars",
            *extra_args,
            "about:blank",
        ]
        # Its own process group, so close() also ends the renderer and GPU processes.
        self._proc = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                      stderr=subprocess.PIPE, text=True, errors="replace",
                                      start_new_session=True)
        found: "queue.Queue[Optional[str]]" = queue.Queue()

        def drain() -> None:  # keeps the pipe from filling up, and remembers the last lines
            assert self._proc is not None and self._proc.stderr is not None
            for line in self._proc.stderr:
                self._stderr_tail = (self._stderr_tail + [line.rstrip()])[-40:]
                m = _DEVTOOLS_RE.search(line)
                if m:
                    found.put(m.group(1))
            found.put(None)  # stderr closed: the browser exited

        threading.Thread(target=drain, name="chromium-stderr", daemon=True).start()
        try:
            url = found.get(timeout=timeout_s)
        except queue.Empty:
            raise CdpError(f"{chromium} printed no 'DevTools listening on ws://...' line within "
                           f"{timeout_s:.0f} s; its stderr ended with:\n" + self.stderr_tail())
        if url is None:
            raise CdpError(f"{chromium} exited (status {self._proc.wait()}) before DevTools "
                           "started; its stderr ended with:\n" + self.stderr_tail())
        # No Origin header: Chromium refuses websocket clients that send one it does not allow.
        self._ws = websocket.create_connection(url, timeout=timeout_s, suppress_origin=True,
                                               enable_multithread=True)
        self._ws.settimeout(None)
        threading.Thread(target=self._read_loop, name="cdp-reader", daemon=True).start()

    def _open_page(self) -> None:
        target = self.send("Target.createTarget", {"url": "about:blank"}, session=False)
        attached = self.send("Target.attachToTarget",
                             {"targetId": target["targetId"], "flatten": True}, session=False)
        self.session_id = attached["sessionId"]
        self.target_id = target["targetId"]
        for domain in ("Page", "Runtime", "Log"):
            self.send(f"{domain}.enable")
        # The viewport exactly width x height (the window's own frame would take some of it).
        self.send("Emulation.setDeviceMetricsOverride", {
            "width": self._size[0], "height": self._size[1], "deviceScaleFactor": 1,
            "mobile": False})

    def close(self) -> None:
        """Ends Chromium and removes its profile directory. Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        if self._ws is not None:
            try:
                self._ws.close()
            except Exception:  # the browser may be gone already
                pass
        if self._proc is not None and self._proc.poll() is None:
            try:
                os.killpg(self._proc.pid, signal.SIGTERM)
                self._proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(self._proc.pid, signal.SIGKILL)
                self._proc.wait()
            except ProcessLookupError:
                pass
        shutil.rmtree(self._tmp, ignore_errors=True)

    def __enter__(self) -> "Browser":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def stderr_tail(self) -> str:
        """Chromium's last stderr lines, for error messages."""
        return "\n".join(self._stderr_tail)

    # ---- protocol ---------------------------------------------------------------------------

    def _read_loop(self) -> None:
        while True:
            try:
                raw = self._ws.recv()
            except Exception:  # closed, by close() or by the browser exiting
                break
            if not raw:
                break
            message = json.loads(raw)
            if "id" in message:
                with self._lock:
                    waiter = self._replies.get(message["id"])
                if waiter is not None:
                    waiter.put(message)
            else:
                try:
                    self._on_event(message)
                except Exception as e:  # never let one event stop the reader
                    self._console.append({"type": "driver-error", "text": repr(e)})
        with self._lock:  # wake every waiter: no reply will come
            for waiter in self._replies.values():
                waiter.put({"error": {"message": "the DevTools connection closed"}})

    def _post(self, method: str, params: Optional[dict], session: bool) -> int:
        if self._closed or self._ws is None:
            raise CdpError(f"{method}: the browser is closed")
        message_id = next(self._ids)
        message: Dict[str, Any] = {"id": message_id, "method": method, "params": params or {}}
        if session and self.session_id:
            message["sessionId"] = self.session_id
        with self._lock:
            self._replies[message_id] = queue.Queue()
        self._ws.send(json.dumps(message))
        return message_id

    def send(self, method: str, params: Optional[dict] = None, session: bool = True,
             timeout_s: float = 30.0) -> dict:
        """Sends a command (to the page, or to the browser with session=False) and returns its
        result; raises CdpError on an error reply or when none comes within timeout_s."""
        message_id = self._post(method, params, session)
        try:
            reply = self._replies[message_id].get(timeout=timeout_s)
        except queue.Empty:
            raise CdpError(f"{method}: no reply within {timeout_s:.0f} s")
        finally:
            with self._lock:
                self._replies.pop(message_id, None)
        if "error" in reply:
            raise CdpError(f"{method}: {reply['error'].get('message')} "
                           f"{reply['error'].get('data', '')}".rstrip())
        return reply.get("result", {})

    def _send_async(self, method: str, params: dict) -> None:
        """A command whose reply nobody waits for (answers to paused requests)."""
        message_id = self._post(method, params, session=True)
        with self._lock:
            self._replies.pop(message_id, None)

    def add_listener(self, listener: Callable[[dict], None]) -> None:
        """Calls listener(message) on the reader thread for every event of the page."""
        self._listeners.append(listener)

    def _on_event(self, message: dict) -> None:
        method = message.get("method", "")
        params = message.get("params", {})
        if method == "Page.loadEventFired":
            self._load_fired.set()
        elif method == "Runtime.consoleAPICalled":
            text = " ".join(_remote_text(a) for a in params.get("args", []))
            self._console.append({"type": params.get("type", "log"), "text": text})
        elif method == "Runtime.exceptionThrown":
            details = params.get("exceptionDetails", {})
            exception = details.get("exception", {})
            text = exception.get("description") or details.get("text", "exception")
            self._console.append({"type": "exception", "text": text})
        elif method == "Log.entryAdded":
            entry = params.get("entry", {})
            self._console.append({"type": f"log.{entry.get('level', 'info')}",
                                  "text": entry.get("text", ""), "url": entry.get("url", "")})
        elif method == "Fetch.requestPaused":
            self._answer_paused(params)
        for listener in self._listeners:
            listener(message)

    # ---- page helpers -----------------------------------------------------------------------

    def navigate(self, url: str, timeout_s: float = 30.0) -> None:
        """Loads url and waits for its load event (not when only the #fragment changed: that
        loads nothing)."""
        self._load_fired.clear()
        result = self.send("Page.navigate", {"url": url}, timeout_s=timeout_s)
        if result.get("errorText"):
            raise CdpError(f"navigating to {url}: {result['errorText']}")
        if "loaderId" not in result:  # same-document navigation
            return
        if not self._load_fired.wait(timeout_s):
            raise CdpError(f"{url} did not finish loading within {timeout_s:.0f} s")

    def evaluate(self, expression: str, timeout_s: float = 30.0) -> Any:
        """The JSON value of a JavaScript expression in the page (promises are awaited);
        undefined gives None. An exception in the page raises CdpError."""
        result = self.send("Runtime.evaluate", {
            "expression": expression,
            "returnByValue": True,
            "awaitPromise": True,
        }, timeout_s=timeout_s)
        if "exceptionDetails" in result:
            details = result["exceptionDetails"]
            text = details.get("exception", {}).get("description") or details.get("text")
            raise CdpError(f"evaluating {expression!r}: {text}")
        return result.get("result", {}).get("value")

    def wait_for(self, expression: str, timeout_s: float = 30.0, interval_s: float = 0.1) -> Any:
        """Evaluates expression until it is truthy and returns that value; raises TimeoutError
        with the last value (or exception) seen when timeout_s passes."""
        deadline = time.monotonic() + timeout_s
        last: Any = None
        while True:
            try:
                last = self.evaluate(expression, timeout_s=max(1.0, timeout_s))
                if last:
                    return last
            except CdpError as e:  # e.g. the page is still loading the script that defines it
                last = e
            if time.monotonic() >= deadline:
                raise TimeoutError(f"{expression!r} not truthy after {timeout_s:.0f} s; "
                                   f"last value: {last!r}")
            time.sleep(interval_s)

    def screenshot(self, path: str) -> None:
        """Writes the page's viewport as a PNG."""
        data = self.send("Page.captureScreenshot", {"format": "png"}, timeout_s=60)["data"]
        with open(path, "wb") as f:
            f.write(base64.b64decode(data))

    def fail_requests(self, url_pattern: str, status: int = 500) -> None:
        """Answers every later request whose URL matches url_pattern (CDP's wildcards: * any
        characters, ? one; backslash escapes) with HTTP `status` and an error body in the API's
        JSON form. Patterns accumulate; failed_requests() lists the URLs answered so."""
        self._fail_status = status
        self._fail_patterns.append({"urlPattern": url_pattern, "requestStage": "Request"})
        self.send("Fetch.enable", {"patterns": self._fail_patterns})

    def clear_failures(self) -> None:
        """Stops failing requests."""
        self._fail_patterns = []
        self.send("Fetch.disable")

    def failed_requests(self) -> List[str]:
        return list(self._failed)

    def _answer_paused(self, params: dict) -> None:
        url = params.get("request", {}).get("url", "")
        self._failed.append(url)
        body = json.dumps({"error": {"code": self._fail_status,
                                     "message": "failed on purpose by the test (cdp.py)"}})
        self._send_async("Fetch.fulfillRequest", {
            "requestId": params["requestId"],
            "responseCode": self._fail_status,
            "responseHeaders": [{"name": "Content-Type", "value": "application/json"}],
            "body": base64.b64encode(body.encode()).decode(),
        })

    def console_messages(self) -> List[Dict[str, Any]]:
        """Console calls, uncaught exceptions and browser log entries so far, oldest first:
        dicts with "type" (log, warning, error, ..., exception, log.<level>) and "text"."""
        return list(self._console)


def _remote_text(obj: dict) -> str:
    """A console argument (a CDP RemoteObject) as text."""
    if "value" in obj:
        value = obj["value"]
        return value if isinstance(value, str) else json.dumps(value)
    return obj.get("description") or obj.get("unserializableValue") or obj.get("type", "")


def main() -> int:
    import argparse

    parser = argparse.ArgumentParser(description="Load a page in headless Chromium and print "
                                     "the JSON value of an expression.")
    parser.add_argument("url")
    parser.add_argument("--wait", default="true",
                        help="expression to wait for (default: none); its value is printed")
    parser.add_argument("--timeout", type=float, default=30.0)
    parser.add_argument("--screenshot", help="write a PNG here")
    parser.add_argument("--size", default="1280x800", help="window size, WxH")
    parser.add_argument("--console", action="store_true", help="print console messages too")
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.split("x"))
    with Browser(width, height) as browser:
        browser.navigate(args.url, args.timeout)
        value = browser.wait_for(args.wait, args.timeout)
        print(json.dumps(value, indent=2))
        if args.screenshot:
            browser.screenshot(args.screenshot)
        if args.console:
            for m in browser.console_messages():
                print(f"[{m['type']}] {m['text']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
