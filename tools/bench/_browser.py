"""Headless Chromium driven over the DevTools protocol (CDP), for the web-viewer tests and the viewer bench.

``Browser`` starts ``/usr/bin/chromium`` (Debian's package, installed by ``.ci/run``) with a fresh profile, a remote
debugging port on loopback and SwiftShader for WebGL, and talks to one page over its websocket
(``websocket-client``, the dev extra).  Real waits: the page is polled until a condition holds (``wait_until``), not
given a virtual-time budget (which captures only the viewer's loading screen).  Console messages and uncaught
exceptions are collected from the CDP events ``Runtime.consoleAPICalled``, ``Runtime.exceptionThrown`` and
``Log.entryAdded``.

``viewer_state(browser)`` reads what the Rerun web viewer of the page holds: its ``GetViewerStateResponse`` (the
Viewer Control API of rerun 0.41, ``window._handle.viewer_state()``), decoded here (``decode_viewer_state``) into
each recording's timelines with their time ranges, the time cursor, and what is still loading.
"""

from __future__ import annotations

import base64
import json
import os
import shutil
import socket
import subprocess
import tempfile
import time
import urllib.request
from dataclasses import dataclass, field
from pathlib import Path

CHROMIUM = "/usr/bin/chromium"
# An intercepted internet request's answer may be read by the page (cross-origin): allow it, preflights included.
_CORS = [
    {"name": "Access-Control-Allow-Origin", "value": "*"},
    {"name": "Access-Control-Allow-Headers", "value": "*"},
    {"name": "Access-Control-Allow-Methods", "value": "GET, POST, OPTIONS"},
]


class BrowserError(RuntimeError):
    """Chromium did not start, its DevTools endpoint did not answer, or a CDP command failed."""


def chromium_path() -> str | None:
    """The Chromium executable, or None if it is not installed."""
    return CHROMIUM if os.access(CHROMIUM, os.X_OK) else shutil.which("chromium")


def free_tcp_port(host: str = "127.0.0.1") -> int:
    with socket.socket() as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def chromium_argv(exe: str, profile: Path, port: int, width: int, height: int) -> list[str]:
    """Headless, no network of its own (the machine's is closed), WebGL through SwiftShader, root-safe."""
    return [
        exe,
        "--headless=new",
        f"--remote-debugging-port={port}",
        "--remote-debugging-address=127.0.0.1",
        f"--user-data-dir={profile}",
        f"--window-size={width},{height}",
        "--no-sandbox",  # CI runs as root
        "--use-angle=swiftshader",
        "--enable-unsafe-swiftshader",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--disable-quic",
        "--no-first-run",
        "--no-default-browser-check",
        "--disable-dev-shm-usage",
        "about:blank",
    ]


class Browser:
    """One headless Chromium with one page; ``close()`` ends it (and its process group)."""

    def __init__(self, width: int = 1600, height: int = 1000, start_timeout_s: float = 30.0):
        import websocket  # websocket-client

        exe = chromium_path()
        if exe is None:
            raise BrowserError("chromium is not installed (apt-get install -y chromium)")
        self.width, self.height = width, height
        self._profile = Path(tempfile.mkdtemp(prefix="cdp-profile-"))
        self.port = free_tcp_port()
        self._log = open(self._profile.parent / f"{self._profile.name}.log", "w")
        self.proc = subprocess.Popen(
            chromium_argv(exe, self._profile, self.port, width, height),
            stdin=subprocess.DEVNULL,
            stdout=self._log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        self.console: list[dict] = []  # {"level", "text"} of every console message and exception
        self.external: list[str] = []  # internet URLs the page asked for (answered 204, the network is closed)
        self._id = 0
        self._loaded = False
        try:
            ws_url = self._page_websocket(start_timeout_s)
            self.ws = websocket.create_connection(ws_url, timeout=60, suppress_origin=True)
            for method in ("Page.enable", "Runtime.enable", "Log.enable"):
                self.call(method)
            # The machine's network is closed: what the viewer fetches from the internet (web fonts, its release
            # check, its analytics) is answered here with an empty 204 instead of failing with console errors.
            self.call("Fetch.enable", {"patterns": [{"urlPattern": "https://*"}]})
            self.call(
                "Emulation.setDeviceMetricsOverride",
                {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False},
            )
        except BaseException:
            self.close()
            raise

    def _page_websocket(self, timeout_s: float) -> str:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                self._log.flush()
                tail = Path(self._log.name).read_text(errors="replace").strip().splitlines()[-1:]
                raise BrowserError(
                    f"chromium exited with code {self.proc.returncode} at start-up" + (f": {tail[0]}" if tail else "")
                )
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{self.port}/json/list", timeout=2) as r:
                    pages = [t for t in json.load(r) if t.get("type") == "page"]
                if pages:
                    return pages[0]["webSocketDebuggerUrl"]
            except OSError:
                pass
            time.sleep(0.2)
        raise BrowserError(f"chromium's DevTools endpoint on port {self.port} did not answer in {timeout_s:g} s")

    # ------------------------------------------------------------------ protocol
    def call(self, method: str, params: dict | None = None, timeout_s: float = 60.0) -> dict:
        """Send one CDP command and return its result; events that arrive meanwhile are recorded."""
        self._id += 1
        my_id = self._id
        self.ws.send(json.dumps({"id": my_id, "method": method, "params": params or {}}))
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            msg = json.loads(self.ws.recv())
            if msg.get("id") == my_id:
                if "error" in msg:
                    raise BrowserError(f"{method}: {msg['error']}")
                return msg.get("result", {})
            self._record(msg)
        raise BrowserError(f"{method}: no answer in {timeout_s:g} s")

    def _send(self, method: str, params: dict) -> None:
        """A command whose answer nobody waits for (``call`` skips answers that are not its own)."""
        self._id += 1
        self.ws.send(json.dumps({"id": self._id, "method": method, "params": params}))

    def _record(self, msg: dict) -> None:
        method, p = msg.get("method"), msg.get("params", {})
        if method == "Page.loadEventFired":
            self._loaded = True
        elif method == "Fetch.requestPaused":  # an internet request (the only ones intercepted)
            self.external.append(p.get("request", {}).get("url", ""))
            self._send(
                "Fetch.fulfillRequest", {"requestId": p["requestId"], "responseCode": 204, "responseHeaders": _CORS}
            )
        elif method == "Runtime.consoleAPICalled":
            text = " ".join(str(a.get("value", a.get("description", ""))) for a in p.get("args", []))
            self.console.append({"level": p.get("type", "log"), "text": text})
        elif method == "Runtime.exceptionThrown":
            d = p.get("exceptionDetails", {})
            text = d.get("exception", {}).get("description") or d.get("text", "")
            self.console.append({"level": "exception", "text": text})
        elif method == "Log.entryAdded":
            e = p.get("entry", {})
            self.console.append({"level": e.get("level", "info"), "text": f"{e.get('url', '')} {e.get('text', '')}"})

    def errors(self) -> list[str]:
        """Console errors and uncaught exceptions seen so far."""
        return [m["text"] for m in self.console if m["level"] in ("error", "exception")]

    # ------------------------------------------------------------------ page
    def open(self, url: str, timeout_s: float = 120.0) -> None:
        """Navigate and wait for the page's load event (the viewer's wasm then starts; drawing comes later)."""
        self._loaded = False
        self.call("Page.navigate", {"url": url})
        deadline = time.monotonic() + timeout_s
        while not self._loaded:
            if time.monotonic() > deadline:
                raise BrowserError(f"{url}: no load event within {timeout_s:g} s")
            self.pump(0.5)

    def evaluate(self, expression: str):
        r = self.call("Runtime.evaluate", {"expression": expression, "returnByValue": True})
        return r.get("result", {}).get("value")

    def screenshot(self, path: Path | None = None) -> bytes:
        """A PNG of the page (the whole 1600x1000 viewport)."""
        # a software-rendered frame of the whole viewer: a minute or more on a loaded 2-core machine
        self.no_higher_priority()
        data = base64.b64decode(self.call("Page.captureScreenshot", {"format": "png"}, timeout_s=300)["data"])
        if path is not None:
            Path(path).write_bytes(data)
        return data

    def no_higher_priority(self) -> None:
        """Chromium, run as root, raises the priority of its browser and GPU threads (nice -8): SwiftShader's software
        rendering then took the CPU from the suite's real-time flights on other workers.  Every thread of its process
        group goes back to this process's nice value (raising a nice value needs no privilege); threads it starts
        later are caught on the next call (``pump`` and ``screenshot`` call this)."""
        own = os.getpriority(os.PRIO_PROCESS, 0)
        for proc in Path("/proc").iterdir():
            if not proc.name.isdigit():
                continue
            try:
                if os.getpgid(int(proc.name)) != self.proc.pid:
                    continue
                for task in (proc / "task").iterdir():
                    tid = int(task.name)
                    if os.getpriority(os.PRIO_PROCESS, tid) < own:
                        os.setpriority(os.PRIO_PROCESS, tid, own)
            except (OSError, ValueError):  # gone meanwhile
                continue

    def pump(self, seconds: float) -> None:
        """Let the page run for ``seconds`` of real time while recording its console events."""
        self.no_higher_priority()
        deadline = time.monotonic() + seconds
        self.ws.settimeout(0.2)
        try:
            while time.monotonic() < deadline:
                try:
                    self._record(json.loads(self.ws.recv()))
                except Exception as exc:  # noqa: BLE001 - websocket-client's timeout type varies by version
                    if "timed out" not in str(exc).lower():
                        raise
        finally:
            self.ws.settimeout(60)

    def wait_until(self, check, timeout_s: float, poll_s: float = 2.0):
        """Poll ``check()`` (e.g. a screenshot test) every ``poll_s`` real seconds until it returns a true value."""
        deadline = time.monotonic() + timeout_s
        while True:
            value = check()
            if value or time.monotonic() >= deadline:
                return value
            self.pump(poll_s)

    def close(self) -> None:
        try:
            if getattr(self, "ws", None) is not None:
                self.ws.close()
        finally:
            if self.proc.poll() is None:
                try:
                    os.killpg(self.proc.pid, 15)
                except ProcessLookupError:
                    pass
                try:
                    self.proc.wait(10)
                except subprocess.TimeoutExpired:
                    os.killpg(self.proc.pid, 9)
                    self.proc.wait()
            self._log.close()
            Path(self._log.name).unlink(missing_ok=True)  # Chromium's output, beside the profile: gone with it
            shutil.rmtree(self._profile, ignore_errors=True)

    def __enter__(self) -> Browser:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# ------------------------------------------------------------------ the viewer's state
# The Viewer Control API's GetViewerStateResponse (rerun's ``viewer_control.proto``, rerun-sdk 0.41): the field
# numbers of the messages read here.  A protobuf message is a run of (key = field << 3 | wire type, value) pairs.
_STATE_RECORDINGS, _STATE_LOADING = 3, 7  # GetViewerStateResponse
_REC_STORE_ID, _REC_TIMELINES, _REC_CURSOR = 1, 2, 3  # ViewerRecording
_TL_TIMELINE, _TL_RANGE = 1, 3  # ViewerTimeline: Timeline {1: name}, TimeRange {1: start, 2: end}
_CURSOR_TIMELINE, _CURSOR_TIME = 1, 3  # TimeCursor: Timeline {1: name}, TimelineTime {1: time}


@dataclass
class ViewerRecording:
    """One recording the viewer holds: {timeline: (first, last) time value} (ns for ``sim_time`` and
    ``wall_time``), and the time cursor (timeline, value) if set."""

    store_id: str
    ranges: dict[str, tuple[int, int]] = field(default_factory=dict)
    cursor: tuple[str, int | None] | None = None


@dataclass
class ViewerState:
    recordings: list[ViewerRecording]
    loading: list[str]  # sources the viewer is still loading from (files, not a live proxy)

    def recording(self, recording_id: str) -> ViewerRecording | None:
        return next((r for r in self.recordings if r.store_id.endswith(f":{recording_id}")), None)


def _varint(b: bytes, i: int) -> tuple[int, int]:
    x = shift = 0
    while True:
        c = b[i]
        i += 1
        x |= (c & 0x7F) << shift
        shift += 7
        if c < 0x80:
            return x, i


def _fields(b: bytes) -> list[tuple[int, int | bytes]]:
    """(field number, value) of one message: an int for a varint, bytes for a length-delimited value."""
    out: list[tuple[int, int | bytes]] = []
    i = 0
    while i < len(b):
        key, i = _varint(b, i)
        number, wire = key >> 3, key & 7
        if wire == 0:
            value, i = _varint(b, i)
        elif wire == 2:
            n, i = _varint(b, i)
            value, i = bytes(b[i : i + n]), i + n
        elif wire in (1, 5):
            width = 8 if wire == 1 else 4
            value, i = bytes(b[i : i + width]), i + width
        else:
            raise ValueError(f"protobuf wire type {wire} of field {number} is not read here")
        out.append((number, value))
    return out


def _int64(v: int) -> int:
    return v - (1 << 64) if v >= 1 << 63 else v


def _get(b: bytes, number: int, default=None):
    return next((v for n, v in _fields(b) if n == number), default)


def _name(timeline: bytes) -> str:
    return _get(timeline, 1, b"").decode()


def decode_viewer_state(data: bytes) -> ViewerState:
    """A ``GetViewerStateResponse`` (protobuf bytes) as a ``ViewerState``."""
    recordings, loading = [], []
    for number, value in _fields(data):
        if number == _STATE_LOADING:
            loading.append(_get(value, 1, b"").decode())
        if number != _STATE_RECORDINGS:
            continue
        rec = ViewerRecording(store_id="")
        for n, v in _fields(value):
            if n == _REC_STORE_ID:
                rec.store_id = v.decode()
            elif n == _REC_TIMELINES:
                name, rng = _name(_get(v, _TL_TIMELINE, b"")), _get(v, _TL_RANGE)
                if rng is not None:  # absent: no data on it yet
                    rec.ranges[name] = (_int64(_get(rng, 1, 0)), _int64(_get(rng, 2, 0)))
            elif n == _REC_CURSOR:
                when = _get(v, _CURSOR_TIME)
                rec.cursor = (_name(_get(v, _CURSOR_TIMELINE, b"")), None if when is None else _int64(_get(when, 1, 0)))
        recordings.append(rec)
    return ViewerState(recordings, loading)


def viewer_state(browser: Browser) -> ViewerState | None:
    """What the page's Rerun web viewer holds now, or None before the viewer has started."""
    raw = browser.evaluate("window._handle ? Array.from(window._handle.viewer_state()) : null")
    return None if raw is None else decode_viewer_state(bytes(raw))
