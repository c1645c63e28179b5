"""Bounded memory on long flights: lockstep flights of several hours of sim time with the .rrd and the series on.

For each length (``--hours``, default 1 and 3) one launcher flight is flown; every 0.1 s the peak resident memory
(VmHWM of /proc/PID/status) of each process is read: the SITL, the autopilot, the GCS script, the launcher (this
process) and the step that finishes the recording (``rerun rrd merge``, a child of the launcher).  Figures: each
process's peak at each length, and its growth per hour of sim time between the shortest and the longest flight,
which must be about 0 (target: at most 2 MB per hour) for every process to stay below a fixed bound whatever the
flight's length.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import threading
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


def _merge_pids() -> list[int]:
    """This process's children that run ``rerun rrd merge``."""
    me = str(os.getpid())
    out = []
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            with open(f"/proc/{d}/stat") as f:
                ppid = f.read().rsplit(")", 1)[1].split()[1]
            if ppid != me:
                continue
            with open(f"/proc/{d}/cmdline", "rb") as f:
                if b"rrd\x00merge" in f.read():
                    out.append(int(d))
        except (OSError, IndexError):
            continue
    return out


class PeakWatch(threading.Thread):
    """Polls the peak memory of the flight's processes until stopped."""

    def __init__(self, flight):
        super().__init__(daemon=True)
        self.flight = flight
        self.peaks: dict[str, float] = {}
        self.halt = threading.Event()

    def _take(self, name: str, pid: int) -> None:
        v = _hwm_mb(pid)
        if v is not None and v > self.peaks.get(name, 0.0):
            self.peaks[name] = v

    def run(self) -> None:
        while not self.halt.wait(0.1):
            for name, pid in self.flight.pids.items():
                self._take(name, pid)
            for pid in _merge_pids():
                self._take("rrd_merge", pid)
            self._take("launcher", os.getpid())


def fly(hours: float, rate: float, workdir: Path) -> tuple[dict, float, bool, str | None]:
    from tools.flight import Flight

    out = workdir / f"{hours:g}h"
    try:  # this process is the launcher of every flight: restart its high-water mark for this one
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
    except OSError:
        pass
    flight = Flight(
        lockstep=True, duration=hours * 3600.0, rate=rate, out=out, quiet=True, rrd=True, series=True, timeout=86_400
    )
    t0 = time.perf_counter()
    with flight:
        watch = PeakWatch(flight)
        watch.start()
        res = flight.wait()
    time.sleep(0.3)  # the last polls see the merge's final peak
    watch.halt.set()
    watch.join()
    return watch.peaks, time.perf_counter() - t0, res.ok, res.reason


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
            pk, wall, ok, reason = fly(h, args.rate, Path(tmp))
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
