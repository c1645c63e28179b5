"""The web viewer in a real browser: headless Chromium (Debian's package) on a live ``--web`` flight and on its saved
``flight.rrd``.

How it checks that the recording is loaded and drawn, not the loading screen:

* Chromium runs headless with WebGL through SwiftShader and a remote-debugging port; ``tests/_browser.py`` drives
  one page over the DevTools protocol.  Real waits: the page is screenshotted every few seconds until the check
  below holds (up to ``LOAD_TIMEOUT_S``), never a virtual-time budget (that only captures the loading screen).
* The check reads the screenshot's pixels (1600x1000, the Flight tab) in the regions of the layout
  (``tools.view.views.flight_blueprint``): the roll-tracking plot must hold hundreds of pixels of the SITL's true-roll
  colour (``sitl.telemetry``: PURPLE) and the gains row those of the proportional gains (SKY,
  ``autopilot.telemetry.layout``), far more than a legend's dot; the 3D view must hold the aircraft (a purple
  shape on the background); the bottom row, the mode and failsafe lanes (GREEN: CLSAC and OK), must be on screen,
  so the tab fits the window.  The loading screen and an empty viewer have none of these.
* No console errors and no uncaught exceptions from the page.  The machine's network is closed, so what the viewer
  fetches from the internet (web fonts, its release check, analytics) is answered with an empty 204 by the DevTools
  client instead of failing; everything the viewer needs comes from the loopback server.

A recording made for it (true roll +25 deg, reference -20 deg) shows the attitude the right way: the slope of each
aircraft's wing on the screenshot is tan(roll) to within 0.12.

The live flight also shows live tuning: a ground station (pymavlink, 255:190 on a ``--gcs-peer`` port) sends one
accepted and one refused PARAM_SET; the saved recording holds both as event-log lines and as markers on the three
gain plots at the gains of that instant.  The screenshots are kept in the test's tmp folder.
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from autopilot.shared.telemetry.layout import ORANGE, PURPLE, SKY
from autopilot.telemetry import layout as L
from sitl import telemetry as S
from tests._browser import Browser, chromium_path, free_tcp_port, viewer_state
from tests._mavlink_procs import free_ports
from tools.flight.web import WebServer
from tools.view import rrd_files as rrd

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

pytestmark = [
    pytest.mark.e2e,
    pytest.mark.skipif(chromium_path() is None, reason="chromium is not installed (.ci/run: apt-get install chromium)"),
]
ROOT = Path(__file__).resolve().parents[3]
LOAD_TIMEOUT_S = 240.0  # SwiftShader on a loaded 2-core machine: the viewer draws in 20-60 s

# Regions of the 1600x1000 Flight tab, as fractions (x0, y0, x1, y1) of the screenshot.
ROLL_PLOT = (0.0, 0.08, 0.70, 0.30)
ATTITUDE_3D = (0.74, 0.08, 1.0, 0.32)
GAINS_ROW = (0.0, 0.50, 1.0, 0.66)
BOTTOM_ROW = (0.0, 0.82, 0.50, 0.98)
LINE_PIXELS = 250  # a drawn line holds hundreds of pixels of its colour; a legend's dot some tens


def _region(img: np.ndarray, box) -> np.ndarray:
    h, w = img.shape[:2]
    x0, y0, x1, y1 = box
    return img[int(y0 * h) : int(y1 * h), int(x0 * w) : int(x1 * w), :3].astype(int)


def colour_pixels(img: np.ndarray, box, rgb, tol: int = 12) -> int:
    """Pixels of ``box`` within ``tol`` of ``rgb`` on every channel."""
    return int(np.all(np.abs(_region(img, box) - np.array(rgb)) <= tol, axis=-1).sum())


def lane_pixels(img: np.ndarray, box) -> int:
    """Pixels of the GREEN family (the lanes draw it blended with the background): G well above R and B."""
    r = _region(img, box)
    return int(((r[..., 1] - r[..., 0] > 80) & (r[..., 1] - r[..., 2] > 20)).sum())


def aircraft_pixels(img: np.ndarray, box) -> int:
    """Pixels of the lit purple aircraft (R above G, B above G) in the 3D view."""
    r = _region(img, box)
    return int(((r[..., 0] - r[..., 1] > 30) & (r[..., 2] - r[..., 1] > 15)).sum())


def drawn(png: bytes) -> dict[str, int]:
    import io

    from PIL import Image

    img = np.array(Image.open(io.BytesIO(png)).convert("RGB"))
    return {
        "roll truth line": colour_pixels(img, ROLL_PLOT, PURPLE),
        "gains lines": colour_pixels(img, GAINS_ROW, SKY),
        "aircraft in 3D": aircraft_pixels(img, ATTITUDE_3D),
        "mode lanes": lane_pixels(img, BOTTOM_ROW),
    }


def plots_drawn(counts: dict[str, int]) -> bool:
    return (
        counts["roll truth line"] >= LINE_PIXELS
        and counts["gains lines"] >= LINE_PIXELS
        and counts["aircraft in 3D"] >= 100
        and counts["mode lanes"] >= 5000
    )


def viewer_lags(b: Browser, n: int = 5, every_s: float = 2.0) -> list[float]:
    """``n`` readings, ``every_s`` apart, of how old the newest sample the page's viewer holds is: the host clock
    minus the newest ``wall_time`` of the recording (every row carries its sample's host clock)."""
    lags = []
    for _ in range(n):
        b.pump(every_s)
        state = viewer_state(b)
        recs = [r for r in (state.recordings if state else []) if r.store_id.startswith("Recording:")]
        ends = [r.ranges["wall_time"][1] for r in recs if "wall_time" in r.ranges]
        if ends:
            lags.append(time.time() - max(ends) * 1e-9)
    return lags


def view_in_browser(url: str, shot: Path, lags: bool = False, holds=None) -> tuple:
    """Open ``url`` in headless Chromium, screenshot until the plots are drawn; (pixel counts, errors, internet,
    the viewer's lag behind the flight if ``lags``: ``viewer_lags`` once drawn, the viewer's state at the end: once
    ``holds(state)`` is true if given, for at most ``LOAD_TIMEOUT_S``)."""
    with Browser(1600, 1000) as b:
        b.open(url)
        state = {}

        def check():
            state["counts"] = drawn(b.screenshot(shot))
            return plots_drawn(state["counts"])

        b.wait_until(check, LOAD_TIMEOUT_S, poll_s=3.0)
        b.pump(3.0)  # a few more seconds of the live page: errors after drawing count too
        behind = viewer_lags(b) if lags else []
        if holds is not None:
            b.wait_until(lambda: holds(viewer_state(b)), LOAD_TIMEOUT_S, poll_s=2.0)
        return state["counts"], b.errors(), b.external, behind, viewer_state(b)


class _Gcs:
    """A ground station on the autopilot's --gcs-peer port (255:190), unsigned."""

    def __init__(self, port: int):
        self.conn = mavutil.mavlink_connection(
            f"udpin:127.0.0.1:{port}", source_system=255, source_component=190, dialect="all"
        )

    def wait(self, kind: str, timeout: float, cond=None):
        t_end = time.monotonic() + timeout
        while time.monotonic() < t_end:
            m = self.conn.recv_match(type=kind, blocking=True, timeout=0.2)
            if m is not None and m.get_srcSystem() == 1 and (cond is None or cond(m)):
                return m
        raise AssertionError(f"no {kind} from the vehicle within {timeout} s")

    def param_set(self, name: str, value: float, expect: float, timeout: float = 10.0):
        for _ in range(3):  # UDP: ask again if the answer was lost in a busy machine
            self.conn.mav.param_set_send(1, 1, name.encode(), value, mavutil.mavlink.MAV_PARAM_TYPE_REAL32)
            try:
                return self.wait("PARAM_VALUE", timeout / 3, lambda m: m.param_id == name and m.param_value == expect)
            except AssertionError:
                continue
        raise AssertionError(f"PARAM_SET {name}={value}: no PARAM_VALUE {expect}")


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    """A real-time ``--web`` flight watched in the browser while it flies, tuned live, then stopped with SIGINT."""
    tmp = tmp_path_factory.mktemp("live")
    out = tmp / "flight"
    http, grpc = free_tcp_port(), free_tcp_port()
    gcs_port = free_ports(1)[0]
    gcs = _Gcs(gcs_port)
    argv = [sys.executable, "-m", "tools.launch", "--duration", "600", "--quiet", "--out", str(out), "--no-png"]
    argv += ["--web", "--web-port", str(http), "--web-grpc-port", str(grpc)]
    argv += ["--no-signing", "--gcs-peer", f"127.0.0.1:{gcs_port}"]
    proc = subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(proc.stdout), daemon=True)
    reader.start()
    try:
        gcs.wait("HEARTBEAT", 60)
        gcs.conn.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        time.sleep(2.0)  # fly a little first: the markers then sit on adapted gains
        gcs.param_set("CLSAC_LV", 10.0, expect=10.0)  # accepted
        gcs.param_set("CLSAC_AM", 3.0, expect=-5.0)  # refused (outside its bounds: A_m < 0): the value stays -5
        url = WebServer("127.0.0.1", http, grpc).browser_url()
        counts, errors, external, lags, _ = view_in_browser(url, tmp / "live.png", lags=True)
        running = proc.poll() is None
        proc.send_signal(signal.SIGINT)
        proc.wait(120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        gcs.conn.close()
    reader.join(5)
    return {
        "out": out,
        "tmp": tmp,
        "counts": counts,
        "errors": errors,
        "external": external,
        "lags": lags,
        "running": running,
        "code": proc.returncode,
        "stdout": "".join(lines),
        "ports": (http, grpc),
    }


def test_live_web_flight_is_drawn_in_the_browser(live):
    assert live["running"], "the flight had ended before the browser drew it: not a live view"
    assert plots_drawn(live["counts"]), f"not drawn within {LOAD_TIMEOUT_S:g} s: {live['counts']} ({live['tmp']})"
    assert live["errors"] == [], live["errors"]
    assert live["code"] == 130, live["stdout"][-2000:]  # stopped with SIGINT after the look
    assert (live["out"] / "flight.rrd").is_file()


def test_the_live_viewer_keeps_up_with_the_flight(live):
    """The live viewer holds samples a few seconds old, not the 31-84 s of a viewer sent every row: it gets a
    thinned stream in 4 s batches (``--live-rate``; ``python -m tools.bench viewer`` measures both)."""
    lags = live["lags"]
    assert len(lags) >= 3, lags
    assert min(lags) < 15.0, lags


def test_saved_flight_rrd_is_drawn_in_the_browser(live, tmp_path):
    """``rerun --serve-web DIR/flight.rrd`` on loopback (the README's way to look at a flight after it)."""
    # the viewer's own account of what it holds (tools.bench._browser.decode_viewer_state): once it has read the
    # whole file, the sim_time range of the file's data
    data = rrd.load(live["out"] / "flight.rrd")
    span = (min(int(s.t_ns[0]) for s in data.values()), max(int(s.t_ns[-1]) for s in data.values()))

    def whole(state) -> bool:
        recs = [r for r in (state.recordings if state else []) if r.store_id.startswith("Recording:")]
        return len(recs) == 1 and recs[0].ranges.get("sim_time") == span

    with WebServer("127.0.0.1", free_tcp_port(), free_tcp_port(), source=live["out"] / "flight.rrd") as srv:
        counts, errors, _, _, state = view_in_browser(srv.browser_url(), tmp_path / "saved.png", holds=whole)
    assert plots_drawn(counts), f"not drawn within {LOAD_TIMEOUT_S:g} s: {counts} ({tmp_path})"
    assert errors == [], errors
    assert whole(state), (span, state)


def test_live_tuning_is_in_the_event_log_and_on_the_gain_plots(live):
    path = live["out"] / "flight.rrd"
    texts = [t for _, t in rrd.load_text(path, L.AP_EVENTS)]
    assert "PARAM_SET CLSAC_LV = 10: accepted" in texts
    assert "PARAM_SET CLSAC_AM = 3: refused" in texts
    assert any(t.startswith("CLSAC_AM=3 rejected: ") and "got 3" in t for t in texts), texts  # the reason, before
    data = rrd.load(path)
    for gain, marks in (
        (L.AP_GAIN_KE, L.AP_PARAM_SET_KE),
        (L.AP_GAIN_KX, L.AP_PARAM_SET_KX),
        (L.AP_GAIN_KU, L.AP_PARAM_SET_KU),
    ):
        m, g = data[marks], data[gain]
        assert m.names == ("PARAM_SET accepted", "PARAM_SET refused")
        assert len(m.t) == 2  # one accepted (first), one refused
        accepted, refused = m.values[0], m.values[1]
        assert np.isfinite(accepted[0]) and np.isnan(accepted[1])
        assert np.isnan(refused[0]) and np.isfinite(refused[1])
        # each marker sits on the gain's total (third series) at the step it followed: same instant, same value.
        # In real time two steps can share a sim time (no fresher ATTITUDE: 40 of 4976 rows in one CI flight), and
        # the gains adapt at each: the step it followed is the last row at that instant.
        for t_ns, v in ((m.t_ns[0], accepted[0]), (m.t_ns[1], refused[1])):
            i = np.searchsorted(g.t_ns, t_ns, side="right") - 1
            assert g.t_ns[i] == t_ns and g.values[i, 2] == v, (t_ns, g.values[g.t_ns == t_ns, 2], v)
    # the vehicle's own mode: CLSAC, and FAILSAFE only where the failsafe lane left OK (a loaded machine may
    # starve the real-time loop of attitudes for 100 ms)
    states = rrd.load_states(path)
    modes = [s for _, s in states[L.AP_MODE]]
    assert modes[0] == "CLSAC" and set(modes) <= {"CLSAC", "FAILSAFE"}, modes
    if "FAILSAFE" in modes:
        assert any(s != "OK" for _, s in states[L.AP_FAILSAFE])


def test_the_3d_aircraft_is_at_the_true_roll_and_the_ghost_at_the_reference(live):
    path = live["out"] / "flight.rrd"
    data, poses = rrd.load(path), rrd.load_poses(path)
    for entity, signal_path, column in ((S.SITL_ATTITUDE, S.SITL_ROLL, 0), (L.AP_REFERENCE_ATTITUDE, L.AP_ROLL, 1)):
        t, q = poses[entity]
        roll = data[signal_path]
        assert len(t) == len(roll.t) > 100
        phi = np.radians(roll.values[:, column])  # phi truth / ym, shown in degrees
        # a rotation by phi about the body x axis: q = (sin(phi/2), 0, 0, cos(phi/2)) (stored as float32)
        np.testing.assert_allclose(q[:, 0], np.sin(phi / 2), atol=2e-7)
        np.testing.assert_allclose(q[:, 3], np.cos(phi / 2), atol=2e-7)
        assert np.all(q[:, 1:3] == 0)
        assert np.max(np.abs(phi)) > math.radians(5)  # the aircraft did roll
    # both are drawn: the aircraft opaque (solid), the reference a translucent ghost of the ORANGE of ym
    from rerun.chunk import RrdReader

    r = RrdReader(str(path))
    colours = {}
    for chunk in r.stream(store=r.recordings()[0]):
        rb = chunk.to_record_batch()
        if "Boxes3D:colors" in rb.schema.names:
            colours[chunk.entity_path] = rb.column("Boxes3D:colors").flatten().to_pylist()[0]
    rgba = {k: ((c >> 24) & 255, (c >> 16) & 255, (c >> 8) & 255, c & 255) for k, c in colours.items()}
    assert rgba[S.SITL_ATTITUDE] == (*PURPLE, 255)
    assert rgba[L.AP_REFERENCE_ATTITUDE][:3] == ORANGE and rgba[L.AP_REFERENCE_ATTITUDE][3] < 255


def _wing_slope(mask: np.ndarray) -> float:
    """The slope dy/dx (image rows grow downwards) of the line through a shape's pixels: the wing dominates it."""
    ys, xs = np.nonzero(mask)
    assert len(xs) > 100, len(xs)
    return float(np.polyfit(xs, ys, 1)[0])


def test_the_browser_shows_the_aircraft_roll_the_right_way(tmp_path):
    """A recording with the true roll at +25 deg and the reference at -20 deg, drawn by the browser: the solid
    aircraft's right wing (screen right, seen from behind) is down, the ghost's left wing is down."""
    import io

    from PIL import Image

    from autopilot.shared import telemetry as tm
    from tools.view.views import flight_blueprint

    rid = tm.new_recording_id()
    parts = [tmp_path / "ap.rrd", tmp_path / "sitl.rrd"]
    with tm.Telemetry("autopilot", rid, parts[0]) as ta, tm.Telemetry("sitl", rid, parts[1]) as ts:
        ap, st = ta.table(L.AUTOPILOT), ts.table(S.SITL_TABLE)
        for k in range(50):
            row = [0.0] * len(L.AUTOPILOT_FIELDS)
            row[L.AUTOPILOT.index("ym")] = math.radians(-20.0)
            ap.append(k / 100, time.time(), tuple(row))
            srow = [0.0] * len(S.SITL_FIELDS)
            srow[S.SITL_TABLE.index("phi")] = math.radians(25.0)
            st.append(k / 100, time.time(), tuple(srow))
    path = tm.merge_recordings(parts, tmp_path / "flight.rrd", blueprint=flight_blueprint())
    with WebServer("127.0.0.1", free_tcp_port(), free_tcp_port(), source=path) as srv:
        with Browser(1600, 1000) as b:
            b.open(srv.browser_url())

            def both_drawn():
                img = np.array(Image.open(io.BytesIO(b.screenshot(tmp_path / "roll.png"))).convert("RGB"))
                r = _region(img, ATTITUDE_3D)
                solid = (r[..., 0] - r[..., 1] > 30) & (r[..., 2] - r[..., 1] > 15)  # lit PURPLE
                ghost = (r[..., 0] - r[..., 2] > 50) & (r[..., 1] - r[..., 2] > 20)  # translucent ORANGE
                if solid.sum() <= 300 or ghost.sum() <= 300:
                    return None
                # Both drawn, and both banked: the static shapes can be drawn level a frame before their poses
                # arrive (one .ci/run in four measured the ghost's slope at 0.006). A viewer that never banks them
                # times out; one that banks them the wrong way fails the slopes below.
                banked = min(abs(_wing_slope(solid)), abs(_wing_slope(ghost))) > 0.1
                return (solid, ghost) if banked else None

            shapes = b.wait_until(both_drawn, LOAD_TIMEOUT_S, poll_s=3.0)
            errors = b.errors()
    assert shapes is not None, f"the aircraft and its ghost were not drawn ({tmp_path / 'roll.png'})"
    solid, ghost = shapes
    # Seen from behind, the wing's slope on screen is about tan(roll) (rows grow downwards: right wing down is
    # positive); measured 0.45 for tan(25 deg) = 0.47 and -0.35 for tan(-20 deg) = -0.36 (a little perspective).
    assert _wing_slope(solid) == pytest.approx(math.tan(math.radians(25.0)), abs=0.12)
    assert _wing_slope(ghost) == pytest.approx(math.tan(math.radians(-20.0)), abs=0.12)
    assert errors == [], errors


def test_nothing_listens_after_the_live_flight(live):
    from tests.tools.flight.test_web import listeners

    http, grpc = live["ports"]
    assert listeners(http) == set() and listeners(grpc) == set()
