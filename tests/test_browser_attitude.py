"""The attitude the right way round in a real browser: a recording made for it (true roll +25 deg, reference -20 deg),
drawn by headless Chromium from ``rerun --serve-web`` (tests/_browser.py, the checks of test_browser_viewer.py).

No flight flies while it draws, so it runs in the parallel phase (tests/conftest.py); the live flight and its saved
recording are drawn in test_browser_viewer.py, which runs alone.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from _browser import Browser, chromium_path, free_tcp_port
from test_browser_viewer import ATTITUDE_3D, LOAD_TIMEOUT_S, _region

from autopilot.telemetry import layout as L
from sitl import telemetry as S
from tools.web import WebServer

pytestmark = [
    pytest.mark.e2e,
    pytest.mark.skipif(chromium_path() is None, reason="chromium is not installed (.ci/run: apt-get install chromium)"),
]


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
    from tools.views import flight_blueprint

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
                return (solid, ghost) if solid.sum() > 300 and ghost.sum() > 300 else None

            shapes = b.wait_until(both_drawn, LOAD_TIMEOUT_S, poll_s=3.0)
            errors = b.errors()
    assert shapes is not None, f"the aircraft and its ghost were not drawn ({tmp_path / 'roll.png'})"
    solid, ghost = shapes
    # Seen from behind, the wing's slope on screen is about tan(roll) (rows grow downwards: right wing down is
    # positive); measured 0.45 for tan(25 deg) = 0.47 and -0.35 for tan(-20 deg) = -0.36 (a little perspective).
    assert _wing_slope(solid) == pytest.approx(math.tan(math.radians(25.0)), abs=0.12)
    assert _wing_slope(ghost) == pytest.approx(math.tan(math.radians(-20.0)), abs=0.12)
    assert errors == [], errors
