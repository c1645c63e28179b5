"""The envelope of a controlled flight (autopilot.envelope): its boundaries against series whose maximum, saturated
share and exit times are known in closed form, its one-announcement-per-excursion rule, and the same definition in
the study's batch form."""

from __future__ import annotations

import math
import re
import subprocess
import sys

import numpy as np
import pytest

from autopilot.envelope import (
    ROLL_REARM_DEG,
    SHARE_MIN_S,
    Envelope,
    EnvelopeError,
    EnvelopeMonitor,
    judge,
    judge_series,
    saturated,
    within,
)

LIM = math.radians(30.0)  # the rudder limit of the paper
RATE = 100.0
DT = 1.0 / RATE


def _t(seconds: float) -> np.ndarray:
    return np.arange(int(round(seconds * RATE))) * DT


# ------------------------------------------------------------------------------------------- saturated
def test_saturated_is_at_the_limit_either_side_or_not_finite():
    assert saturated(LIM, LIM) and saturated(-LIM, LIM) and saturated(2 * LIM, LIM)
    assert saturated(math.nan, LIM) and saturated(math.inf, LIM)
    assert not saturated(LIM * (1 - 2e-9), LIM) and not saturated(0.0, LIM) and not saturated(-0.9 * LIM, LIM)
    u = np.array([LIM, -LIM, LIM * (1 - 2e-9), 0.0, np.nan, -LIM * (1 - 0.5e-9)])
    assert saturated(u, LIM).tolist() == [True, True, False, False, True, True]


def test_saturated_equals_the_laws_own_clip_flag():
    """What the study counted before (``u != u_raw`` of np.clip) is what ``saturated`` says of the clipped u."""
    rng = np.random.default_rng(7)
    u_raw = rng.normal(0.0, LIM, 100_000)
    u_raw[:3] = [np.nan, LIM, -LIM]  # NaN counts as saturated in both; exactly at the limit is not clipped
    u = np.clip(u_raw, -LIM, LIM)
    clip_flag = u != u_raw
    assert np.array_equal(saturated(u, LIM)[3:], clip_flag[3:]) and saturated(u, LIM)[0] and clip_flag[0]


# ------------------------------------------------------------------------------------------- boundaries
@pytest.mark.parametrize(
    ("roll_deg", "share", "ok"),
    [(59.999, 0.0, True), (60.0, 0.0, False), (0.0, 0.1999, True), (0.0, 0.2, False), (61.0, 0.5, False)],
)
def test_limits_are_strict(roll_deg, share, ok):
    assert bool(within(math.radians(roll_deg), share)) is ok
    assert judge(math.radians(roll_deg), share, samples=100).ok is ok


def test_within_is_elementwise_on_a_batch():
    roll = np.radians([10.0, 60.0, 59.9, np.nan, 10.0])
    share = np.array([0.0, 0.0, 0.19, 0.0, np.nan])
    assert within(roll, share).tolist() == [True, False, True, False, False]
    env = Envelope(max_roll_deg=10.0, max_saturated_share=0.5)
    assert within(roll, share, env).tolist() == [False, False, False, False, False]
    assert within(np.radians([9.0]), np.array([0.49]), env).tolist() == [True]


def test_sine_roll_exits_when_and_where_the_closed_form_says():
    """roll = 70 deg sin(2 pi t / 4 s): max 70 deg at t = 1 s (a sample); |roll| first >= 60 deg at
    t* = asin(6/7) 4 / (2 pi) s, i.e. at the first sample on or after t*."""
    t = _t(30.0)
    roll = np.radians(70.0) * np.sin(2 * np.pi * t / 4.0)
    res = judge_series(t, roll, np.zeros_like(t), LIM)
    t_star = math.asin(60.0 / 70.0) * 4.0 / (2 * math.pi)
    k_first = math.ceil(t_star * RATE)
    assert not res.ok and res.max_abs_roll_deg == pytest.approx(70.0, abs=1e-9)
    assert res.first_exit_s == pytest.approx(k_first * DT, abs=1e-12) and res.saturated_share == 0.0
    assert res.reason == f"|roll| reached 70.0 deg (limit 60; first past it at {k_first * DT:.1f} s)"
    assert judge_series(t, roll, np.zeros_like(t), LIM, Envelope(max_roll_deg=70.5)).ok


@pytest.mark.parametrize(("n_sat", "ok"), [(599, True), (600, False)])
def test_saturated_share_at_the_boundary(n_sat, ok):
    """3000 steps, the first ``n_sat`` at the limit: share n_sat / 3000, against 20 % = 600 steps exactly."""
    t = _t(30.0)
    u = np.where(np.arange(len(t)) < n_sat, -LIM, 0.1 * LIM)
    res = judge_series(t, np.zeros_like(t), u, LIM)
    assert res.ok is ok and res.saturated_share == n_sat / 3000
    if not ok:
        # the running share is 1 until step 600, so it is over the limit from the first judged time on
        assert res.first_exit_s == pytest.approx(SHARE_MIN_S) and res.max_abs_roll_deg == 0.0
        assert res.reason == "rudder saturated 20.0 % of the flight (limit 20 %)"
    else:
        assert res.first_exit_s is None and res.reason.startswith("controlled: max |roll| 0.0 deg, rudder saturated")


def test_late_saturation_exits_when_the_running_share_reaches_the_limit():
    """Unsaturated for 20 s, then saturated: the running share (k - 2000 + 1) / (k + 1) reaches 0.25 first at
    k + 1 = 2000 / 0.75, i.e. k = ceil(2000 / 0.75) - 1, with limit 25 %."""
    t = _t(40.0)
    u = np.where(t >= 20.0 - 1e-9, LIM, 0.0)
    res = judge_series(t, np.zeros_like(t), u, LIM, Envelope(max_saturated_share=0.25))
    k = math.ceil(2000 / 0.75) - 1
    assert not res.ok and res.saturated_share == 0.5
    assert res.first_exit_s == pytest.approx(k * DT, abs=1e-12)


def test_a_flight_shorter_than_the_share_window_is_judged_at_its_end():
    t = _t(2.0)
    res = judge_series(t, np.zeros_like(t), np.full_like(t, LIM), LIM)
    assert not res.ok and res.saturated_share == 1.0 and res.first_exit_s == pytest.approx(t[-1])


def test_exit_times_are_flight_time_from_the_first_sample():
    t = 100.0 + _t(10.0)  # a SITL clock that did not start at 0
    roll = np.where(t >= 103.0, math.radians(65.0), 0.0)
    assert judge_series(t, roll, np.zeros_like(t), LIM).first_exit_s == pytest.approx(3.0)


def test_judge_series_agrees_with_numpy_on_a_random_flight():
    rng = np.random.default_rng(3)
    t = _t(30.0)
    roll = np.radians(40.0) * rng.standard_normal(len(t))
    u = np.clip(rng.normal(0.0, LIM, len(t)), -LIM, LIM)
    res = judge_series(t, roll, u, LIM)
    assert res.max_abs_roll_deg == pytest.approx(np.degrees(np.max(np.abs(roll))), rel=1e-12)
    assert res.saturated_share == np.mean(np.abs(u) >= LIM)
    assert res.ok is bool(within(np.max(np.abs(roll)), np.mean(np.abs(u) >= LIM)))


def test_check_off_is_always_controlled_but_still_measured():
    t = _t(30.0)
    res = judge_series(t, np.full_like(t, math.radians(90.0)), np.full_like(t, LIM), LIM, Envelope(check=False))
    assert res.ok and res.first_exit_s is None and res.max_abs_roll_deg == pytest.approx(90.0)
    assert res.reason == "not checked: max |roll| 90.0 deg, rudder saturated 100.0 % of the flight"
    assert res.to_dict()["checked"] is False


def test_nothing_flown_is_not_controlled():
    res = EnvelopeMonitor().result()
    assert not res.ok and res.samples == 0 and res.reason == "no control step was flown"


# ------------------------------------------------------------------------------------------- announcements
def _announcements(roll_deg, u=None, env=Envelope()):
    mon = EnvelopeMonitor(env)
    u = np.zeros(len(roll_deg)) if u is None else u
    texts = [mon.add(k * DT, math.radians(r), float(uk), LIM) for k, (r, uk) in enumerate(zip(roll_deg, u))]
    return [(k, s) for k, s in enumerate(texts) if s is not None], mon


def test_each_roll_excursion_is_announced_once():
    """Three separate excursions over 60 deg (back to 0 in between): three texts, at their first samples; chatter
    around the limit that never comes back ROLL_REARM_DEG inside is one excursion."""
    roll = np.zeros(1000)
    for start in (100, 400, 700):
        roll[start : start + 50] = 65.0
    roll[401:440:2] = 59.0  # chatter inside the first 5 deg of the limit: not a new excursion
    said, mon = _announcements(roll)
    assert [k for k, _ in said] == [100, 400, 700] and mon.excursions == 3
    assert said[0][1] == "ENVELOPE: |roll| 65.0 deg >= 60 at 1.0 s" and len(said[0][1]) <= 50
    chatter = np.tile([61.0, 60.0 - ROLL_REARM_DEG + 0.1], 200)
    assert len(_announcements(chatter)[0]) == 1
    assert len(_announcements(np.tile([61.0, 60.0 - ROLL_REARM_DEG - 0.1], 200))[0]) == 200


def test_saturation_is_announced_once_when_the_running_share_crosses():
    u = np.full(3000, LIM)  # saturated throughout: share 1 from the start, announced at SHARE_MIN_S only
    said, _ = _announcements(np.zeros(3000), u)
    assert [k for k, _ in said] == [round(SHARE_MIN_S * RATE)]
    assert said[0][1] == f"ENVELOPE: rudder saturated 100% >= 20% at {SHARE_MIN_S:.0f} s" and len(said[0][1]) <= 50


def test_nothing_is_announced_with_the_check_off_or_inside():
    said, _ = _announcements(np.full(1000, 80.0), np.full(1000, LIM), Envelope(check=False))
    assert said == []
    assert _announcements(np.full(1000, 59.9), np.zeros(1000))[0] == []


# ------------------------------------------------------------------------------------------- bad limits
@pytest.mark.parametrize(
    ("kw", "text"),
    [
        ({"max_roll_deg": 0.0}, "max_roll_deg must be in (0, 180] deg, got 0.0"),
        ({"max_roll_deg": 180.5}, "max_roll_deg must be in (0, 180] deg, got 180.5"),
        ({"max_roll_deg": math.nan}, "max_roll_deg must be in (0, 180] deg, got nan"),
        ({"max_saturated_share": 0.0}, "max_saturated_share must be in (0, 1], got 0.0"),
        ({"max_saturated_share": 1.5}, "max_saturated_share must be in (0, 1], got 1.5"),
    ],
)
def test_limits_out_of_range_are_refused(kw, text):
    with pytest.raises(EnvelopeError, match=re.escape(text)):
        Envelope(**kw)


@pytest.mark.parametrize(
    ("flag", "value", "allowed"),
    [("--envelope-roll", "0", "(0, 180] deg"), ("--envelope-roll", "1e9", "(0, 180] deg")]
    + [("--envelope-saturated", "0", "(0, 100] %"), ("--envelope-saturated", "nan", "(0, 100] %")],
)
@pytest.mark.parametrize("prog", ["tools.launch", "autopilot"])
def test_bad_envelope_flags_are_one_line_exit_2(prog, flag, value, allowed):
    r = subprocess.run([sys.executable, "-m", prog, flag, value], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and r.stdout == "", r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and flag in lines[0] and f"must be in {allowed}, got {value!r}" in lines[0], lines


def test_flight_keywords_are_bounded_like_the_flags():
    from tools.flight import Flight, FlightConfigError

    with pytest.raises(FlightConfigError, match=r"envelope_roll: must be in \(0, 180\] deg, got 200") as e:
        Flight(envelope_roll=200)
    assert e.value.field == "envelope_roll"
    with pytest.raises(FlightConfigError, match=r"envelope_saturated: must be in \(0, 100\] %"):
        Flight(envelope_saturated=-1)
    cfg = Flight(envelope_roll=45, envelope_saturated=5, envelope=False).config
    assert cfg.flight_envelope == Envelope(45.0, 0.05, check=False)


# ------------------------------------------------------------------------------- a flight the law did not fly
def _disarmed_flight(steps: int, law_steps, rate: float = 100.0):
    """A level flight of ``steps`` control steps that the law flew at the steps in ``law_steps`` (tracking the
    command exactly) and that a ground station had disarmed at all others."""
    from autopilot.envelope import EnvelopeMonitor

    mon = EnvelopeMonitor()
    law = set(law_steps)
    for k in range(steps):
        flew = k in law
        mon.add(k / rate, 0.05, 0.0, math.radians(30), 0.05 if flew else None, armed=flew)
    return mon.result()


def test_a_flight_disarmed_for_most_of_its_length_is_not_ok_and_every_clause_is_true():
    """Issue 35: a keyed DISARM for 97 % of a 300 s flight ended "OK (disarmed ... by a ground station)", with the
    clause "tracking not judged (flown 300.0 s, shorter than a 20 s window)".  Here the law flies the first 9 s of
    30,000 steps: 900 / 30000 = 3.0 % of the flight."""
    c = _disarmed_flight(30000, range(900))
    assert not c.ok
    assert c.reason == "the law flew only 3.0 % of the flight (limit: more than 50 %; a ground station had the rest)"
    assert c.ground_station["disarmed_s"] == pytest.approx(291.0)
    assert "shorter than" not in c.reason and c.tracking.law_s == pytest.approx(9.0)


@pytest.mark.parametrize(("law_steps", "ok"), [(1501, True), (1500, False), (1499, False)])
def test_the_ground_station_s_share_is_strict_at_half(law_steps, ok):
    """Of 3000 steps: the ground station at exactly half (1500) is out, as every limit of the envelope is strict."""
    c = _disarmed_flight(3000, range(law_steps))
    assert c.ok is ok, c.reason
    assert c.ground_station["disarmed_share"] == (3000 - law_steps) / 3000


def test_tracking_not_judged_says_how_long_the_law_flew_when_the_flight_was_longer():
    """Law 16 s, then disarmed 14 s (47 %: controlled): no 20 s window of the law, and the reason says that, not that
    the 30 s flight was shorter than a window."""
    c = _disarmed_flight(3000, range(1600))
    assert c.ok and not c.tracking.judged
    why = "tracking not judged (the law flew 16.0 s of the 30.0 s flight, less than a 20 s window)"
    assert c.reason.endswith("; " + why)


# ------------------------------------------------------------------------------------------- bounded, twice
DEG = math.pi / 180.0


@pytest.mark.parametrize(
    "roll_deg, sat, ok",
    [(59.99, 0.1999, True), (60.0, 0.1, False), (59.99, 0.2, False), (61.0, 0.3, False), (10.0, 0.0, True)],
)
def test_the_per_flight_study_needs_both_bounds_strictly(roll_deg, sat, ok):
    """The per-flight study's (JSBSim aircraft, plant files: ``tools.experiment.study.flights``) bounded is
    ``autopilot.envelope.judge_series``'s ``ok``: max |roll| < 60 deg AND saturated < 20 %, both strict (mutations:
    ``and`` -> ``or``; ``<`` -> ``<=``), here on a 10 000-step series built with exactly that peak and share."""
    from autopilot.envelope import judge_series

    n, lim = 10_000, math.radians(30.0)
    t = np.arange(n) / 100.0
    roll = np.full(n, 10.0 * DEG)
    roll[n // 2] = roll_deg * DEG
    u = np.zeros(n)
    u[: round(sat * n)] = lim  # the command at its limit on exactly this share of the steps
    assert judge_series(t, roll, u, lim).ok is ok


@pytest.mark.parametrize(
    "roll_deg, sat, ok", [(59.99, 0.1999, True), (60.0, 0.1, False), (59.99, 0.2, False), (61.0, 0.1, False)]
)
def test_the_envelope_inequalities_elementwise(roll_deg, sat, ok):
    """``autopilot.envelope.within``, which the study's ``bounded`` is, at its edges, on arrays as on floats."""
    from autopilot.envelope import within

    assert bool(within(roll_deg * DEG, sat)) is ok
    assert within(np.array([roll_deg * DEG, 1.0 * DEG]), np.array([sat, 0.0])).tolist() == [ok, True]


def test_the_monitors_step_is_the_elementwise_functions_sample_by_sample():
    """The monitor writes out ``stop_hit``, ``swing_step`` and ``block_add`` on floats (once per control step); the
    same flight fed through the functions, sample by sample, must leave the same blocks, counters and verdict, to
    the bit: a saturating command (stop hits), a regular +-6 deg oscillation (swings), noise, and a NaN roll."""
    import pickle

    from autopilot import envelope as env
    from autopilot.swings import swing_start, swing_step

    class ByTheFunctions(EnvelopeMonitor):
        def _track(self, ft, roll, ref, u, u_limit, sat):
            j = int(math.floor(ft / env.TRACK_BLOCK_S + 1e-6))
            text = None
            if j != self._block_index:
                if self._block is not None:
                    text = self._close(j)
                self._block, self._block_index = env._empty_block(), j
            b = self._block
            d = roll - ref
            hit, self._hit_armed = env.stop_hit(bool(sat), u, u_limit, self._hit_armed)
            if self._swing is None:
                self._swing = swing_start(float(d))
            env.block_add(b, roll, ref, d, hit, bool(swing_step(self._swing, float(d), float(self._k))), bool(sat))
            self._k += 1
            if self._d_prev is not None and ft > self._ft_prev:
                rate = (d - self._d_prev) / (ft - self._ft_prev)
                b[env._DOT2] += rate * rate
                b[env._NDOT] += 1
            if b[env._N] == 1:
                b[env._T0] = ft
            b[env._T1] = ft
            self._d_prev, self._ft_prev = d, ft
            return text

    rng = np.random.default_rng(7)
    t = _t(70.0)
    ref = np.radians(10.0) * np.sign(np.sin(2 * np.pi * t / 20.0))
    roll = ref + np.radians(6.0) * np.sin(2 * np.pi * 0.8 * t) + np.radians(0.3) * rng.standard_normal(len(t))
    roll[3000] = math.nan
    u = np.clip(1.4 * LIM * np.sin(2 * np.pi * 0.8 * t + 0.3), -LIM, LIM)
    mons = EnvelopeMonitor(), ByTheFunctions()
    samples = list(zip(t.tolist(), roll.tolist(), u.tolist(), ref.tolist()))
    texts = [[m.add(ti, ri, ui, LIM, yi) for ti, ri, ui, yi in samples] for m in mons]
    assert texts[0] == texts[1] and any(texts[0])
    res = [m.result() for m in mons]
    assert res[0].tracking.max_swings >= 16 and res[0].tracking.oscillating_windows > 0
    assert pickle.dumps(res[0].to_dict()) == pickle.dumps(res[1].to_dict())
    state = [{k: v for k, v in vars(m).items()} for m in mons]
    assert pickle.dumps(state[0]) == pickle.dumps(state[1])
