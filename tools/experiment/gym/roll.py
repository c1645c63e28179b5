"""``Roll-v0``: the roll loop of the SITL's aircraft as a Gymnasium environment (docs/gymnasium.md).

``gymnasium.make("sitl.gym:Roll-v0", plant="jsbsim:c172x")`` (``sitl.gym`` registers it).  The physics is the
lockstep flight's own (``tools.experiment.gym.flight.Lane``: ``sitl.plant``, ``sitl.damage``, ``sitl.disturbances``,
``sitl.sensors``); the action is the surface command that the autopilot would send, the observation what it
receives.  Imported only when an environment is made: the product does not depend on gymnasium.
"""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from tools.experiment.gym.flight import OPTIONS, U_LIMIT_RAD, Episode, Lane, episode

OBSERVATION = ("phi", "p", "r", "um", "u_last")  # rad, rad/s, rad/s, rad, rad
OBSERVATION_MIMO = ("phi", "p", "r", "beta", "um", "beta_cmd", "u_last", "u2_last")  # a square MIMO plant
SEED_MAX = 2**31 - 1


def observation_space(mimo: bool = False) -> spaces.Box:
    """roll phi in [-pi, pi] (rad, wrapped as ATTITUDE carries it), roll rate p and yaw rate r (rad/s, within
    float32's range), the command u_m (rad) and the last surface command flown (rad, within the 30 deg servo
    calibration).  A square MIMO plant: phi, p, r, the sideslip beta (rad), u_m, the sideslip command, the
    aileron's and the rudder's last commands."""
    inf = float(np.finfo(np.float32).max)  # ATTITUDE's rates are float32
    if mimo:
        low = np.array([-math.pi, -inf, -inf, -math.pi, -math.pi, -math.pi, -U_LIMIT_RAD, -U_LIMIT_RAD])
        return spaces.Box(low, -low, dtype=np.float64)
    low = np.array([-math.pi, -inf, -inf, -math.pi, -U_LIMIT_RAD])
    high = np.array([math.pi, inf, inf, math.pi, U_LIMIT_RAD])
    return spaces.Box(low, high, dtype=np.float64)


def action_space(mimo: bool = False) -> spaces.Box:
    """The surface command in rad, within the servo's calibrated +-30 deg; the plant's own stop (the c172x's
    aileron: 17.5 deg) clips it further, as the servo would.  A square MIMO plant: (aileron, rudder)."""
    return spaces.Box(-U_LIMIT_RAD, U_LIMIT_RAD, shape=(2 if mimo else 1,), dtype=np.float64)


class RollEnv(gym.Env):
    """The roll loop of one aircraft: one step = one control period (10 ms at 100 Hz) of the lockstep flight.

    Keywords (the defaults of every reset; ``reset(options=...)`` puts options on top of them, for that episode and
    the later ones reset without options): ``plant``
    (``kh2013a``, ``FILE.toml``, ``jsbsim:MODEL[:KEY=VALUE,...]``), ``fault`` (a ``--fault`` spec or a list of
    them), ``duration`` (s, 30), ``control_rate`` (Hz, 100), ``physics_rate`` (Hz, 1000), the command ``profile``
    (square, step, sine), ``amplitude`` (deg), ``period`` (s), ``csv``, the disturbance flags of ``python -m
    tools.launch`` by their names (``turbulence``, ``roll_noise`` in deg, ``sensor_delay``, ``gust``, ...; no link
    faults) and ``effort_weight`` (the reward's weight on u^2, 1).  See docs/gymnasium.md.
    """

    metadata = {"render_modes": []}

    def __init__(self, **options):
        self._defaults = dict(options)
        self._ep: Episode = episode(self._defaults)  # checked now: a bad keyword fails at make()
        self.mimo = self._ep.mimo
        self.observation_space = observation_space(self.mimo)
        self.action_space = action_space(self.mimo)
        self.lane: Lane | None = None

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if options:  # the keywords' defaults with these on top, for this episode and the next ones without options
            ep = episode({**self._defaults, **options})
            if ep.mimo != self.mimo:
                raise ValueError(
                    f"--plant {ep.plant}: this environment's spaces are for a "
                    f"{'square MIMO' if self.mimo else 'single-surface'} plant: make one with plant={ep.plant!r}"
                )
            self._ep = ep
        flight_seed = seed if seed is not None else int(self.np_random.integers(0, SEED_MAX))
        self.lane = lane = Lane(self._ep, flight_seed)
        return lane.observation(), {**lane.info(), "seed": lane.seed}

    def step(self, action):
        lane = self.lane
        if lane is None:
            raise RuntimeError("call reset() before step()")
        a = np.asarray(action, dtype=np.float64).reshape(-1)
        n = 2 if self.mimo else 1
        if a.shape != (n,):
            raise ValueError(f"step {lane.k}: the action is {n} surface command(s) (rad), got shape {np.shape(action)}")
        for u in a.tolist():
            if not math.isfinite(u):
                raise ValueError(f"step {lane.k} (t = {lane.k * lane.dt:.3f} s): the action must be finite, got {u!r}")
        lane.act(a[0].item())
        if self.mimo:
            lane.act2(a[1].item())
        reward, out = lane.score()
        lane.advance()
        lane.measure()
        diverged = lane.diverged()
        if diverged is not None and lane.exit is None:
            lane.exit = f"the plant diverged: {diverged}"
        terminated = lane.exit is not None
        truncated = not terminated and lane.k >= lane.ep.steps
        if terminated:
            reward += lane.penalty()
        info = lane.info()
        if terminated or truncated:
            info["verdict"] = lane.monitor.result().to_dict()
        return lane.observation(), reward, terminated, truncated, info


__all__ = ["OBSERVATION", "OBSERVATION_MIMO", "OPTIONS", "RollEnv", "action_space", "observation_space"]
