"""Viewer benchmark: how far the live web viewer lags behind a real-time flight, with and without the live stream's
thinning (``--live-rate``, ``--live-window``).

    python -m tools.bench viewer [--seconds 90] [--poll 2] [--only NAME] [--json]
    python -m tools.bench.viewer ...          (same, without the dispatcher)

Each configuration flies one real-time ``--web`` flight (``python -m tools.launch``, a subprocess) watched by
headless Chromium (``/usr/bin/chromium``, WebGL through SwiftShader: software rendering, the case of the issue) on
the launcher's page.  Every ``--poll`` seconds the bench reads the viewer's own state
(``tools.bench._browser.viewer_state``: the Viewer Control API's ``GetViewerStateResponse``) and takes the lag as
the host clock now minus the newest ``wall_time`` the viewer holds (every row carries the host clock of its sample:
this is how old the newest sample the viewer has is).  Readings before the viewer holds any of the flight do not
count.  Figures per configuration: the median and p90 of the lag, and the newest ``sim_time`` the viewer held.

The configurations, flown in turn in one run: ``every-row`` (``--rrd-live --live-rate 0 --live-window 0``: the
processes write their parts with rerun and stream every row to the viewer, as before the thinning) and ``thinned``
(the defaults: the viewer's own stream, ``--live-rate`` rows per sim second of each plot, the plots over the last
``--live-window`` s).
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from autopilot.shared.process import standard_json

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = {"every-row": ["--rrd-live", "--live-rate", "0", "--live-window", "0"], "thinned": []}
TARGET_LAG_S = 5.0  # the thinned stream's median lag


def _wait_port(port: int, proc: subprocess.Popen, timeout_s: float) -> None:
    import socket

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"the launcher exited ({proc.returncode}) before its web viewer answered")
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.3):
                return
        except OSError:
            time.sleep(0.2)
    raise RuntimeError(f"the web viewer did not answer on port {port} within {timeout_s:g} s")


def measure(seconds: float, flags: list[str], poll_s: float, workdir: Path) -> dict:
    """One real-time ``--web`` flight of ``seconds`` with ``flags``, watched by headless Chromium: the lag samples."""
    from tools.bench._browser import Browser, free_tcp_port, viewer_state
    from tools.flight.web import WebServer

    http, grpc = free_tcp_port(), free_tcp_port()
    out = workdir / f"flight-{http}"
    argv = [sys.executable, "-m", "tools.launch", "--duration", f"{seconds:g}", "--quiet", "--no-png"]
    argv += ["--out", str(out), "--web", "--web-port", str(http), "--web-grpc-port", str(grpc), *flags]
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen(argv, cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    samples: list[dict] = []
    try:
        _wait_port(http, proc, 60.0)
        url = WebServer("127.0.0.1", http, grpc).browser_url()
        with Browser(1600, 1000) as b:
            b.open(url)
            t_open = time.time()
            while proc.poll() is None:
                b.pump(poll_s)
                state = viewer_state(b)
                now = time.time()
                if state is None:
                    continue
                recs = [r for r in state.recordings if r.store_id.startswith("Recording:") and "wall_time" in r.ranges]
                if not recs:
                    continue
                rec = recs[0]
                wall_end = rec.ranges["wall_time"][1] * 1e-9
                sim_end = rec.ranges.get("sim_time", (0, 0))[1] * 1e-9
                samples.append({"t": now - t_open, "lag_s": now - wall_end, "sim_end_s": sim_end})
    finally:
        if proc.poll() is None:
            proc.wait(seconds + 120)
    lags = [s["lag_s"] for s in samples]
    return {
        "samples": samples,
        "median_lag_s": statistics.median(lags) if lags else math.nan,
        "p90_lag_s": _p90(lags),
        "max_sim_s": max((s["sim_end_s"] for s in samples), default=math.nan),
        "exit_code": proc.returncode,
    }


def _p90(xs: list[float]) -> float:
    from tools.bench import percentile

    return percentile(xs, 90.0) if xs else math.nan


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(prog="python -m tools.bench viewer", description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=90.0, help="length of each real-time flight (default 90)")
    ap.add_argument("--poll", type=float, default=2.0, help="seconds between two readings of the viewer (default 2)")
    ap.add_argument("--only", choices=sorted(CONFIGS), action="append", help="fly only this configuration")
    ap.add_argument("--json", action="store_true", help="also print every sample as JSON")
    args = ap.parse_args(argv)
    for name in ("seconds", "poll"):
        v = getattr(args, name)
        if not (math.isfinite(v) and v > 0):
            ap.error(f"--{name} must be positive, got {v}")
    from tools.bench import figure, report
    from tools.bench._browser import chromium_path

    if chromium_path() is None:
        ap.error("chromium is not installed (apt-get install -y chromium)")
    raw = {}
    with tempfile.TemporaryDirectory(prefix="bench-viewer-") as tmp:
        for name in args.only or list(CONFIGS):
            raw[name] = measure(args.seconds, CONFIGS[name], args.poll, Path(tmp))
    figures = {}
    for name, r in raw.items():
        target = TARGET_LAG_S if name == "thinned" else None
        n = len(r["samples"])
        figures[f"{name}.median_lag"] = figure(r["median_lag_s"], "s", target, p90=r["p90_lag_s"], n=n)
        figures[f"{name}.sim_time_shown"] = figure(r["max_sim_s"], "s", flight_s=args.seconds)
    report(f"live web viewer lag ({args.seconds:g} s real-time flights, headless Chromium, SwiftShader)", figures)
    if args.json:
        print(standard_json(raw, indent=1))
    return figures


if __name__ == "__main__":
    main()
