"""Bounded memory on long flights: lockstep flights of several hours of sim time with the .rrd and the series on.

For each length (``--hours``, default 1 and 3) one ``python -m tools.launch`` flight is flown in its own process;
every 0.1 s the peak resident memory (VmHWM of /proc/PID/status) of each process is read: the launcher, the SITL,
the autopilot, the GCS script and the step that finishes the recording: ``rerun rrd merge`` for a short flight, and
for a long one the concatenation of the parts, which runs in the launcher itself (its peak includes it).
Figures: each process's peak at each length, and its growth per hour of sim time between the shortest and the
longest flight, which must be about 0 (target: at most 2 MB per hour) for every process to stay below a fixed
bound whatever the flight's length.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from tools.bench import figure, print_table

QUICK_ARGV = ["--hours", "0.05,0.15"]
GROWTH_TARGET_MB_PER_H = 2.0


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
)


def fly(hours: float, rate: float, workdir: Path) -> tuple[dict, float, int]:
    """One ``python -m tools.launch`` flight in its own process; the peak memory of the launcher and of each of
    its children (polled every 0.1 s), the wall time and the launcher's exit status."""
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
    return peaks, time.perf_counter() - t0, launcher.returncode


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
            pk, wall, code = fly(h, args.rate, Path(tmp))
            ok, reason = code == 0, f"launcher exit status {code}"
            peaks[h] = pk
            print(
                f"  {h:g} h of sim time in {wall:.0f} s wall ({'ok' if ok else 'FAILED: ' + str(reason)}): "
                + ", ".join(f"{k} {v:.0f} MB" for k, v in sorted(pk.items())),
                flush=True,
            )
            for name, v in sorted(pk.items()):
                figures[f"peak_{name}_{h:g}h_mb"] = figure(v, "MB", wall_s=round(wall, 1), flight_ok=ok)
    lo, hi = lengths[0], lengths[-1]
    if hi > lo:
        for name in sorted(set(peaks[lo]) & set(peaks[hi])):
            slope = (peaks[hi][name] - peaks[lo][name]) / (hi - lo)
            figures[f"growth_{name}_mb_per_h"] = figure(
                slope, "MB/h", GROWTH_TARGET_MB_PER_H, at_hours=[lo, hi], peaks_mb=[peaks[lo][name], peaks[hi][name]]
            )
    print_table("Endurance: peak memory of each process of a lockstep flight with .rrd and series", figures)
    return figures
