"""End to end, real time: ``--pin --busy-wait``, whose two spinning processes take both CPUs for the length of the
flight.  A module of its own, so that it runs with the other real-time lane waiting (``tests/conftest.py``,
``ALONE``).  Timing bounds are loose (a loaded 2-core machine); the strict targets are in ``python -m tools.bench
mavlink``."""

from __future__ import annotations

import os
import re

import pytest
from _mavlink_procs import load_json, run_cli

pytestmark = pytest.mark.e2e  # real processes over loopback UDP


def test_launch_realtime_busy_wait_pinned_serves_both_links(tmp_path):
    """--pin --busy-wait: the loop never sleeps, yet every attitude and setpoint is taken while it spins and
    the helper threads are moved off the control CPU."""
    out = tmp_path / "busy"
    r = run_cli(
        "tools.launch", "--duration", "3", "--rate", "100", "--pin", "--busy-wait", "--out", str(out), timeout=120
    )
    assert r.returncode == 0, r.stdout + r.stderr
    s = load_json(out / "summary.json")
    assert s["ok"] and s["runs"][0]["steps"] == 300
    assert s["timing"]["missed_deadlines"] <= 30  # loose: a loaded 2-core machine
    ap, gcs = s["counters"]["autopilot"], s["counters"]["gcs"]
    # ATTITUDE at about the 200 Hz sensor rate for 3 s (loose: the SITL shares CPU 0 with the GCS script), every
    # one of them read between steps; every setpoint sent was taken.
    sitl_sent = s["counters"]["sitl"]["tx_by_type"]["ATTITUDE"]
    assert sitl_sent >= 0.75 * 200 * 3
    # (the SITL goes on sending for a moment after the autopilot's last step, until the launcher stops it: 0.25 s)
    assert ap["sitl"]["rx_by_type"]["ATTITUDE"] >= sitl_sent - 0.25 * 200
    assert ap["sitl"]["tx_by_type"]["SERVO_OUTPUT_RAW"] == 300
    sent = gcs["tx_by_type"]["SET_ATTITUDE_TARGET"]
    assert sent > 50 and ap["gcs"]["rx_by_type"]["SET_ATTITUDE_TARGET"] >= sent - 2
    assert not ap["sitl"]["rejected"] and not ap["gcs"]["rejected"]
    start = (out / "autopilot.log").read_text()
    assert "busy-wait (never sleeps)" in start
    if (os.cpu_count() or 1) >= 2:
        assert re.search(r"[1-9]\d* helper thread\(s\) moved off CPU 1", start), start
