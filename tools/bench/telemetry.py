"""Telemetry benchmark: what logging costs the control loop, how big a flight is, whether memory stays flat.

    python -m tools.bench telemetry [--minutes 1] [--compare-seconds 20] [--rate 400] [--out DIR] [--json]
    python -m tools.bench.telemetry ...          (same, without the dispatcher)

Figures (``main(argv)`` returns them as a dict and prints a table against the targets):

1. ``append_ns``: median cost of one ``Table.append`` of a full autopilot row (25 values), with the
   writer thread running, and of building that row from the controller (``row_build_ns``).
2. A 400 Hz control loop on deadlines (sleep until the deadline, never ``sleep(period)``), each step the
   autopilot's own ``ControlStep`` (setpoint, law, PWM map, metrics) plus an ``Aircraft`` advance, with and
   without telemetry in ONE run: 5 s blocks
   alternating off/on so drift and machine noise hit both alike.  Per mode: median step time (wake to
   end of the step's work, the append included when on), p99 jitter (wake - deadline), missed
   deadlines (steps whose work ended after the next deadline).  Targets: +<= 10 % median, +0 missed.
3. ``.rrd`` size per flight-minute: one simulated minute at the real rates (autopilot row at the
   control rate, link counters at 10 Hz, SITL truth row per ATTITUDE frame) written through the real
   writers in flush-interval batches, each process its own part, then merged as the launcher does.
4. Memory: RSS over a real-time ``--minutes`` flight of the loop with telemetry on (default 1 min,
   ``--minutes 10`` for the issue's figure).  Target: flat, < 50 MB growth.
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from autopilot.shared.process import standard_json

TARGET_MEDIAN_OVERHEAD = 0.10
TARGET_MEMORY_GROWTH_MB = 50.0


def _rss_mb() -> float:
    import psutil

    return psutil.Process().memory_info().rss / 1e6


def _make_plant(rate: float):
    """The autopilot's control step (square-wave command, default PWM map) and the aircraft it flies."""
    from autopilot.config import ClSacConfig
    from autopilot.shared.pwm import PwmMap
    from autopilot.step import ControlStep, ProfileSetpoints
    from sitl.aircraft import Aircraft, AircraftConfig

    step = ControlStep(ClSacConfig(control_rate_hz=rate), PwmMap(), ProfileSetpoints(_command))
    nphys = 5
    ac = Aircraft(AircraftConfig(physics_rate_hz=rate * nphys))
    return step, ac, nphys


def _command(t: float) -> float:
    from tools.flight import profiles

    return profiles.square(t, math.radians(10.0), 10.0)


class GcMonitor:
    """Garbage-collector pauses, attributed to whatever ``label`` is current (they hold the GIL too)."""

    def __init__(self):
        import gc

        self.label = None
        self.pauses: dict[str, list[tuple[int, float]]] = {}
        self._t0 = 0.0
        self._gc = gc
        gc.callbacks.append(self._cb)

    def _cb(self, phase, info):
        if phase == "start":
            self._t0 = time.perf_counter()
        elif self.label is not None:
            self.pauses.setdefault(self.label, []).append((info["generation"], time.perf_counter() - self._t0))

    def summary(self, label: str) -> dict[str, float]:
        p = self.pauses.get(label, [])
        full = [d for g, d in p if g == 2]
        return {
            "gc_collections": len(p),
            "gc_full": len(full),
            "gc_max_pause_us": max((d for _, d in p), default=0.0) * 1e6,
        }

    def close(self):
        if self._cb in self._gc.callbacks:
            self._gc.callbacks.remove(self._cb)


class Loop:
    """A deadline-scheduled control loop; ``run(seconds, tables)`` flies one block."""

    def __init__(self, rate: float):
        self.rate = rate
        self.period = 1.0 / rate
        self.step, self.ac, self.nphys = _make_plant(rate)
        self.k = 0
        self.missed_total = 0

    def run(self, seconds: float, tables=None) -> dict[str, np.ndarray | int]:
        perf = time.perf_counter
        sleep = time.sleep
        wall = time.time
        period = self.period
        n = int(round(seconds * self.rate))
        step_t = np.empty(n)
        comp_t = np.empty(n)
        jitter = np.empty(n)
        missed = 0
        step, ac, nphys = self.step, self.ac, self.nphys
        ctrl = step.law
        ap = links = None
        if tables is not None:
            ap, links = tables
        prev_wake = None
        deadline = perf() + period
        for i in range(n):
            now = perf()
            if deadline > now:
                sleep(deadline - now)
            wake = perf()
            k = self.k
            t_sim = k * period
            x = ac.x
            phi = float(x[3])
            p = float(x[1])
            res = step(t_sim, phi)  # the loop needs the command and its PWM with or without telemetry
            ac.advance(res.u, nphys)
            t_out = perf()
            compute = t_out - wake
            measured_period = (wake - prev_wake) if prev_wake is not None else period
            if ap is not None:  # the only difference between "off" and "on": the logging calls
                ap.append(
                    t_sim,
                    wall(),
                    ctrl.telemetry() + (p, res.pwm, measured_period, compute, wake - deadline, self.missed_total),
                )
                if k % 40 == 0:
                    w = wall()
                    for j, tab in enumerate(links):
                        tab.append(t_sim, w, (k, k + j, 0))
            end = perf()
            step_t[i] = end - wake
            comp_t[i] = compute
            jitter[i] = wake - deadline
            deadline += period
            if end > deadline:  # the work overran into the next period: that deadline is missed
                missed += 1
                self.missed_total += 1
                while deadline < end:  # skip to the next deadline still ahead
                    deadline += period
            prev_wake = wake
            self.k = k + 1
        return {"step": step_t, "compute": comp_t, "jitter": jitter, "missed": missed}


def _stats(blocks: list[dict]) -> dict[str, float]:
    step = np.concatenate([b["step"] for b in blocks])
    comp = np.concatenate([b["compute"] for b in blocks])
    jit = np.concatenate([b["jitter"] for b in blocks])
    return {
        "late_wakes_over_0_5ms": int(np.sum(jit > 0.5e-3)),
        "late_wakes_over_1ms": int(np.sum(jit > 1e-3)),
        "steps": int(step.size),
        "median_step_us": float(np.median(step) * 1e6),
        "median_compute_us": float(np.median(comp) * 1e6),
        "p99_step_us": float(np.percentile(step, 99) * 1e6),
        "p99_jitter_us": float(np.percentile(jit, 99) * 1e6),
        "max_jitter_us": float(np.max(jit) * 1e6),
        "missed": int(sum(b["missed"] for b in blocks)),
    }


def bench_append(tmp: Path, rate: float) -> dict[str, float]:
    from autopilot.shared.telemetry import Telemetry
    from autopilot.telemetry.layout import AUTOPILOT

    step, _, _ = _make_plant(rate)
    step(0.0, 0.01)
    ctrl = step.law
    tel = Telemetry("bench_append", rrd_path=tmp / "append.rrd")
    try:
        ap = tel.table(AUTOPILOT)
        row = ctrl.telemetry() + (0.1, 1500.0, 0.0025, 1e-5, 1e-5, 0)
        reps, n = 15, 20000
        per_append, per_build = [], []
        perf = time.perf_counter
        append = ap.append
        for _ in range(reps):
            t0 = perf()
            for _ in range(n):
                append(0.0025, 1.0, row)
            per_append.append((perf() - t0) / n)
            t0 = perf()
            for _ in range(n):
                ctrl.telemetry() + (0.1, 1500.0, 0.0025, 1e-5, 1e-5, 0)
            per_build.append((perf() - t0) / n)
            time.sleep(0.02)
        loop_overhead = []
        for _ in range(reps):
            t0 = perf()
            for _ in range(n):
                pass
            loop_overhead.append((perf() - t0) / n)
        base = statistics.median(loop_overhead)
        return {
            "append_ns": (statistics.median(per_append) - base) * 1e9,
            "row_build_ns": (statistics.median(per_build) - base) * 1e9,
        }
    finally:
        tel.close()


def bench_loop(tmp: Path, rate: float, seconds: float, block_s: float = 1.0) -> dict[str, dict]:
    """Alternate blocks without and with telemetry in one run (same process, same loop object).

    The writer exists throughout (as it would in a flight), but in "off" blocks nothing is appended,
    so it has nothing to send: the difference between the modes is the cost of logging.
    """
    from autopilot.shared.telemetry import Telemetry
    from autopilot.telemetry.hooks import autopilot_tables

    loop = Loop(rate)
    loop.run(1.0)  # warm-up
    gcm = GcMonitor()
    tel = Telemetry("autopilot", rrd_path=tmp / "loop.rrd")
    try:
        ap, links, _, _ = autopilot_tables(tel)
        links = list(links.values())
        off, on = [], []
        pair_diff = []
        nblocks = max(1, int(round(seconds / block_s / 2)))
        for b in range(nblocks):
            order = ("off", "on") if b % 2 == 0 else ("on", "off")  # ABBA: no mode always goes first
            for mode in order:
                gcm.label = mode
                if mode == "off":
                    off.append(loop.run(block_s))
                else:
                    on.append(loop.run(block_s, (ap, links)))
            pair_diff.append(float(np.median(on[-1]["step"]) - np.median(off[-1]["step"])))
            gcm.label = None
    finally:
        tel.close()
        gcm.close()
    return {
        "off": {**_stats(off), **gcm.summary("off")},
        "on": {**_stats(on), **gcm.summary("on")},
        "paired_median_diff_us": float(np.median(pair_diff) * 1e6),
        "writer_stretch_p50_us": float(np.median(tel.stretches) * 1e6) if tel.stretches else 0.0,
        "writer_stretch_p99_us": float(np.percentile(tel.stretches, 99) * 1e6) if tel.stretches else 0.0,
        "writer_errors": tel.errors,
    }


def bench_size(tmp: Path, rate: float, sitl_rate: float, minutes: float = 1.0) -> dict[str, float]:
    """One simulated flight-minute through the real writers (batched as in real time), merged as the launcher does."""
    from autopilot.shared import telemetry as tm
    from autopilot.telemetry.hooks import autopilot_tables
    from autopilot.vehicle import Mode
    from sitl.telemetry import SITL_TABLE
    from tools.view.views import flight_blueprint

    rid = tm.new_recording_id()
    parts = {p: tmp / f"size-{p}.rrd" for p in ("autopilot", "sitl")}
    ap_tel = tm.Telemetry("autopilot", rid, parts["autopilot"])
    sitl_tel = tm.Telemetry("sitl", rid, parts["sitl"])
    try:
        ap, links, mode, _ = autopilot_tables(ap_tel)
        links = list(links.values())
        st = sitl_tel.table(SITL_TABLE)
        step, ac, nphys = _make_plant(rate)
        ctrl = step.law
        period = 1.0 / rate
        n = int(round(minutes * 60 * rate))
        wall0 = time.time()
        batch = int(round(rate * tm.DEFAULT_FLUSH_INTERVAL_S))
        sitl_every = max(1, int(round(rate / sitl_rate)))
        mode.set(0.0, wall0, Mode.CLSAC.name)
        rng = np.random.default_rng(1)
        for k in range(n):
            t = k * period
            w = wall0 + t
            x = ac.x
            phi_meas = float(np.float32(x[3] + 1e-4 * rng.standard_normal()))  # a noisy sensor, not a clean sine
            res = step(t, phi_meas)
            if k % sitl_every == 0:
                st.append(t, w, tuple(x.tolist()) + (res.u, res.pwm))
            ac.advance(res.u, nphys)
            ap.append(
                t,
                w,
                ctrl.telemetry()
                + (
                    float(np.float32(x[1])),
                    res.pwm,
                    period + 2e-5 * rng.standard_normal(),
                    1.2e-5 + 1e-6 * rng.random(),
                    5e-5 * rng.random(),
                    0,
                ),
            )
            if k % 40 == 0:
                for j, tab in enumerate(links):
                    tab.append(t, w, (k + j, k, 0))
            if (k + 1) % batch == 0:  # what the writer threads would have sent by now in real time
                ap_tel.flush()
                sitl_tel.flush()
    finally:
        ap_tel.close()
        sitl_tel.close()
    merged = tm.merge_recordings(list(parts.values()), tmp / "size-flight.rrd", blueprint=flight_blueprint())
    sizes = {p: parts[p].stat().st_size / 1e6 for p in parts}
    return {
        "minutes": minutes,
        "autopilot_part_mb_per_min": sizes["autopilot"] / minutes,
        "sitl_part_mb_per_min": sizes["sitl"] / minutes,
        "merged_mb_per_min": merged.stat().st_size / 1e6 / minutes,
        "merge_verified": tm.verify_rrd(merged)[0],
    }


def bench_memory(tmp: Path, rate: float, minutes: float, sample_s: float = 5.0) -> dict[str, float | list]:
    """Real-time loop with telemetry on for ``minutes``; RSS sampled every ``sample_s``."""
    from autopilot.shared.telemetry import Telemetry
    from autopilot.telemetry.hooks import autopilot_tables

    loop = Loop(rate)
    tel = Telemetry("autopilot", rrd_path=tmp / "memory.rrd")
    try:
        ap, links, _, _ = autopilot_tables(tel)
        links = list(links.values())
        loop.run(sample_s, (ap, links))  # warm-up block: imports, first chunks, allocator
        rss = [_rss_mb()]
        times = [0.0]
        blocks = []
        nblocks = max(1, int(round(minutes * 60 / sample_s)))
        for i in range(nblocks):
            b = loop.run(sample_s, (ap, links))
            # keep the samples as float32: the bench's own arrays must not pass for the writer's growth
            blocks.append({k: (v.astype(np.float32) if isinstance(v, np.ndarray) else v) for k, v in b.items()})
            rss.append(_rss_mb())
            times.append((i + 1) * sample_s)
    finally:
        tel.close()
    size_mb = (tmp / "memory.rrd").stat().st_size / 1e6
    r = np.array(rss)
    tt = np.array(times)
    half = len(r) // 2
    slope = float(np.polyfit(tt[half:], r[half:], 1)[0] * 60) if len(r) - half >= 3 else float("nan")
    return {
        "minutes": minutes,
        "rss_start_mb": float(r[0]),
        "rss_end_mb": float(r[-1]),
        "rss_max_mb": float(r.max()),
        "growth_mb": float(r.max() - r[0]),
        "second_half_slope_mb_per_min": slope,
        "loop": _stats(blocks),
        "bench_sample_arrays_mb": sum(v.nbytes for b in blocks for v in b.values() if isinstance(v, np.ndarray)) / 1e6,
        "autopilot_part_mb_per_min": size_mb / minutes,
        "rss_samples_mb": [round(float(v), 2) for v in r],
    }


QUICK_ARGV = ["--minutes", "0.25", "--compare-seconds", "10"]  # `python -m tools.bench --quick`


def to_figures(raw: dict) -> dict[str, dict]:
    """The dispatcher's format (tools/bench/__init__.py): name -> {value, unit[, target, pass], details}."""
    from tools.bench import figure

    off, on = raw["loop"]["off"], raw["loop"]["on"]
    mem, size = raw["memory"], raw["size"]
    overhead_pct = (on["median_step_us"] / off["median_step_us"] - 1.0) * 100.0
    # Missed deadlines are rare events: "nothing added" is judged against the counts' Poisson noise (2 sigma).
    miss_noise = 2.0 * math.sqrt(max(1, off["missed"] + on["missed"]))
    return {
        "append_row": figure(
            raw["append"]["append_ns"] / 1000.0, "us", 1.0, note="Table.append, 25-value autopilot row"
        ),
        "build_row": figure(raw["append"]["row_build_ns"] / 1000.0, "us", None, note="ctrl.telemetry() + 6 extras"),
        "step_median_off": figure(off["median_step_us"], "us", None, steps=off["steps"], p99=off["p99_step_us"]),
        "step_median_on": figure(on["median_step_us"], "us", None, steps=on["steps"], p99=on["p99_step_us"]),
        "step_median_overhead": figure(
            overhead_pct,
            "%",
            TARGET_MEDIAN_OVERHEAD * 100.0,
            paired_diff_us=raw["loop"]["paired_median_diff_us"],
            compute_off_us=off["median_compute_us"],
            compute_on_us=on["median_compute_us"],
        ),
        "jitter_p99_off": figure(
            off["p99_jitter_us"],
            "us",
            None,
            max=off["max_jitter_us"],
            late_0_5ms=off["late_wakes_over_0_5ms"],
            late_1ms=off["late_wakes_over_1ms"],
        ),
        "jitter_p99_on": figure(
            on["p99_jitter_us"],
            "us",
            None,
            max=on["max_jitter_us"],
            late_0_5ms=on["late_wakes_over_0_5ms"],
            late_1ms=on["late_wakes_over_1ms"],
        ),
        "missed_deadlines_added": figure(
            on["missed"] - off["missed"],
            "steps",
            round(miss_noise, 1),
            off=off["missed"],
            on=on["missed"],
            note="target: 0 within 2-sigma noise",
        ),
        "writer_gil_stretch_p99": figure(
            raw["loop"]["writer_stretch_p99_us"], "us", None, p50=raw["loop"]["writer_stretch_p50_us"]
        ),
        "rrd_per_flight_minute": figure(
            size["merged_mb_per_min"],
            "MB",
            None,
            autopilot_part=size["autopilot_part_mb_per_min"],
            sitl_part=size["sitl_part_mb_per_min"],
            verified=size["merge_verified"],
        ),
        "memory_growth": figure(
            mem["growth_mb"],
            "MB",
            TARGET_MEMORY_GROWTH_MB,
            minutes=mem["minutes"],
            rss_start=mem["rss_start_mb"],
            rss_end=mem["rss_end_mb"],
            of_which_bench_samples=mem["bench_sample_arrays_mb"],
        ),
        "memory_slope_2nd_half": figure(mem["second_half_slope_mb_per_min"], "MB/min", None),
        "long_run_missed": figure(
            mem["loop"]["missed"], "steps", None, steps=mem["loop"]["steps"], jitter_p99_us=mem["loop"]["p99_jitter_us"]
        ),
    }


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(prog="python -m tools.bench telemetry", description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--minutes",
        type=float,
        default=1.0,
        help="length of the real-time memory run (default 1; the issue's figure: 10)",
    )
    ap.add_argument(
        "--compare-seconds",
        type=float,
        default=20.0,
        help="total length of the off/on loop comparison, in 1 s blocks (default 20 s)",
    )
    ap.add_argument("--rate", type=float, default=400.0, help="control rate in Hz (default 400)")
    ap.add_argument(
        "--sitl-rate",
        type=float,
        default=400.0,
        help="SITL telemetry rows per second (default 400: one per ATTITUDE frame)",
    )
    ap.add_argument("--out", type=Path, default=None, help="keep the .rrd files here (default: a temporary directory)")
    ap.add_argument("--json", action="store_true", help="also print every raw measurement as JSON")
    args = ap.parse_args(argv)
    for name in ("minutes", "compare_seconds", "rate", "sitl_rate"):
        v = getattr(args, name)
        if not (math.isfinite(v) and v > 0):
            ap.error(f"--{name.replace('_', '-')} must be positive, got {v}")
    from tools.bench import report

    tmp = Path(tempfile.mkdtemp(prefix="bench-telemetry-")) if args.out is None else args.out
    tmp.mkdir(parents=True, exist_ok=True)
    try:
        raw: dict = {"rate_hz": args.rate}
        raw["append"] = bench_append(tmp, args.rate)
        raw["loop"] = bench_loop(tmp, args.rate, args.compare_seconds)
        raw["size"] = bench_size(tmp, args.rate, args.sitl_rate)
        raw["memory"] = bench_memory(tmp, args.rate, args.minutes)
    finally:
        if args.out is None:
            shutil.rmtree(tmp, ignore_errors=True)
    figures = to_figures(raw)
    if args.json:
        print(standard_json(raw, indent=2))
    report(
        f"telemetry: control loop at {args.rate:g} Hz with and without telemetry, .rrd size, memory "
        f"({args.minutes:g} min real time); Python {sys.version.split()[0]}, {os.cpu_count()} CPUs",
        figures,
    )
    return figures


if __name__ == "__main__":
    main()
