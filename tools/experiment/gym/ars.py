"""A linear policy trained by augmented random search over the vector environment, scored on held-out faults.

    python -m tools.experiment.gym.ars --out /tmp/ars [--iterations 60] [--directions 8] [--seed 1]

Augmented random search (Mania, Guy & Recht, "Simple random search of static linear policies is competitive for
reinforcement learning", NeurIPS 2018), their Algorithm 1, version V2-t: the policy is u = M (s - mu) / sigma on the
observation s of ``Roll-v0`` (roll, roll rate, yaw rate, command, last surface command); mu and sigma are the
running mean and standard deviation of the states seen in training.  Each iteration draws ``--directions`` N
perturbations delta_k (entries N(0, 1)), flies M + nu delta_k and M - nu delta_k on the same fault and seed (all 2N
aircraft in one ``tools.experiment.gym.vector.RollVectorEnv``), keeps the ``--top`` b directions with the largest
max(r+, r-) and steps

    M <- M + alpha / (b sigma_R) sum_k (r+_k - r-_k) delta_k        (sigma_R: std of the 2b returns used)

The return r is the environment's: -(ise_ref + w energy) over the flight, minus the early-end penalty.

Training faults: effectiveness drawn uniformly in [0.3, 1.0] from 5 s, one per direction and iteration, in light
turbulence, 15 s flights of the paper's square wave.  Held out (never trained on, ``HELD_OUT``): effectiveness 0.2
(worse than any trained), roll damping 0.5 and a rudder rate limit of 20 deg/s, each from 10 s of the 30 s paper
scenario in light turbulence, seeds 101..; the fault-free flight for reference.  The policy and the designed PID
(``--controller baseline``'s gains, as a policy in the same environment) are scored by the product's metrics and
verdict (``info``: ise_ref, energy, saturation, the envelope's reason).

It saves ``policy.json`` (M, mu, sigma, the training settings), ``scores.json`` and ``policy_law.py`` in ``--out``:
the policy as a law (``tools.experiment.gym.policy_law``, its numbers as literals), flown with ``--controller
OUT/policy_law.py:Policy`` by the launcher and the damage study.

Training is deterministic for its flags (one generator seeded by ``--seed`` draws the directions, the faults and the
flights' seeds).  The damage study's leaderboard (docs/damage.md, "Leaderboard") trains it with ``--seed 1`` and the
default budget (60 iterations of 8 directions, the best 4 kept: 960 flights of 15 s) and flies it beside every law
(``python -m tools.experiment.damage.leaderboard --fly OUT``), where every fault but effectiveness 0.3-1.0 on the
KH2013A is held out.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

TRAIN_KIND = ("effectiveness", 0.3, 1.0)
HELD_OUT = ("none", "effectiveness=0.2@10", "damping=0.5@10", "rate=20@10")


class Linear:
    """u = M (s - mu) / sigma, the ARS V2 policy; ``Stats`` keeps mu and sigma (Welford's running moments)."""

    def __init__(self, dim: int):
        self.m = np.zeros((1, dim))
        self.mu = np.zeros(dim)
        self.sigma = np.ones(dim)
        self._n, self._mean, self._m2 = 0, np.zeros(dim), np.zeros(dim)

    def __call__(self, obs: np.ndarray, m: np.ndarray | None = None) -> np.ndarray:
        """Actions (rad) for a batch of observations; ``m``: one matrix per row (n, 1, dim), else the policy's."""
        z = (obs - self.mu) / self.sigma
        if m is None:
            return z @ self.m.T
        return np.einsum("nij,nj->ni", m, z)

    def observe(self, obs: np.ndarray) -> None:
        for s in obs:
            self._n += 1
            d = s - self._mean
            self._mean = self._mean + d / self._n
            self._m2 = self._m2 + d * (s - self._mean)

    def update_stats(self) -> None:
        if self._n > 1:
            self.mu = self._mean.copy()
            self.sigma = np.sqrt(np.maximum(self._m2 / (self._n - 1), 1e-8))

    def to_dict(self) -> dict:
        return {"M": self.m.tolist(), "mu": self.mu.tolist(), "sigma": self.sigma.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> Linear:
        p = cls(len(d["mu"]))
        p.m, p.mu, p.sigma = np.array(d["M"]), np.array(d["mu"]), np.array(d["sigma"])
        return p


def rollout(env, act, options, seed: int, record=None) -> tuple[np.ndarray, dict]:
    """Fly every aircraft of the vector env once (``act(obs) -> actions``); returns the returns and the last info
    of each (before its autoreset)."""
    obs, _ = env.reset(seed=seed, options=options)
    n = env.num_envs
    ret, alive, last = np.zeros(n), np.ones(n, dtype=bool), [None] * n
    while alive.any():
        if record is not None:
            record(obs[alive])
        obs, r, term, trunc, info = env.step(act(obs))
        ret += np.where(alive, r, 0.0)
        for i in np.flatnonzero(alive & (term | trunc)):
            last[i] = {k: (v[i].item() if hasattr(v[i], "item") else v[i]) for k, v in info.items()}
        alive &= ~(term | trunc)
    return ret, last


def train(iterations: int, directions: int, top: int, seed: int, step: float, noise: float, log=print) -> Linear:
    from tools.experiment.gym.vector import RollVectorEnv

    rng = np.random.default_rng(seed)
    policy = Linear(5)
    env = RollVectorEnv(2 * directions, duration=15.0, turbulence="light")
    for it in range(iterations):
        t0 = time.perf_counter()
        deltas = rng.standard_normal((directions, 1, 5))
        ms = np.concatenate([policy.m + noise * deltas, policy.m - noise * deltas])
        lo, hi = TRAIN_KIND[1:]
        faults = [f"{TRAIN_KIND[0]}={rng.uniform(lo, hi):.3f}@5" for _ in range(directions)]
        opts = [{"fault": f} for f in faults] * 2  # each direction's pair on the same fault and seed
        flight_seed = int(rng.integers(1, 2**31 - 1))
        seeds = [flight_seed + k for k in range(directions)] * 2
        ret, _ = rollout(env, lambda o, _m=ms: policy(o, _m), opts, seeds, record=policy.observe)
        rp, rm = ret[:directions], ret[directions:]
        best = np.argsort(-np.maximum(rp, rm))[:top]
        sd = float(np.std(np.concatenate([rp[best], rm[best]]))) or 1.0
        policy.m = policy.m + step / (top * sd) * np.einsum("k,kij->ij", rp[best] - rm[best], deltas[best])
        policy.update_stats()
        took = time.perf_counter() - t0
        log(f"iteration {it + 1:3d}: mean return {np.mean(ret):9.4f}, best {np.max(ret):9.4f} ({took:.1f} s)")
    return policy


def pid_policy(plant: str = "kh2013a"):
    """The designed PID (``--controller baseline``) as a policy of one aircraft: its own states, stepped per obs."""
    from dataclasses import replace

    from autopilot.controllers import make_law
    from tools.experiment.scenario import BASELINE_RUN, PAPER, controller_config

    law = make_law(controller_config(replace(PAPER, plant=plant), BASELINE_RUN))
    return lambda obs: np.array([[law(float(obs[0, 0]), float(obs[0, 3]))]])


def score(act_factory, faults=HELD_OUT, seeds=(101, 102, 103)) -> list[dict]:
    """Each fault and seed of the 30 s paper scenario in light turbulence, flown in ``Roll-v0``: the product's
    metrics and its verdict (``info["verdict"]``: ``autopilot.envelope``, tracking included)."""
    import gymnasium

    import sitl.gym  # noqa: F401 (registers Roll-v0)

    out = []
    env = gymnasium.make("sitl.gym:Roll-v0", turbulence="light")
    for f in faults:
        for s in seeds:
            act = act_factory()
            obs, _ = env.reset(seed=s, options={"fault": [] if f == "none" else f})
            ret, done = 0.0, False
            while not done:
                obs, r, term, trunc, info = env.step(act(obs[None, :])[0])
                ret += r
                done = term or trunc
            v = info["verdict"]
            out.append(
                {
                    "fault": f,
                    "seed": s,
                    "return": ret,
                    "ise_ref": info["ise_ref"],
                    "energy": info["energy"],
                    "saturation": info["saturation"],
                    "controlled": v["ok"],
                    "verdict": v["reason"],
                }
            )
    return out


def table(rows: dict) -> str:
    lines = [f"{'fault':<22} {'law':<4} {'ise_ref':>8} {'energy':>8} {'sat %':>6}  verdict"]
    for name, rs in rows.items():
        for r in rs:
            lines.append(
                f"{r['fault'] + ' s' + str(r['seed']):<22} {name:<4} {r['ise_ref']:8.4f} {r['energy']:8.4f} "
                f"{100 * r['saturation']:6.1f}  {r['verdict'].split(':')[0]}"
            )
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m tools.experiment.gym.ars", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, help="folder for policy.json and scores.json (outside the repository)")
    p.add_argument("--iterations", type=int, default=60)
    p.add_argument("--directions", type=int, default=8, help="N, perturbation directions per iteration")
    p.add_argument("--top", type=int, default=4, help="b, directions kept per update")
    p.add_argument("--step", type=float, default=0.02, help="alpha, step size")
    p.add_argument("--noise", type=float, default=0.03, help="nu, exploration noise")
    p.add_argument("--seed", type=int, default=1)
    args = p.parse_args(argv)
    if not (0 < args.top <= args.directions):
        p.error(f"--top must be in 1..--directions ({args.directions}), got {args.top}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    policy = train(args.iterations, args.directions, args.top, args.seed, args.step, args.noise)
    took = time.perf_counter() - t0
    settings = {k: v for k, v in vars(args).items() if k != "out"}
    record = {
        **policy.to_dict(),
        "observation": ["phi", "p", "r", "um", "u_last"],
        "action": "surface command, rad",
        "algorithm": "ARS V2-t (Mania, Guy & Recht 2018)",
        "train_faults": f"{TRAIN_KIND[0]} uniform in [{TRAIN_KIND[1]}, {TRAIN_KIND[2]}] from 5 s, 15 s flights, "
        "light turbulence",
        "settings": settings,
        "train_s": took,
    }
    (out / "policy.json").write_text(json.dumps(record, indent=1))
    from tools.experiment.gym.policy_law import law_source

    (out / "policy_law.py").write_text(law_source(record))  # --controller DIR/policy_law.py:Policy
    rows = {"ars": score(lambda: policy), "pid": score(pid_policy)}
    (out / "scores.json").write_text(json.dumps({"held_out": list(HELD_OUT), "scores": rows}, indent=1))
    print(f"trained in {took:.0f} s; held-out faults, 30 s paper scenario, light turbulence:")
    print(table(rows))
    print(f"wrote {out / 'policy.json'}, {out / 'scores.json'} and {out / 'policy_law.py'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
