"""Render a local HTML file in headless Chromium and report what a reader would see.

Drives Debian's ``chromium`` over the Chrome DevTools protocol (a websocket; the
``websockets`` package comes with ``uvicorn[standard]``): loads the page, waits for its
load event, reads every image's natural size, collects console errors and uncaught
exceptions, and takes a full-page screenshot and a PDF print. The browser runs with
background networking disabled and a private profile, so nothing but the page is loaded.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import tempfile
import time
import urllib.request
from base64 import b64decode
from dataclasses import dataclass
from pathlib import Path

from websockets.sync.client import connect

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
MISSING = ("headless Chromium is not installed: `apt-get install -y chromium` (Debian) "
           "to run the report rendering tests")
_FLAGS = ("--headless", "--disable-gpu", "--disable-background-networking",
          "--disable-component-update", "--disable-default-apps", "--disable-extensions",
          "--disable-sync", "--no-first-run", "--no-default-browser-check",
          "--metrics-recording-only", "--mute-audio", "--hide-scrollbars",
          "--remote-debugging-port=0", "--window-size=1200,900")
_TIMEOUT = 60.0


@dataclass(frozen=True)
class Rendering:
    """What Chromium made of a page.

    Attributes
    ----------
    images : list of dict
        ``alt``, ``complete`` and ``naturalWidth`` of every ``<img>`` after the load event.
    errors : list of str
        Console errors, uncaught exceptions and failed loads logged by the browser.
    screenshot : bytes
        Full-page PNG screenshot.
    pdf : bytes
        The page printed to PDF (A4, as a reader printing it would get).
    """

    images: list[dict]
    errors: list[str]
    screenshot: bytes
    pdf: bytes


def render(page: Path) -> Rendering:
    """Load ``page`` (a local file) in a fresh headless Chromium and inspect it."""
    # Chromium's helper processes can still be writing to the profile when the browser
    # has exited (a CI run failed removing it: "Directory not empty"), so the browser
    # runs in a process group of its own that is ended as a whole, and what a helper
    # still writes does not fail the test.
    with tempfile.TemporaryDirectory(prefix="chromium-", ignore_cleanup_errors=True) as profile:
        sandbox = ("--no-sandbox",) if os.geteuid() == 0 else ()  # root cannot sandbox
        process = subprocess.Popen([CHROMIUM, *_FLAGS, *sandbox, f"--user-data-dir={profile}",
                                    "about:blank"], stdout=subprocess.DEVNULL,
                                   stderr=subprocess.DEVNULL, start_new_session=True)
        try:
            return _inspect(_page_socket(Path(profile)), page)
        finally:
            os.killpg(process.pid, signal.SIGTERM)
            process.wait(timeout=30)


def _page_socket(profile: Path) -> str:
    """The websocket URL of the browser's blank page, once its DevTools port is up."""
    port_file = profile / "DevToolsActivePort"
    deadline = time.monotonic() + _TIMEOUT
    while time.monotonic() < deadline:
        if port_file.is_file() and port_file.read_text().strip():
            port = port_file.read_text().split()[0]
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=10) as r:
                targets = [t for t in json.load(r) if t["type"] == "page"]
            if targets:
                return targets[0]["webSocketDebuggerUrl"]
        time.sleep(0.1)
    raise TimeoutError(f"Chromium did not open its DevTools port within {_TIMEOUT} s")


class _Session:
    """Commands and events over one DevTools websocket."""

    def __init__(self, socket) -> None:
        self.socket, self.next_id, self.events = socket, 0, []

    def call(self, method: str, **params) -> dict:
        self.next_id += 1
        self.socket.send(json.dumps({"id": self.next_id, "method": method, "params": params}))
        while True:
            message = json.loads(self.socket.recv(timeout=_TIMEOUT))
            if message.get("id") == self.next_id:
                if "error" in message:
                    raise RuntimeError(f"{method}: {message['error']}")
                return message["result"]
            self.events.append(message)

    def wait_for(self, method: str) -> None:
        while not any(e.get("method") == method for e in self.events):
            self.events.append(json.loads(self.socket.recv(timeout=_TIMEOUT)))


def _inspect(url: str, page: Path) -> Rendering:
    with connect(url, max_size=None, open_timeout=_TIMEOUT) as socket:
        session = _Session(socket)
        for domain in ("Page", "Runtime", "Log"):
            session.call(f"{domain}.enable")
        navigation = session.call("Page.navigate", url=page.resolve().as_uri())
        if "errorText" in navigation:   # the page itself did not load: no page to inspect
            raise RuntimeError(f"Chromium could not load {page}: {navigation['errorText']}")
        session.wait_for("Page.loadEventFired")
        images = session.call("Runtime.evaluate", returnByValue=True, expression=(
            "Array.from(document.images).map(i => ({alt: i.alt, complete: i.complete, "
            "naturalWidth: i.naturalWidth}))"))["result"]["value"]
        shot = session.call("Page.captureScreenshot", format="png", captureBeyondViewport=True)
        pdf = session.call("Page.printToPDF", paperWidth=8.27, paperHeight=11.69)
        return Rendering(images, _errors(session.events), b64decode(shot["data"]),
                         b64decode(pdf["data"]))


def _errors(events: list[dict]) -> list[str]:
    """Console errors, exceptions and browser log errors among the DevTools events."""
    found = []
    for event in events:
        method, params = event.get("method"), event.get("params", {})
        if method == "Runtime.consoleAPICalled" and params["type"] in ("error", "assert"):
            found.append(" ".join(str(a.get("value", a.get("description", "")))
                                  for a in params["args"]))
        elif method == "Runtime.exceptionThrown":
            found.append(params["exceptionDetails"].get("text", "exception"))
        elif method == "Log.entryAdded" and params["entry"]["level"] == "error":
            found.append(params["entry"]["text"])
    return found
