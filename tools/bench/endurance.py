"""Bounded memory on long flights: lockstep flights of several hours of sim time with the .rrd and the series on.

For each length (``--hours``, default 1 and 3) one ``python -m tools.launch`` flight is flown in its own process;
every 0.1 s the peak resident memory (VmHWM of /proc/PID/status) of each process is read: the launcher, the SITL,
the autopilot, the GCS script, the helper that draws flight.png (``tools.view.flight_picture``) and the step that
finishes
the recording: ``rerun rrd merge`` for a short flight, and for a long one the concatenation of the parts, which runs in
the launcher itself (its peak includes it).
Figures: each process's peak at each length, and its growth per hour of sim time between the shortest and the
longest flight, which must be about 0 (target: at most 2 MB per hour, from flights of half an hour on) for every
process to stay below a fixed bound whatever the flight's length.  Each flight must leave one DIR/flight.rrd
(its size is reported; the flight's folder is removed before the next flight).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from tools.bench import figure, print_table

QUICK_ARGV = ["--hours", "0.05,0.15"]
GROWTH_TARGET_MB_PER_H = 2.0
# Below this length the fixed-size buffers are still filling (the timing reservoir of 100,000 samples per series
# fills in 1000 s at 100 Hz; ``rerun rrd merge`` runs up to 64 MB of telemetry, about 15 minutes), so growth
# between shorter flights is reported without a target: it is not growth with the flight's length.
GROWTH_FROM_H = 0.5


def _hwm_mb(pid: int) -> float | None:
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def _children(ppid: int) -> dict[int, bytes]:
    """The processes whose parent is ``ppid``: pid -> command line."""
    out = {}
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            with open(f"/proc/{d}/stat") as f:
                if int(f.read().rsplit(")", 1)[1].split()[1]) != ppid:
                    continue
            with open(f"/proc/{d}/cmdline", "rb") as f:
                out[int(d)] = f.read()
        except (OSError, IndexError, ValueError):
            continue
    return out


_NAMES = (
    (b"-m\x00sitl", "sitl"),
    (b"-m\x00autopilot", "autopilot"),
    (b"-m\x00tools.gcs", "gcs"),
    (b"rrd\x00merge", "rrd_merge"),
    (b"-m\x00tools.view.flight_picture", "png_helper"),  # draws flight.png (tools.view.flight_picture)
)


def fly(hours: float, rate: float, workdir: Path) -> tuple[dict, float, int, dict]:
    """One ``python -m tools.launch`` flight in its own process; the peak memory of the launcher and of each of
    its children (polled every 0.1 s), the wall time, the launcher's exit status and its recording: the size of
    DIR/flight.rrd (MB, None if missing) and whether it is indexed, from summary.json."""
    out = workdir / f"{hours:g}h"
    argv = [sys.executable, "-m", "tools.launch", "--lockstep", "--duration", repr(hours * 3600.0)]
    argv += ["--rate", repr(rate), "--quiet", "--out", str(out), "--timeout", "86400"]
    t0 = time.perf_counter()
    launcher = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    peaks: dict[str, float] = {}

    def take(name: str, pid: int) -> None:
        v = _hwm_mb(pid)
        if v is not None and v > peaks.get(name, 0.0):
            peaks[name] = v

    while launcher.poll() is None:
        take("launcher", launcher.pid)
        for pid, cmd in _children(launcher.pid).items():
            for marker, name in _NAMES:
                if marker in cmd:
                    take(name, pid)
        time.sleep(0.1)
    wall = time.perf_counter() - t0
    try:
        files = json.loads((out / "summary.json").read_text())["files"]
        rrd = Path(files["rrd"]) if files.get("rrd") else None
        recording = {"rrd_mb": rrd.stat().st_size / 1e6 if rrd and rrd.is_file() else None}
        recording["rrd_indexed"] = files.get("rrd_indexed")
    except (OSError, ValueError, KeyError, TypeError):
        recording = {"rrd_mb": None, "rrd_indexed": None}
    shutil.rmtree(out, ignore_errors=True)  # gigabytes for a long flight: free the disk before the next one
    return peaks, wall, launcher.returncode, recording


def main(argv: list[str]) -> dict:
    p = argparse.ArgumentParser(prog="python -m tools.bench endurance", description=__doc__.split("\n\n")[0])
    p.add_argument("--hours", default="1,3", help="flight lengths in hours of sim time, comma-separated (default 1,3)")
    p.add_argument("--rate", type=float, default=100.0, help="control rate, Hz (default 100)")
    args = p.parse_args(argv)
    lengths = sorted(float(h) for h in args.hours.split(","))
    figures: dict = {}
    peaks: dict[float, dict] = {}
    with tempfile.TemporaryDirectory(prefix="bench-endurance-") as tmp:
        for h in lengths:
            pk, wall, code, rec = fly(h, args.rate, Path(tmp))
            ok, reason = code == 0, f"launcher exit status {code}"
            if ok and rec["rrd_mb"] is None:
                ok, reason = False, "no DIR/flight.rrd"
            peaks[h] = pk
            print(
                f"  {h:g} h of sim time in {wall:.0f} s wall ({'ok' if ok else 'FAILED: ' + str(reason)}): "
                + ", ".join(f"{k} {v:.0f} MB" for k, v in sorted(pk.items()))
                + f"; one flight.rrd of {rec['rrd_mb'] or 0:.0f} MB"
                + (" (indexed)" if rec["rrd_indexed"] else " (concatenated, no index)"),
                flush=True,
            )
            figures[f"flight_rrd_{h:g}h_mb"] = figure(rec["rrd_mb"] or 0.0, "MB", indexed=rec["rrd_indexed"])
            for name, v in sorted(pk.items()):
                figures[f"peak_{name}_{h:g}h_mb"] = figure(v, "MB", wall_s=round(wall, 1), flight_ok=ok)
    lo, hi = lengths[0], lengths[-1]
    if hi > lo:
        for name in sorted(set(peaks[lo]) & set(peaks[hi])):
            slope = (peaks[hi][name] - peaks[lo][name]) / (hi - lo)
            target = GROWTH_TARGET_MB_PER_H if lo >= GROWTH_FROM_H else None
            figures[f"growth_{name}_mb_per_h"] = figure(
                slope, "MB/h", target, at_hours=[lo, hi], peaks_mb=[peaks[lo][name], peaks[hi][name]]
            )
        if lo < GROWTH_FROM_H:
            print(f"  (growth has no target below {GROWTH_FROM_H:g} h: the fixed-size buffers are still filling)")
    print_table("Endurance: peak memory of each process of a lockstep flight with .rrd and series", figures)
    return figures
