"""Benchmarks, one module per area: ``python -m tools.bench [AREA ...]`` (all areas when none is named).

An area is any module ``tools/bench/<area>.py`` (not starting with ``_``) that defines::

    def main(argv: list[str]) -> dict:
        '''Measure, print a table, return the figures.'''

The returned dict maps a figure name to a dict with at least ``value`` and ``unit``, and where the
figure has a target also ``target`` (same unit, an upper bound) and ``pass`` (bool); anything else is
extra detail (``p90``, ``n``, ...).  ``argv`` is what the dispatcher forwards: the module's optional
``QUICK_ARGV`` list (e.g. ``["--quick"]``) when the user asked for a short run with ``--quick``, followed by
anything given after ``--``.  An area that raises or exits non-zero is reported and the others still run.
``--json PATH`` on the command line writes all areas' figures, and ``--strict`` makes the command exit 1 when
a figure misses its target.

Shared helpers for area modules live here: :func:`figure`, :func:`print_table`, :func:`report`, :func:`timed_batches`,
:func:`flights_per_s`.
"""

from __future__ import annotations

import gc
import importlib
import pkgutil
import statistics
import time
from typing import Callable, Iterable


def areas() -> list[str]:
    """Names of the benchmark areas present (modules of this package), sorted."""
    return sorted(m.name for m in pkgutil.iter_modules(__path__) if not m.name.startswith("_"))


def load(area: str):
    """Import ``tools.bench.<area>``."""
    return importlib.import_module(f"{__name__}.{area}")


def figure(value: float, unit: str, target: float | None = None, *, higher: bool = False, **extra) -> dict:
    """One benchmark figure; ``pass`` is set when there is a target (value <= target; with ``higher``, for a
    figure where more is better such as a fraction of a floor, value >= target, marked ``target_is="min"``)."""
    out = {"value": float(value), "unit": unit}
    if target is not None:
        out["target"] = float(target)
        out["pass"] = bool(value >= target if higher else value <= target)
        if higher:
            out["target_is"] = "min"
    out.update(extra)
    return out


def percentile(values: list[float], q: float) -> float:
    """Linear-interpolated percentile, q in [0, 100]."""
    xs = sorted(values)
    if not xs:
        raise ValueError("no values")
    k = (len(xs) - 1) * q / 100.0
    lo = int(k)
    hi = min(lo + 1, len(xs) - 1)
    return xs[lo] + (xs[hi] - xs[lo]) * (k - lo)


def timed_batches(
    run_batch: Callable[[], None],
    calls_per_batch: int,
    batches: int,
    setup: Callable[[], None] | None = None,
    warmup: int = 2,
) -> list[float]:
    """Per-call times in microseconds, one value per batch (batch time / calls_per_batch).

    ``setup`` runs before every batch, outside the timed region.  The garbage collector is off while
    timing (as ``timeit`` does) so a collection does not land inside one batch at random.
    """
    per_call: list[float] = []
    gc_was_on = gc.isenabled()
    gc.disable()
    try:
        for i in range(warmup + batches):
            if setup is not None:
                setup()
            t0 = time.perf_counter_ns()
            run_batch()
            dt = time.perf_counter_ns() - t0
            if i >= warmup:
                per_call.append(dt / calls_per_batch / 1000.0)
    finally:
        if gc_was_on:
            gc.enable()
    return per_call


def flights_per_s(tasks: list, workers: int, simulate) -> float:
    """Flights per second of ``tasks`` flown by ``simulate`` through the studies' executor
    (``tools.experiment.study.execute``) on ``workers`` local processes, from the call to the last result."""
    from tools.experiment.study import execute

    t0 = time.perf_counter()
    execute(tasks, None, None, workers, simulate=simulate)
    return len(tasks) / (time.perf_counter() - t0)


def summarise_us(samples: list[float]) -> dict:
    """median, p90 and min of per-call times (min: what the code costs on an idle machine)."""
    return {
        "median": statistics.median(samples),
        "p90": percentile(samples, 90.0),
        "min": min(samples),
        "n": len(samples),
    }


def machine_load() -> dict:
    """CPU count and 1-minute load average (timings on a busy machine are inflated)."""
    import os

    try:
        load1 = os.getloadavg()[0]
    except (AttributeError, OSError):
        load1 = None
    return {"cpus": os.cpu_count(), "load1": load1}


def load_warning() -> str | None:
    m = machine_load()
    if m["load1"] is not None and m["cpus"] and m["load1"] > 0.5 * m["cpus"]:
        return (
            f"note: load average {m['load1']:.1f} on {m['cpus']} CPU(s): other processes compete for the CPU, "
            "so these timings are inflated (compare 'min' with the target)"
        )
    return None


def print_table(title: str, figures: dict[str, dict], file=None) -> None:
    """A fixed-width table: figure, value, unit, target, PASS/FAIL, details."""
    print(title, file=file)
    w = max([30] + [len(n) for n in figures])
    head = f"  {'figure':<{w}} {'value':>10} {'unit':<5} {'target':>9}  {'result':<6} detail"
    print(head, file=file)
    print("  " + "-" * (len(head) - 2), file=file)
    for name, f in figures.items():
        bound = ">=" if f.get("target_is") == "min" else "<="
        target = f"{bound} {_fmt(f['target'])}" if "target" in f else ""
        verdict = ("PASS" if f["pass"] else "FAIL") if "pass" in f else "info"
        shown = ("value", "unit", "target", "pass", "target_is")
        extra = ", ".join(f"{k}={_fmt(v)}" for k, v in f.items() if k not in shown)
        print(f"  {name:<{w}} {_fmt(f['value']):>10} {f['unit']:<5} {target:>9}  {verdict:<6} {extra}", file=file)


def report(title: str, figures: dict[str, dict], file=None) -> None:
    """How an area ends: its figures' table (:func:`print_table`) and, on a busy machine, the load's note
    (:func:`load_warning`)."""
    print_table(title, figures, file=file)
    warning = load_warning()
    if warning:
        print(warning, file=file)


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:.3g}" if abs(v) < 1000 else f"{v:.0f}"
    return str(v)


def failures(results: dict[str, dict[str, dict]]) -> list[str]:
    """``area.figure`` names that missed their target."""
    return [
        f"{a}.{n}"
        for a, figs in results.items()
        for n, f in figs.items()
        if isinstance(f, dict) and f.get("pass") is False
    ]


__all__: Iterable[str] = (
    "areas",
    "load",
    "figure",
    "percentile",
    "timed_batches",
    "flights_per_s",
    "summarise_us",
    "print_table",
    "report",
    "failures",
    "machine_load",
    "load_warning",
)
