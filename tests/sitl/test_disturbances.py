"""Sensor errors, link-fault channels, plant scale factors and the disturbance flags (pure, no processes)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from sitl import disturbances, model
from sitl.aircraft import Aircraft
from sitl.disturbances import Disturbances, Injector, from_values, parse_values, to_argv
from sitl.faults import FaultChannel, FaultConfig, FaultConfigError
from sitl.sensors import SensorConfig, SensorConfigError, Sensors
from sitl.uncertainty import PlantScales, UncertaintyError, draw_scales, parse_scale


# ------------------------------------------------------------------------------------------------ sensors
def test_sensor_delay_and_bias_exact():
    s = Sensors(SensorConfig(roll_bias=0.01, rate_bias=-0.2, delay=3), np.random.default_rng(0))
    truth = [(0.1 * k, 1.0 * k, 2.0 * k) for k in range(10)]
    out = [s.measure(*t) for t in truth]
    for k, (phi, p, r) in enumerate(out):
        j = max(0, k - 3)
        assert (phi, p, r) == (0.1 * j + 0.01, 1.0 * j - 0.2, 2.0 * j)


def test_sensor_noise_seeded_and_sized():
    cfg = SensorConfig(roll_noise=0.02, rate_noise=0.5)
    a = Sensors(cfg, np.random.default_rng(5))
    b = Sensors(cfg, np.random.default_rng(5))
    xa = np.array([a.measure(0.0, 0.0, 0.0)[:2] for _ in range(40000)])
    xb = np.array([b.measure(0.0, 0.0, 0.0)[:2] for _ in range(40000)])
    assert np.array_equal(xa, xb)
    # Sample sd of 40,000 normals: standard error sd/sqrt(2N) = 0.35 %; 4 of them.
    np.testing.assert_allclose(xa.std(axis=0), [0.02, 0.5], rtol=0.014)


def test_sensors_on_a_batch():
    s = Sensors(SensorConfig(roll_bias=0.5, delay=1), np.random.default_rng(0))
    first = s.measure(np.arange(3.0), np.zeros(3), np.zeros(3))
    second = s.measure(np.arange(3.0) + 10, np.zeros(3), np.zeros(3))
    np.testing.assert_array_equal(first[0], np.arange(3.0) + 0.5)
    np.testing.assert_array_equal(second[0], np.arange(3.0) + 0.5)


def test_sensor_config_rejects():
    with pytest.raises(SensorConfigError, match="roll_noise"):
        SensorConfig(roll_noise=-1)
    with pytest.raises(SensorConfigError, match="delay"):
        SensorConfig(delay=1.5)


# ------------------------------------------------------------------------------------------------- faults
def _pattern(cfg: FaultConfig, seed: int, delay=None, n=2000):
    ch = FaultChannel(cfg, np.random.default_rng(seed), delay)
    got = []
    for k in range(n):
        ch.push(k, k)
        got.append(ch.due(k))
    return got, ch.counts


def test_faults_loss_rate_and_counts():
    got, c = _pattern(FaultConfig(loss=0.2), 1, n=20000)
    # Binomial(20000, 0.2): sd 57 packets; 4 sd.
    assert abs(c["lost"] - 4000) < 4 * math.sqrt(20000 * 0.2 * 0.8)
    assert c["sent"] == 20000 and c["delivered"] == 20000 - c["lost"]
    assert sum(len(g) for g in got) == c["delivered"]


def test_faults_delay_duplicate_reorder():
    got, c = _pattern(FaultConfig(delay=3), 0, n=10)
    assert got[:3] == [[], [], []] and got[3:] == [[k] for k in range(7)]
    got, c = _pattern(FaultConfig(duplicate=0.5), 2, n=1000)
    assert c["duplicated"] > 400 and sum(len(g) for g in got) == 1000 + c["duplicated"]
    got, c = _pattern(FaultConfig(reorder=0.3), 3, n=1000)
    flat = [x for g in got for x in g]
    overtaken = sum(1 for a, b in zip(flat, flat[1:]) if b < a)
    assert c["reordered"] > 250 and overtaken > 0
    assert sorted(flat) == list(range(len(flat)))  # nothing lost or made up (a held tail may be pending)


def test_faults_deterministic_per_seed():
    cfg = FaultConfig(loss=0.1, delay=2, duplicate=0.1, reorder=0.1)
    assert _pattern(cfg, 9) == _pattern(cfg, 9)
    assert _pattern(cfg, 9)[0] != _pattern(cfg, 10)[0]


def test_fault_config_rejects():
    with pytest.raises(FaultConfigError, match="loss"):
        FaultConfig(loss=1.0)
    with pytest.raises(FaultConfigError, match="delay"):
        FaultConfig(delay=-0.1)


# ---------------------------------------------------------------------------------------------- uncertainty
# ------------------------------------------------------------------------------------ fault injector: loss
def _lost_indices(loss: float, duplicate: float, n: int, seed: int = 7) -> tuple[set[int], int]:
    """Push packets 0..n-1 through one channel; the indices that never arrive (from what is delivered, not the
    channel's counters) and the number of copies delivered."""
    ch = FaultChannel(FaultConfig(loss=loss, duplicate=duplicate), np.random.default_rng(seed), delay=0)
    delivered = []
    for k in range(n):
        ch.push(k, k)
        delivered += ch.due(k)
    return set(range(n)) - set(delivered), len(delivered)


def test_loss_is_independent_of_the_duplicate_draw():
    n, p = 20_000, 0.2
    bound = 4.0 * math.sqrt(p * (1 - p) / n)  # 4 sigma of a binomial share: fails by chance ~6e-5 of the time
    lost_0, copies_0 = _lost_indices(p, 0.0, n)
    lost_5, copies_5 = _lost_indices(p, 0.5, n)
    assert abs(len(lost_0) / n - p) < bound and abs(len(lost_5) / n - p) < bound
    # the same packets are lost whatever the duplicate probability: each packet's loss draw is its own
    assert lost_0 == lost_5
    # among the packets that arrive, half arrive twice (duplication does not depend on the loss draw either)
    arrived = n - len(lost_5)
    assert abs((copies_5 - arrived) / arrived - 0.5) < 4.0 * math.sqrt(0.25 / arrived)
    assert copies_0 == n - len(lost_0)


def test_plant_scales_matrices():
    s = PlantScales(control=0.5, roll_damping=2.0, dihedral=3.0, yaw_coupling=0.25, servo_wn=2.0, servo_zeta=0.5)
    a, b = s.matrices()
    np.testing.assert_allclose(a[:4, 4], 0.5 * model.B_LP.ravel())
    assert a[1, 1] == 2.0 * -2.22 and a[1, 0] == 3.0 * -40.5
    assert a[1, 2] == 0.25 * 2.48 and a[2, 1] == 0.25 * -2.84
    # Servo: wn -> 2 wn, zeta -> zeta/2: wn^2 x4, 2 zeta wn x1.
    assert a[5, 4] == -4 * model.SERVO_WN2 and b[5, 0] == 4 * model.SERVO_WN2
    assert a[5, 5] == pytest.approx(-model.SERVO_2ZETA_WN)
    untouched = np.ones_like(a, dtype=bool)
    untouched[:4, 4] = untouched[1, :3] = untouched[2, 1] = untouched[5, 4:] = False
    np.testing.assert_array_equal(a[untouched], model.A_P[untouched])
    na, nb = PlantScales().matrices()
    assert np.array_equal(na, model.A_P) and np.array_equal(nb, model.B_P)


def test_scales_drawn_from_ranges_with_seed():
    spec = dict([parse_scale("control=0.5:1.5"), parse_scale("dihedral=2")])
    a = draw_scales(spec, np.random.default_rng(1))
    assert a == draw_scales(spec, np.random.default_rng(1)) != draw_scales(spec, np.random.default_rng(2))
    assert 0.5 <= a.control <= 1.5 and a.dihedral == 2.0 and a.roll_damping == 1.0
    for bad in ("control", "foo=1", "control=0", "control=2:1", "control=a"):
        with pytest.raises(UncertaintyError):
            parse_scale(bad)


# ---------------------------------------------------------------------------------------------- flags
def test_flags_round_trip_and_streams_independent():
    text = {"turbulence": "light", "gust": ["1,10,2"], "scale": ["control=0.8:1.2"], "loss": "0.1", "seed": "4"}
    values = parse_values(text)
    again = parse_values(dict(zip(values, values.values())))
    assert values == again
    argv = to_argv(values)
    assert argv[:2] == ["--turbulence", "light"] and "--loss" in argv and "--seed" in argv
    d = from_values(values)
    assert d.seed == 4 and d.faults.loss == 0.1 and d.atmosphere.gusts[0].amplitude == 1.0
    # Adding a disturbance does not shift another's random stream.
    d2 = from_values({**values, "roll_noise": 0.5})
    assert d.plant_scales() == d2.plant_scales()


def test_flags_reject_one_line():
    for bad in ({"loss": "1"}, {"gust": "1,2"}, {"scale": "x=1"}, {"turbulence": "storm"}):
        with pytest.raises(disturbances.DisturbanceValueError) as exc:
            parse_values(bad)
        assert "\n" not in str(exc.value) and exc.value.field in bad
    with pytest.raises(disturbances.ERRORS):
        from_values({"altitude": 20.0})


def test_injector_lockstep_link_is_a_function_of_frame_and_seed():
    d = Disturbances(faults=FaultConfig(loss=0.3, delay=0.02, duplicate=0.2, reorder=0.2), seed=11)

    def fly():
        inj = Injector(d, 1e-3, 100.0, lockstep=True)
        return [(inj.uplink_frame(k, (k,)), inj.downlink_frame(k, 1500 + k)) for k in range(500)]

    a = fly()
    assert a == fly()
    up = [x[0] for x in a]
    assert up[0] == ((0,), 0) and up[1] == ((0,), 0)  # nothing delivered before the 2-frame delay: hold
    held = [s[0][0] for s in up]
    assert all(h <= max(0, k - 2) for k, h in enumerate(held))  # never newer than the delay allows
    assert len(set(held)) > 200  # but most get through (loss 0.3, and a reordered one is overtaken: ~0.56)
    assert all(b >= a for a, b in zip(held[2:], held[3:]))  # the receiver never goes back in time


def test_injector_plant_and_atmosphere():
    d = from_values({"scale": ["control=0.5"], "crosswind": 1.0})
    inj = Injector(d, 1e-3, 100.0, lockstep=True)
    ac = Aircraft(params=inj.params())
    inj.advance(ac, 0.0, 10)
    assert ac.x[0] != 0.0  # the crosswind pushed the aircraft
    assert Injector(Disturbances(), 1e-3, 100.0, lockstep=True).params() is None


def test_bad_flags_exit_2_with_one_line(capsys):
    from sitl.__main__ import main as sitl_main
    from tools.launch import main as launch_main

    for main, argv, word in (
        (sitl_main, ["--loss", "1.5"], "--loss"),
        (sitl_main, ["--scale", "wing=2"], "--scale"),
        (sitl_main, ["--altitude", "20"], "--altitude"),
        (launch_main, ["--gust", "1,2"], "--gust"),
        (launch_main, ["--sensor-delay", "-1"], "--sensor-delay: must be in [0, 100000] samples"),
    ):
        with pytest.raises(SystemExit) as exc:
            main(argv)
        assert exc.value.code == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and word in err, err


def test_flight_keywords_validated_and_passed_to_the_sitl_only():
    from tools.flight import FlightConfig, FlightConfigError, child_argvs

    cfg = FlightConfig(lockstep=True, gust=["1,10,2", (2.0, 5.0, 3.0)], scale="control=0.5:1.5", loss=0.1, seed=4)
    argvs = child_argvs(cfg, Path("/tmp/x"), 14560, 14550)
    sitl = argvs["sitl"]
    assert sitl[sitl.index("--loss") + 1] == "0.1" and sitl.count("--gust") == 2
    assert sitl[sitl.index("--scale") + 1] == "control=0.5:1.5" and sitl[sitl.index("--seed") + 1] == "4"
    assert "--loss" not in argvs["autopilot"] and "--loss" not in argvs["gcs"]
    assert "--seed" not in child_argvs(FlightConfig(), Path("/tmp/x"), 1, 2)["sitl"]
    with pytest.raises(FlightConfigError) as exc:
        FlightConfig(reorder=1.0)
    assert exc.value.field == "reorder"
    # A disturbed flight is not the paper's reference scenario (summary.json "scenario").
    assert FlightConfig().scenario == FlightConfig(seed=3).scenario == "paper"
    assert FlightConfig(crosswind=1.0).scenario == FlightConfig(loss=0.01).scenario == "custom"


def test_injector_real_time_delays_datagrams_in_wall_seconds():
    inj = Injector(Disturbances(faults=FaultConfig(delay=0.005)), 1e-3, 200.0, lockstep=False)
    assert inj.uplink_raw(10.0, b"a") == [] and inj.downlink(10.001, ("s", 1)) == []
    assert inj.next_due() == pytest.approx(10.005)
    assert inj.uplink_raw(10.0049, None) == [] and inj.uplink_raw(10.005, None) == [b"a"]
    assert inj.downlink(10.006) == [("s", 1)] and inj.next_due() == math.inf
    # Without link faults the datagrams pass straight through.
    plain = Injector(Disturbances(), 1e-3, 200.0, lockstep=False)
    assert plain.uplink_raw(0.0, b"x") == [b"x"] and plain.downlink(0.0, 1) == [1]
