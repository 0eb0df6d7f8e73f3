"""Firefox (Debian's ``firefox-esr``) driven through its own WebDriver BiDi for the lab page's
tests: a session over one websocket, the page in one browsing context, the profile's
preferences that keep it on loopback, and the process helpers."""

from __future__ import annotations

import base64
import json
import os
import queue
import shutil
import signal
import subprocess
import threading
import time
from pathlib import Path
from typing import Any

FIREFOX = shutil.which("firefox-esr") or shutil.which("firefox")

__all__ = [
    "FIREFOX",
    "PREFS",
    "Bidi",
    "BidiError",
    "Page",
    "launch_firefox",
    "lines_of",
    "stop",
    "wait_line",
]

#: The profile: the remote agent's recommended preferences already turn most background
#: services off; these send whatever would still leave to a closed port on loopback.
PREFS = {
    "network.proxy.type": 1,
    "network.proxy.http": "127.0.0.1",
    "network.proxy.http_port": 9,
    "network.proxy.ssl": "127.0.0.1",
    "network.proxy.ssl_port": 9,
    "network.proxy.no_proxies_on": "127.0.0.1",
    "network.proxy.allow_hijacking_localhost": False,
    "network.trr.mode": 5,
    "network.dns.disablePrefetch": True,
    "network.prefetch-next": False,
    "network.captive-portal-service.enabled": False,
    "network.connectivity-service.enabled": False,
    "browser.safebrowsing.malware.enabled": False,
    "browser.safebrowsing.phishing.enabled": False,
    "browser.safebrowsing.downloads.enabled": False,
    "datareporting.policy.dataSubmissionEnabled": False,
    "toolkit.telemetry.enabled": False,
    "app.update.enabled": False,
    "extensions.update.enabled": False,
    "browser.shell.checkDefaultBrowser": False,
}


class BidiError(RuntimeError):
    pass


class Bidi:
    """A WebDriver BiDi session over one websocket: :meth:`call` sends a command and returns its
    result; events that arrive meanwhile go to ``on_event``."""

    def __init__(self, ws: Any, on_event: Any) -> None:
        self.ws = ws
        self.on_event = on_event
        self.last_id = 0

    def call(self, method: str, params: dict[str, Any], timeout_s: float = 60) -> Any:
        self.last_id += 1
        cid = self.last_id
        self.ws.send(json.dumps({"id": cid, "method": method, "params": params}))
        deadline = time.monotonic() + timeout_s
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise BidiError(f"{method}: no answer in {timeout_s} s")
            msg = json.loads(self.ws.recv(timeout=left))
            if msg.get("type") == "event":
                self.on_event(msg["method"], msg["params"])
            elif msg.get("id") == cid:
                if msg.get("type") == "error":
                    raise BidiError(f"{method}: {msg.get('error')}: {msg.get('message')}")
                return msg["result"]


class Page:
    """The page in one browsing context: JavaScript in, JSON out."""

    def __init__(self, bidi: Bidi, context: str) -> None:
        self.bidi = bidi
        self.context = context

    def js(self, expr: str) -> Any:
        """The JSON value of ``expr`` (awaited when it is a promise)."""
        out = self.bidi.call(
            "script.evaluate",
            {
                "expression": f"(async () => JSON.stringify(await ({expr})))()",
                "target": {"context": self.context},
                "awaitPromise": True,
                "resultOwnership": "none",
            },
        )
        if out["type"] == "exception":
            raise BidiError(f"{expr[:120]}: {out['exceptionDetails'].get('text')}")
        value = out["result"].get("value")
        return None if value is None else json.loads(value)

    def element(self, selector: str) -> dict[str, str]:
        out = self.bidi.call(
            "script.evaluate",
            {
                "expression": f"document.querySelector({json.dumps(selector)})",
                "target": {"context": self.context},
                "awaitPromise": False,
                "resultOwnership": "root",
            },
        )
        assert out["type"] == "success" and "sharedId" in out["result"], (selector, out)
        return {"sharedId": out["result"]["sharedId"]}

    def wait(self, cond: str, timeout_s: float = 30, what: str = "") -> None:
        deadline = time.monotonic() + timeout_s
        while not self.js(cond):
            if time.monotonic() > deadline:
                msg = self.js("document.querySelector('#msg').textContent")
                raise AssertionError(
                    f"{what or cond}: not within {timeout_s} s (page says {msg!r})"
                )
            time.sleep(0.1)

    def click(self, selector: str) -> None:
        self.js(f"document.querySelector({json.dumps(selector)}).click()")

    def drag(self, points: list[tuple[float, float]]) -> None:
        """A mouse drag through ``points`` (viewport CSS pixels)."""
        x0, y0 = points[0]
        actions: list[dict[str, Any]] = [
            {"type": "pointerMove", "x": round(x0), "y": round(y0), "duration": 0},
            {"type": "pointerDown", "button": 0},
        ]
        actions += [
            {"type": "pointerMove", "x": round(x), "y": round(y), "duration": 40}
            for x, y in points[1:]
        ]
        actions.append({"type": "pointerUp", "button": 0})
        self.bidi.call(
            "input.performActions",
            {
                "context": self.context,
                "actions": [
                    {
                        "type": "pointer",
                        "id": "mouse",
                        "parameters": {"pointerType": "mouse"},
                        "actions": actions,
                    }
                ],
            },
        )

    def shot(self, path: Path) -> None:
        out = self.bidi.call("browsingContext.captureScreenshot", {"context": self.context})
        path.write_bytes(base64.b64decode(out["data"]))


def lines_of(proc: subprocess.Popen[str]) -> queue.Queue[str]:
    lines: queue.Queue[str] = queue.Queue()
    out = proc.stdout
    assert out is not None
    threading.Thread(target=lambda: [lines.put(x) for x in out], daemon=True).start()
    return lines


def wait_line(proc: subprocess.Popen[str], lines: queue.Queue[str], start: str, what: str) -> str:
    deadline = time.monotonic() + 90
    seen: list[str] = []
    while True:
        try:
            line = lines.get(timeout=0.2)
            seen.append(line)
            if line.startswith(start):
                return line
        except queue.Empty:
            if proc.poll() is not None or time.monotonic() > deadline:
                raise AssertionError(f"{what} did not start: {''.join(seen)[-2000:]}") from None


def stop(proc: subprocess.Popen[str]) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def launch_firefox(tmp_path: Path, port: int) -> subprocess.Popen[str]:
    """Headless Firefox with the test profile (:data:`PREFS`) in ``tmp_path``, its WebDriver
    BiDi on ``port``; wait for "WebDriver BiDi listening on" before connecting."""
    assert FIREFOX is not None
    profile = tmp_path / "firefox-profile"
    profile.mkdir()
    (profile / "user.js").write_text(
        "".join(f"user_pref({json.dumps(k)}, {json.dumps(v)});\n" for k, v in PREFS.items())
    )
    return subprocess.Popen(
        [FIREFOX, "--headless", "--no-remote", "--profile", str(profile)]
        + ["--remote-debugging-port", str(port), "about:blank"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        env={**os.environ, "MOZ_CRASHREPORTER_DISABLE": "1", "HOME": str(tmp_path)},
        text=True,
    )
