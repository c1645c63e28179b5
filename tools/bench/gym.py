"""Steps per second of the native vector environment against ``gymnasium.vector.SyncVectorEnv`` (issue 39, item 2).

    python -m tools.bench gym [--quick]          (or: python -m tools.bench.gym [--quick] [--envs N])

Both fly ``Roll-v0`` on the KH2013A with a different effectiveness fault each (0.2 .. 1.0 at 5 s), the same
actions (a proportional policy on roll and roll rate, one matrix product for all), ``--envs`` aircraft (64):
``tools.experiment.gym.vector.RollVectorEnv`` (the batch step) and ``SyncVectorEnv`` over ``gymnasium.make`` (one
``RollEnv.step`` each, with gymnasium's wrappers).  A figure is aircraft steps per second (envs x vector steps / s),
the median of ``--reps`` timed runs of ``--steps`` vector steps each; the ratio's target is >= 10.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from tools.bench import figure, machine_load, report

QUICK_ARGV = ["--quick"]
TARGET_RATIO = 10.0
POLICY = np.array([[-1.0, -0.1, 0.0, 1.0, 0.0]])  # u = um - phi - 0.1 p (rad)


def options(n: int) -> list[dict]:
    return [{"fault": f"effectiveness={0.2 + 0.8 * i / max(n - 1, 1):.3f}@5"} for i in range(n)]


def rate(envs, n: int, steps: int, reps: int) -> list[float]:
    """Aircraft steps per second, one per repetition (each from a fresh reset)."""
    out = []
    for r in range(reps):
        obs, _ = envs.reset(seed=r, options=options(n) if hasattr(envs, "lanes") else None)
        if not hasattr(envs, "lanes"):
            for i, e in enumerate(envs.envs):
                e.reset(seed=r + i, options=options(n)[i])
            obs = np.array([e.unwrapped.lane.observation() for e in envs.envs])
        t0 = time.perf_counter()
        for _ in range(steps):
            obs, *_ = envs.step(obs @ POLICY.T)
        out.append(n * steps / (time.perf_counter() - t0))
    return out


def main(argv: list[str] | None = None) -> dict:
    import gymnasium

    from tools.experiment.gym.vector import RollVectorEnv

    p = argparse.ArgumentParser(prog="python -m tools.bench.gym", description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="fewer steps and repetitions")
    p.add_argument("--envs", type=int, default=64, help="aircraft (default 64)")
    p.add_argument("--steps", type=int, default=None, help="vector steps per repetition (default 1000, quick 200)")
    p.add_argument("--reps", type=int, default=None, help="repetitions (default 5, quick 3)")
    args = p.parse_args(argv or [])
    n = args.envs
    steps = args.steps or (200 if args.quick else 1000)
    reps = args.reps or (3 if args.quick else 5)
    load = machine_load()
    native = RollVectorEnv(n)
    sync = gymnasium.vector.SyncVectorEnv([lambda: gymnasium.make("sitl.gym:Roll-v0") for _ in range(n)])
    fast = rate(native, n, steps, reps)
    slow = rate(sync, n, steps, reps)
    sync.close()
    ratio = statistics.median(fast) / statistics.median(slow)
    figs = {
        "gym_native_steps_per_s": figure(statistics.median(fast), "1/s", envs=n, min=round(min(fast)), reps=reps),
        "gym_sync_steps_per_s": figure(statistics.median(slow), "1/s", envs=n, min=round(min(slow)), reps=reps),
        "gym_native_over_sync": figure(ratio, "x", TARGET_RATIO, higher=True),
    }
    report(f"gym vector environment, {n} aircraft, load {load['load1']} on {load['cpus']} CPU(s)", figs)
    return figs


if __name__ == "__main__":
    import sys

    main(sys.argv[1:])
