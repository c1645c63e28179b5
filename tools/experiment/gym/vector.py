"""``RollVectorEnv``: N aircraft of ``Roll-v0`` in one numpy step, each with its own options, faults and seed
(docs/gymnasium.md, "The vector environment").

``gymnasium.make_vec("sitl.gym:Roll-v0", num_envs=64, vectorization_mode="vector_entry_point")``, or
``RollVectorEnv(64, plant=...)``.  The numbers are those of N ``Roll-v0`` environments (``gymnasium.vector.
SyncVectorEnv``) to the last bit (tests/tools/experiment/test_gym.py): each aircraft is a
``tools.experiment.gym.flight.Lane`` built exactly as the single environment builds it, and the study's way of flying
many aircraft (``tools.experiment.study``: arrays of N states, the same operations elementwise) is applied where it
gives the same bits:

* the physics of a linear plant (the KH2013A, a plant file without a ``truth`` map, no stop or servo fault, no
  atmosphere, no sensor errors) between fault changes: the exact ZOH update x <- Ad^n x + Bd_n u of
  ``sitl.aircraft.Aircraft.advance`` for all of them in one stacked ``numpy.matmul`` (one matrix-vector product
  per aircraft, as the aircraft's own ``@``);
* the pulse, the reference model, the metrics and the envelope's roll, saturation and oscillation checks
  (``autopilot.envelope.saturated``, ``stop_hit``, ``block_add``, ``window_flags``: its elementwise forms).

Every other step (a JSBSim aircraft, turbulence, sensor errors, a fault starting or ending, a stuck or rate-limited
surface) is flown by that aircraft's own ``Lane``.  Autoreset: ``NEXT_STEP``, as ``SyncVectorEnv``.
"""

from __future__ import annotations

import math

import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from autopilot.envelope import (
    BLOCK_FIELDS,
    FOLLOW_GAIN_MIN,
    TRACK_BLOCK_S,
    TRACK_BLOCKS,
    WINDOW_SUMS,
    block_add,
    saturated,
    stop_hit,
    window_flags,
)
from autopilot.swings import swing_start, swing_step
from sitl import plant as plants
from tools.experiment.gym.flight import REF_CM, Lane, commands, episode
from tools.experiment.gym.roll import SEED_MAX, action_space, observation_space

assert FOLLOW_GAIN_MIN > 0  # (the not-following flag is reported by the verdict, it does not end an episode)


class RollVectorEnv(VectorEnv):
    """N ``Roll-v0`` aircraft.  ``reset(seed=..., options=...)``: ``seed`` an int (env i gets seed + i, as
    ``SyncVectorEnv``) or a list; ``options`` a dict for every aircraft or a list of N dicts, one each."""

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}

    def __init__(self, num_envs: int = 1, **options):
        if not (isinstance(num_envs, int) and num_envs >= 1):
            raise ValueError(f"num_envs must be a whole number >= 1, got {num_envs!r}")
        self.num_envs = n = num_envs
        self._defaults = dict(options)
        ep = episode(self._defaults)
        if ep.mimo:
            raise ValueError(f"--plant {ep.plant}: a square MIMO plant flies in Roll-v0, one aircraft, not here yet")
        self._eps = [ep] * n
        self.single_observation_space = observation_space()
        self.single_action_space = action_space()
        self.observation_space = batch_space(self.single_observation_space, n)
        self.action_space = batch_space(self.single_action_space, n)
        self._rngs = [None] * n
        self.lanes: list[Lane] = []
        self._done = np.zeros(n, dtype=bool)

    # ------------------------------------------------------------------------------------------------ reset
    def reset(self, *, seed=None, options=None):
        n = self.num_envs
        if seed is None:
            seeds = [None] * n
        else:
            seeds = list(seed) if isinstance(seed, (list, tuple)) else [seed + i for i in range(n)]
        if len(seeds) != n:
            raise ValueError(f"reset: {len(seeds)} seeds for {n} environments")
        if options is not None:
            per = list(options) if isinstance(options, (list, tuple)) else [options] * n
            if len(per) != n:
                raise ValueError(f"reset: {len(per)} option sets for {n} environments")
            cache: dict = {}
            eps = []
            for i, o in enumerate(per):  # as Roll-v0: no options keep the last episode's; the same ones checked once
                key = repr(sorted(o.items())) if o else None
                if key is not None and key not in cache:
                    cache[key] = episode({**self._defaults, **o})
                    if cache[key].mimo:
                        raise ValueError(f"--plant {cache[key].plant}: a square MIMO plant flies in Roll-v0 only")
                eps.append(self._eps[i] if key is None else cache[key])
            self._eps = eps
        for i, s in enumerate(seeds):
            if s is not None or self._rngs[i] is None:
                self._rngs[i] = seeding.np_random(s)[0]
        self.lanes = [self._lane(i, s) for i, s in enumerate(seeds)]
        self._build()
        self._done[:] = False
        return self._obs(), self._info()

    def _lane(self, i: int, seed) -> Lane:
        s = seed if seed is not None else int(self._rngs[i].integers(0, SEED_MAX))
        return Lane(self._eps[i], s)

    def _build(self) -> None:
        """The batch arrays from the lanes (after a reset; rows again after a lane's autoreset)."""
        n = self.num_envs
        lanes = self.lanes
        self._dt = np.array([ln.dt for ln in lanes])
        self._limit = np.array([ln.limit for ln in lanes])
        self._weight = np.array([ln.ep.effort_weight for ln in lanes])
        self._steps = np.array([ln.ep.steps for ln in lanes])
        self._nphys = np.array([ln.ep.physics_per_control for ln in lanes])
        self._share = np.array([ln.share_steps() for ln in lanes])
        self._roll_lim = np.array([ln.monitor.envelope.max_roll_rad for ln in lanes])
        self._ref = np.array([ln.ref for ln in lanes])
        width = max(ln.ep.steps for ln in lanes) + 1
        self._um = np.zeros((n, width))
        for i, ln in enumerate(lanes):
            table = commands(ln.ep.profile, ln.dt, ln.ep.steps)
            self._um[i, : len(table)] = table
        self._k = np.zeros(n, dtype=np.int64)
        self._xm = np.zeros(n)
        self._u = np.zeros(n)
        self._phi = np.array([ln.phi for ln in lanes])
        self._p = np.array([ln.p for ln in lanes])
        self._r = np.array([ln.r for ln in lanes])
        self._ise = np.zeros(n)
        self._energy = np.zeros(n)
        self._max_u = np.zeros(n)
        self._nsat = np.zeros(n, dtype=np.int64)
        self._exit = np.array([None] * n, dtype=object)
        # tracking: the open block's sums (the envelope's fields: autopilot.envelope.block_add), the ring of closed
        # ones, how many, the open block's index, hit arming
        self._block = np.zeros((n, BLOCK_FIELDS))
        self._ring = np.zeros((n, TRACK_BLOCKS, BLOCK_FIELDS))
        self._swing = np.array(
            swing_start(np.zeros(n))
        )  # autopilot.swings' state (7 x n), set at a lane's first sample
        self._kt = np.zeros(n)  # a lane's tracked samples so far (the monitor's ``_k``)
        self._closed = np.zeros(n, dtype=np.int64)
        self._bidx = np.full(n, -1, dtype=np.int64)
        self._armed = np.ones(n, dtype=bool)
        self._fast_setup()

    def _fast_setup(self) -> None:
        """Which lanes the batch physics flies, their state rows (each plant's ``x`` a view of one) and matrices."""
        lanes = self.lanes
        sizes = [ln.plant.x.shape[0] if self._linear(ln) else 0 for ln in lanes]
        m = max(sizes) if any(sizes) else 0
        self._m = m
        self._linear_ok = np.array([s == m and m > 0 for s in sizes])
        self._x = np.zeros((self.num_envs, max(m, 1)))
        self._ad = np.zeros((self.num_envs, max(m, 1), max(m, 1)))
        self._bd = np.zeros((self.num_envs, max(m, 1)))
        # per lane: the plant's physics step, the last command, the next fault change (a physics step), whether
        # its next steps are a plain update (no stop, no servo fault, the pair built): ``_refresh``
        self._psteps = np.zeros(self.num_envs, dtype=np.int64)
        self._ulast = np.zeros(self.num_envs)
        self._mark = np.zeros(self.num_envs, dtype=np.int64)
        self._plain = np.zeros(self.num_envs, dtype=bool)
        for i in np.flatnonzero(self._linear_ok):
            self._adopt(int(i))
            self._refresh(int(i))

    @staticmethod
    def _linear(ln: Lane) -> bool:
        """A lane whose physics is an ``Aircraft``'s exact linear update (see the module docstring)."""
        ac = ln.plant
        return (
            not ln.euler and not ln.sensors and ln.inj.atmosphere is None and getattr(ac, "_truth_map", 1) is None  # noqa: SLF001 (the Aircraft's own update, read not copied)
        )

    def _adopt(self, i: int) -> None:
        """Row i of the states is the aircraft's state from now on (its ``x`` a view of the row)."""
        ac = self.lanes[i].plant
        self._x[i] = ac.x
        ac.x = self._x[i]

    def _refresh(self, i: int) -> None:
        """Lane i's batch bookkeeping from its aircraft (after a reset or a step the aircraft flew itself): its step,
        its last command, the next step where a fault starts or ends (``sitl.damage.ScheduledEffects``), and
        whether a plain update x <- Ad^n x + Bd_n u flies it, with the aircraft's own matrices for n steps."""
        ln = self.lanes[i]
        ac = ln.plant
        self._psteps[i] = ac.steps
        self._ulast[i] = ac._u_last  # noqa: SLF001 (the Aircraft's own state, read not copied)
        sched = ln.scheduled
        nxt = None if sched is None else sched._next  # noqa: SLF001
        self._mark[i] = np.iinfo(np.int64).max if nxt is None else nxt
        pair = None
        if not ac._limited and ac._act is None:  # noqa: SLF001 (stops, servo faults: stepped one by one)
            pair = ac._multi.get(int(self._nphys[i]))  # noqa: SLF001 (built by the aircraft on its first advance)
        self._plain[i] = pair is not None
        if pair is not None:
            self._ad[i], self._bd[i] = pair

    # ------------------------------------------------------------------------------------------------ step
    def step(self, actions):
        a = np.asarray(actions, dtype=np.float64).reshape(self.num_envs, -1)
        if a.shape[1] != 1:
            raise ValueError(
                f"the actions are one surface command (rad) per environment, got shape {np.shape(actions)}"
            )
        a = a[:, 0].copy()
        redo = np.flatnonzero(self._done)
        bad = np.flatnonzero(~np.isfinite(a) & ~self._done)
        if bad.size:
            i = int(bad[0])
            raise ValueError(
                f"environment {i}, step {int(self._k[i])} (t = {self._k[i] * self._dt[i]:.3f} s): the action must be "
                f"finite, got {a[i]!r}"
            )
        a[redo] = 0.0
        # the pulse (autopilot.shared.pwm.PwmMap: clipped to the limit, rounded to 1 us, back to rad)
        lim = self._limit
        u = np.where(a > lim, lim, np.where(a < -lim, -lim, a))
        pwm = self.lanes[0].pwm
        up = (pwm.pwm_max - pwm.pwm_trim) / pwm.rudder_max_rad
        dn = (pwm.pwm_trim - pwm.pwm_min) / pwm.rudder_max_rad
        v = pwm.pwm_trim + u * np.where(u >= 0.0, up, dn)
        p = np.clip(np.floor(v + 0.5), pwm.pwm_min, pwm.pwm_max)
        d = p - pwm.pwm_trim
        u = d / np.where(d >= 0, up, dn)
        self._u = u
        reward = self._score(u)
        self._advance(u)
        self._measure()
        term = self._exit != None  # noqa: E711 (elementwise on the object array)
        trunc = ~term & (self._k >= self._steps)
        reward = reward + np.where(term, -(self._steps - self._k) * self._roll_lim**2 * self._dt, 0.0)
        reward[redo] = 0.0
        term[redo] = trunc[redo] = False
        for i in redo:  # NEXT_STEP autoreset: the lane that ended last step starts again
            self._autoreset(int(i))
        self._done = term | trunc
        return self._obs(), reward, term, trunc, self._info()

    def _score(self, u: np.ndarray) -> np.ndarray:
        """``Lane.score`` for all lanes: the metrics, the reward, the envelope; the reference model moves on."""
        phi, dt = self._phi, self._dt
        k = self._k
        ym = REF_CM * self._xm
        d = phi - ym
        self._ise += d * d
        self._energy += u * u
        self._max_u = np.maximum(self._max_u, np.abs(u))
        reward = -(d * d + self._weight * (u * u)) * dt
        sat = saturated(u, self._limit)
        self._nsat += sat
        a = np.where(phi == phi, np.abs(phi), np.inf)
        out = a >= self._roll_lim
        self._exit[out & (self._exit == None)] = "roll"  # noqa: E711
        self._track(k * dt, phi, ym, u, sat)
        self._exit[(self._nsat >= self._share) & (self._exit == None)] = "saturation"  # noqa: E711
        um = self._um[np.arange(self.num_envs), np.minimum(k, self._um.shape[1] - 1)]  # (a lane ended: moot)
        self._xm = self._ref[:, 0] * self._xm + self._ref[:, 1] * um
        self._k = k + 1
        return reward

    def _track(self, ft, roll, ref, u, sat) -> None:
        """``autopilot.envelope.EnvelopeMonitor._track``: the samples into 1 s blocks, a block closed when the next
        begins, each window of ``TRACK_BLOCKS`` closed blocks judged (``window_flags``); an oscillation ends it."""
        j = np.floor(ft / TRACK_BLOCK_S + 1e-6).astype(np.int64)
        new = j != self._bidx
        close = np.flatnonzero(new & (self._bidx >= 0))
        if close.size:
            slot = self._closed[close] % TRACK_BLOCKS
            self._ring[close, slot] = self._block[close]
            self._closed[close] += 1
            full = close[self._closed[close] >= TRACK_BLOCKS]
            if full.size:
                tot = np.zeros((full.size, BLOCK_FIELDS))
                first = self._closed[full] % TRACK_BLOCKS  # the oldest block of the ring
                for b in range(TRACK_BLOCKS):  # in time order, as the monitor sums its list
                    tot = tot + self._ring[full, (first + b) % TRACK_BLOCKS]
                osc, _lag = window_flags(*tot.T[list(WINDOW_SUMS)])
                hit = full[osc]
                self._exit[hit[self._exit[hit] == None]] = "oscillation"  # noqa: E711
        if new.any():
            self._block[new] = 0.0
            self._bidx[new] = j[new]
        d = roll - ref
        hit, self._armed = stop_hit(sat, u, self._limit, self._armed)
        first = self._kt == 0.0  # a lane's first tracked sample starts its counter (EnvelopeMonitor._track)
        if first.any():
            self._swing[:, first] = np.array(swing_start(d[first]))
        block_add(self._block.T, roll, ref, d, hit, swing_step(self._swing, d, self._kt), sat)  # the monitor's sums
        self._kt += 1.0

    def _advance(self, u: np.ndarray) -> None:
        n = self.num_envs
        fast = self._plain & (self._mark >= self._psteps + self._nphys)  # no fault starts or ends in these steps
        idx = np.flatnonzero(fast)
        if idx.size == n:  # x <- Ad^n x + Bd_n u (sitl.aircraft.Aircraft.advance), one product per aircraft
            self._x[:] = np.matmul(self._ad, self._x[:, :, None])[:, :, 0] + self._bd * u[:, None]
        elif idx.size:
            self._x[idx] = np.matmul(self._ad[idx], self._x[idx, :, None])[:, :, 0] + self._bd[idx] * u[idx, None]
        self._psteps += np.where(fast, self._nphys, 0)  # what the aircraft's own advance keeps besides the state
        self._ulast = np.where(fast, u, self._ulast)
        lanes = self.lanes
        for i in np.flatnonzero(~fast):
            ln = lanes[i]
            lin = self._linear_ok[i]
            if lin:  # the aircraft's own step and last command, kept here while the batch flew it
                ln.plant.steps = int(self._psteps[i])
                ln.plant._u_last = float(self._ulast[i])  # noqa: SLF001 (where a servo fault's delay line starts)
            ln.u = float(u[i])
            ln.advance()
            if lin:
                self._adopt(int(i))
                self._refresh(int(i))

    def _measure(self) -> None:
        """The ATTITUDE of every lane: from the state rows (roll wrapped, float32), else the lane's own."""
        lin = self._linear_ok
        if lin.any():
            x = self._x
            phi = x[:, 3].copy()
            wrap = lin & ~((phi > -math.pi) & (phi <= math.pi))
            for i in np.flatnonzero(wrap):
                from autopilot.shared.numerics import wrap_pi

                phi[i] = wrap_pi(float(phi[i]))
            f32 = lambda v: v.astype(np.float32).astype(np.float64)  # noqa: E731
            self._phi = np.where(lin, f32(phi), self._phi)
            self._p = np.where(lin, f32(x[:, 1]), self._p)
            self._r = np.where(lin, f32(x[:, 2]), self._r)
            big = np.flatnonzero(lin & ~(np.abs(x) < 1e5).all(axis=1))  # only these can be near the SITL's limit
            for i in big:
                self._diverged(int(i), plants.divergence(x[i]))
        for i in np.flatnonzero(~lin):
            ln = self.lanes[i]
            ln.k = int(self._k[i])
            ln.measure()
            self._phi[i], self._p[i], self._r[i] = ln.phi, ln.p, ln.r
            self._diverged(int(i), ln.diverged())

    def _diverged(self, i: int, why) -> None:
        if why is not None and self._exit[i] is None:
            self._exit[i] = "diverged"

    def _autoreset(self, i: int) -> None:
        self.lanes[i] = self._lane(i, None)
        lanes, self.lanes = self.lanes, [self.lanes[i]]
        saved = {k: v for k, v in self.__dict__.items() if isinstance(v, np.ndarray)}
        self.num_envs = 1
        try:
            self._build()
            row = {k: v for k, v in self.__dict__.items() if isinstance(v, np.ndarray)}
        finally:
            self.num_envs = len(lanes)
            self.lanes = lanes
            self.__dict__.update(saved)
        for key in ("_dt", "_limit", "_weight", "_steps", "_nphys", "_share", "_roll_lim", "_k", "_xm", "_u"):
            getattr(self, key)[i] = row[key][0]
        for key in ("_phi", "_p", "_r", "_ise", "_energy", "_max_u", "_nsat", "_exit", "_block", "_closed"):
            getattr(self, key)[i] = row[key][0]
        self._ref[i] = row["_ref"][0]
        self._bidx[i], self._armed[i], self._ring[i], self._kt[i] = -1, True, 0.0, 0.0
        width = row["_um"].shape[1]
        if width > self._um.shape[1]:
            self._um = np.pad(self._um, ((0, 0), (0, width - self._um.shape[1])))
        self._um[i] = 0.0
        self._um[i, :width] = row["_um"][0]
        lin = bool(row["_linear_ok"][0]) and row["_x"].shape[1] == self._x.shape[1]
        self._linear_ok[i] = lin
        self._plain[i] = False
        if lin:
            self._adopt(i)
            self._refresh(i)

    # ------------------------------------------------------------------------------------------------ out
    def _obs(self) -> np.ndarray:
        um = self._um[np.arange(self.num_envs), self._k]
        return np.stack([self._phi, self._p, self._r, um, self._u], axis=1)

    def _info(self) -> dict:
        dt = self._dt
        return {
            "t": self._k * dt,
            "ise_ref": self._ise * dt,
            "energy": self._energy * dt,
            "saturation": np.where(self._k > 0, self._nsat / np.maximum(self._k, 1), 0.0),
            "max_abs_u": self._max_u.copy(),
            "exit": self._exit.copy(),
            "seed": np.array([ln.seed for ln in self.lanes]),
        }


__all__ = ["RollVectorEnv"]
