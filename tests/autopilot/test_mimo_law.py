"""The MIMO law behind the one-channel loop (issue 32, stages C and D): ``autopilot.mimo``.  Checked against
independent computations: the PFC of each channel by its exact ZOH by hand, the channel metrics by numpy on the same
samples, AOA_SSA's fast decoder against pymavlink's ardupilotmega dialect."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from autopilot import mimo
from autopilot.params import load_file
from sitl import plant as plants

T = 0.01
OPTIONS = {"attitude_timeout_s": 0.1, "setpoint_timeout_s": 1.0, "max_roll_rad": 1.0}


@pytest.fixture
def values():
    return load_file(plants.shipped("jsbsim-c172x-aileron+rudder.params"))


def test_the_clsac_law_flies_both_channels_with_their_own_pfc(values):
    law = mimo.from_values("clsac", values, control_rate_hz=100.0, limits=(0.305, 0.279))
    ks = [(values["CLSAC_PFC_NUM"], values["CLSAC_PFC_DEN0"]), (values["CLSAC_PFC2_NUM"], values["CLSAC_PFC2_DEN0"])]
    xd = np.zeros(2)
    rng = np.random.default_rng(3)
    for _ in range(300):
        law.y2 = float(rng.normal(0, 0.02))
        u1 = law(float(rng.normal(0, 0.1)), 0.17)
        u = (u1, law.u2)
        assert abs(u1) <= 0.305 and abs(law.u2) <= 0.279
        assert law.Ke.shape == (2, 2)
        for i, (_k, a) in enumerate(ks):
            xd[i] = math.exp(-a * T) * xd[i] + (1 - math.exp(-a * T)) / a * u[i]
    # the next step's y_d of each channel is k_i x_d,i (D_i = k_i/(s + a_i), exact ZOH by hand)
    law.y2 = 0.0
    law(0.0, 0.0)
    assert law.y_pfc == pytest.approx(ks[0][0] * xd[0], abs=1e-12)
    assert float(law.law.y_pfc[1]) == pytest.approx(ks[1][0] * xd[1], abs=1e-12)


def test_a_file_without_the_second_channel_is_refused(values):
    siso = load_file(plants.shipped("jsbsim-c172x.params"))
    with pytest.raises(ValueError, match="CLSAC_PFC2_NUM"):
        mimo.from_values("clsac", siso, control_rate_hz=100.0, limits=(0.3, 0.28))
    with pytest.raises(ValueError, match="PID2_KP"):
        mimo.from_values("baseline", siso, control_rate_hz=100.0, limits=(0.3, 0.28))


def test_the_parameter_table_names_each_channel_and_sets_it(values):
    law = mimo.from_values("clsac", values, control_rate_hz=100.0, limits=(0.305, 0.279))
    table = mimo.param_table(law, OPTIONS)
    names = [n for n, _ in table.items()]
    assert {"CLSAC_PFC_NUM", "CLSAC_PFC2_NUM", "CLSAC_PFC2_DEN0", "CLSAC_LV", "CLSAC_GAM_PE"} <= set(names)
    assert all(len(n) <= 16 for n in names)
    assert table.get("CLSAC_PFC2_DEN0") == values["CLSAC_PFC2_DEN0"]
    table.set("CLSAC_PFC2_NUM", 2.0)
    law.reconfigure(table.config)
    assert law.law._cd[1, 1] == 2.0 and law.law._cd[0, 0] == pytest.approx(values["CLSAC_PFC_NUM"])
    with pytest.raises(ValueError, match="CLSAC_PFC2_DEN0"):
        table.set("CLSAC_PFC2_DEN0", -1.0)
    base = mimo.from_values("baseline", values, control_rate_hz=100.0, limits=(0.305, 0.279))
    bt = mimo.param_table(base, OPTIONS)
    bt.set("CLSAC_PID2_KP", 2.5)  # the name before issue 37: an alias of PID2_KP, listed once by its own name
    assert base.laws[1].config.kp == 2.5 and bt.get("PID2_KP") == 2.5 and bt.get("CLSAC_PID_KP") == 1.0
    assert {"PID_KP", "PID2_KP"} <= {n for n, _ in bt.items()} and not any("CLSAC_PID" in n for n, _ in bt.items())
    bt.set("PID2_KD", 0.5)
    assert base.laws[1].config.kd == 0.5 and bt.get("CLSAC_PID2_KD") == 0.5


def test_the_channel_metrics_are_the_sums_of_their_samples():
    rng = np.random.default_rng(5)
    acc = mimo.ChannelMetrics(T, (0.3, 0.28))
    rows = []
    from autopilot.step import Failsafe

    for _ in range(500):
        phi, beta, u, u2 = rng.normal(0, 0.1, 4)
        ym1, ym2 = rng.normal(0, 0.1, 2)
        sat1, sat2 = bool(rng.random() < 0.1), bool(rng.random() < 0.2)
        ctrl = SimpleNamespace(y2=beta, ym_ol=ym1, ym_ol2=ym2, u2=u2, saturated=sat1, sat2=sat2, frozen=False)
        acc(SimpleNamespace(result=SimpleNamespace(phi=phi, u=u, failsafe=Failsafe.NONE), ctrl=ctrl))
        rows.append((phi, beta, u, u2, ym1, ym2, sat1, sat2))
    a = np.array(rows, dtype=float)
    r = acc.result()
    roll, side = r["channels"]
    assert roll["metrics"]["ise_ref"] == pytest.approx(np.sum((a[:, 0] - a[:, 4]) ** 2) * T)
    assert side["metrics"]["ise_ref"] == pytest.approx(np.sum((a[:, 1] - a[:, 5]) ** 2) * T)
    assert side["metrics"]["tv"] == pytest.approx(np.sum(np.abs(np.diff(a[:, 3]))))
    assert side["metrics"]["energy"] == pytest.approx(np.sum(a[:, 3] ** 2) * T)
    assert r["max_abs_sideslip_deg"] == pytest.approx(math.degrees(np.max(np.abs(a[:, 1]))))
    assert r["saturated_fraction"]["rudder"] == pytest.approx(np.mean(a[:, 7]))
    assert r["within_envelope"] == (r["max_abs_sideslip_deg"] <= 10.0)


def test_aoa_ssa_decodes_as_pymavlink_s_ardupilotmega_does():
    from pymavlink.dialects.v20 import ardupilotmega

    from autopilot.shared.fastmav import AOA_SSA, AOA_SSA_ID, FAST_DECODERS, FastPacker

    raw = FastPacker(AOA_SSA, 1, 200)(7, 123456, 2.5, -1.25)
    ref = ardupilotmega.MAVLink(None).decode(bytearray(raw))
    got = FAST_DECODERS[AOA_SSA_ID](raw)
    assert ref.get_type() == "AOA_SSA" and (got.time_usec, got.AOA, got.SSA) == (ref.time_usec, ref.AOA, ref.SSA)
    assert got.SSA == -1.25


def test_a_csv_profile_s_third_column_is_the_sideslip_command(tmp_path):
    from tools.flight.profiles import Profile, ProfileError, from_csv

    f = tmp_path / "p.csv"
    f.write_text("time_s, roll_deg, sideslip_deg\n0, 10, 0\n10, -10, 3\n20, 0\n")
    p = Profile.from_csv(str(f))
    assert p.has_sideslip and p.sideslip(12.0) == pytest.approx(math.radians(3.0)) and p.sideslip(25.0) == 0.0
    assert from_csv(str(f))[1][1] == pytest.approx(math.radians(-10.0))  # the two-column reader is unchanged
    two = tmp_path / "two.csv"
    two.write_text("0, 10\n10, -10\n")
    assert not Profile.from_csv(str(two)).has_sideslip
    f.write_text("0, 10, 45\n")
    with pytest.raises(ProfileError, match="sideslip must be in"):
        Profile.from_csv(str(f))


@pytest.mark.parametrize("deg, ok", [(10.0, True), (-10.0, True), (10.5, False), (-30.0, False), (45.0, False)])
def test_a_sideslip_setpoint_past_the_sideslip_envelope_is_refused_where_it_is_written(tmp_path, deg, ok):
    """Issue 35: a sideslip setpoint up to +-30 deg was taken while the sideslip envelope is 10 deg; a setpoint the
    verdict would call out of the envelope is refused on the command line and in a CSV, with the range."""
    from tools.flight.profiles import Profile, ProfileError

    f = tmp_path / "p.csv"
    f.write_text(f"0, 10, {deg}\n10, -10, 0\n")
    if ok:
        assert Profile.from_csv(str(f)).sideslip(1.0) == pytest.approx(math.radians(deg))
        return
    with pytest.raises(ProfileError, match=r"p\.csv:1: sideslip must be in \[-10, 10\] deg \(the sideslip envelope\)"):
        Profile.from_csv(str(f))


def test_the_gcs_script_refuses_a_sideslip_past_the_envelope_in_one_line(capsys):
    from tools import gcs

    with pytest.raises(SystemExit) as exc:
        gcs.main(["--sideslip", "12"])
    err = capsys.readouterr().err.strip()
    assert exc.value.code == 2 and len(err.splitlines()) == 1
    assert "--sideslip: the sideslip command must be in [-10, 10] deg (the sideslip envelope), got 12" in err


def test_a_sideslip_setpoint_from_a_ground_station_is_clamped_to_the_envelope(values):
    """Over MAVLink (NAMED_VALUE_FLOAT SSA_SP, real datagrams on the real GCS link of an in-process autopilot):
    clamped to +-10 deg as a roll setpoint is to the roll limit, counted and said; NaN refused."""
    import os
    import socket

    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink.dialects.v20 import common as M

    from autopilot.loop import Autopilot, AutopilotOptions
    from autopilot.shared.pwm import PwmMap

    law = mimo.from_values("clsac", values, control_rate_hz=100.0, limits=(0.3, 0.25))
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    where = sock.getsockname()  # its streams to this station, none to the default ports
    opts = AutopilotOptions(lockstep=False, signing_key=None, verbose=False, gcs=where, sitl=where)
    ap = Autopilot(opts, law.config, PwmMap(), law=law, pwm2=PwmMap())
    mav = M.MAVLink(None, 255, 190)
    try:
        for value in (25.0, -12.0, 7.5, float("nan")):
            before = ap.gcs.rx_datagrams
            sock.sendto(M.MAVLink_named_value_float_message(0, b"SSA_SP", value).pack(mav), ap.gcs.local)
            while ap.gcs.rx_datagrams == before:
                ap.gcs.poll(ap._gcs_handler)
            if value == value:
                expect = max(-10.0, min(10.0, value))
                assert ap.setpoints2.at(0.0) == pytest.approx(math.radians(expect)), value
        assert ap.events["sideslip_setpoints_clamped"] == 2 and ap.events["sideslip_setpoints"] == 3
        assert ap.gcs.counters()["rejected"].get("nonfinite_setpoint") == 1
    finally:
        sock.close()
        ap.close()


def test_the_monte_carlo_flies_the_mimo_plant_with_its_controllers():
    from tools.experiment.study.flights import FlightOptions, fly_study_flight

    opts = FlightOptions("jsbsim:c172x:surface=aileron+rudder", turbulence=("none",), seeds=1)
    flights = opts.flights()
    assert [f.controller for f in flights] == ["sac", "clsac", "baseline"]  # pid-ff is not flown on it
    r = fly_study_flight(flights[1])
    assert r["bounded"] and 0.0 < r["max_abs_sideslip"] < math.radians(10.0) and r["rudder_sat_fraction"] == 0.0


def _controlled(ok=True, reason="controlled: max |roll| 12.5 deg"):
    return {
        "ok": ok,
        "checked": True,
        "reason": reason,
        "limits": {"max_abs_roll_deg": 60.0, "max_saturated_share": 0.2},
    }


def _side(beta, rudder):
    return {
        "max_abs_sideslip_deg": beta,
        "envelope_deg": 10.0,
        "saturated_fraction": {"aileron": 0.0, "rudder": rudder},
    }


def test_the_verdict_takes_the_sideslip_channel_at_its_limits():
    from autopilot.mimo import with_sideslip

    ok = with_sideslip(_controlled(), _side(10.0, 0.199))  # at the envelope's edge, just under the share: in
    assert ok["ok"] and ok["sideslip_ok"]
    assert ok["reason"].endswith("; sideslip: max |sideslip| 10.0 deg, rudder saturated 19.9 % of the flight "
                                 "(limits 10 deg, 20 %)")  # fmt: skip
    out = with_sideslip(_controlled(), _side(10.05, 0.0))
    assert not out["ok"] and out["reason"] == "|sideslip| reached 10.1 deg (limit 10)"
    sat = with_sideslip(_controlled(), _side(1.0, 0.2))  # strict, as for the aileron
    assert not sat["ok"] and sat["reason"] == "rudder saturated 20.0 % of the flight (limit 20 %)"
    nan = with_sideslip(_controlled(), _side(float("nan"), 0.0))
    assert not nan["ok"]
    both = with_sideslip(_controlled(False, "|roll| reached 70.0 deg (limit 60)"), _side(12.0, 0.5))
    assert not both["ok"] and both["reason"] == (
        "|roll| reached 70.0 deg (limit 60); |sideslip| reached 12.0 deg (limit 10); rudder saturated 50.0 % of the "
        "flight (limit 20 %)"
    )
    unchecked = {"ok": True, "checked": False, "reason": "not checked"}
    assert with_sideslip(unchecked, _side(50.0, 1.0)) is unchecked


# ---------------------------------------------------------------------------------------- the second channel alone
# The two surfaces have different limits (the c172x's aileron 0.305 rad, rudder 0.279): each test drives one channel
# where the other does not go, so a second channel that reads the first's flag, limit or command is caught.
LIMITS = (0.305, 0.279)


@pytest.mark.parametrize("kind", ["clsac", "baseline"])
def test_each_surface_saturates_at_its_own_limit_and_says_so_on_its_own_flag(values, kind):
    """A 1 rad sideslip error, no roll error: the rudder's command is exactly at the rudder's limit (0.279, not the
    aileron's 0.305), its flag is set, the aileron's is not and its command is 0.  Then the other way round: a 1 rad
    roll error, no sideslip: the aileron at 0.305 with its flag, the rudder at 0 without."""
    law = mimo.from_values(kind, values, control_rate_hz=100.0, limits=LIMITS)
    law.y2, law.um2 = 1.0, 0.0
    u1 = law(0.0, 0.0)
    assert abs(law.u2) == LIMITS[1] and law.sat2 is True
    assert u1 == 0.0 and law.saturated is False
    row = dict(zip(mimo.MIMO_FIELDS, law.mimo_row()))
    assert row["sat2"] is True and abs(row["u2"]) == LIMITS[1]
    law = mimo.from_values(kind, values, control_rate_hz=100.0, limits=LIMITS)
    law.y2, law.um2 = 0.0, 0.0
    u1 = law(1.0, 0.0)
    assert abs(u1) == LIMITS[0] and law.saturated is True
    assert law.u2 == 0.0 and law.sat2 is False


@pytest.mark.parametrize("kind", ["clsac", "baseline"])
def test_the_channel_metrics_count_each_surfaces_saturation_on_its_own(values, kind):
    """Ten steps with the rudder at its limit and the aileron free: the rudder's saturated share is 1, the aileron's
    0, and the largest rudder command the rudder's limit (hand count: every step)."""
    law = mimo.from_values(kind, values, control_rate_hz=100.0, limits=LIMITS)
    metrics = mimo.ChannelMetrics(T, LIMITS)
    from autopilot.step import Failsafe

    for _ in range(10):
        law.y2 = 1.0
        u = law(0.0, 0.0)
        metrics(SimpleNamespace(result=SimpleNamespace(failsafe=Failsafe.NONE, phi=0.0, u=u), ctrl=law))
    side = metrics.result()
    assert side["saturated_fraction"] == {"aileron": 0.0, "rudder": 1.0}
    assert side["channels"][1]["metrics"]["max_abs_u"] == LIMITS[1]


@pytest.mark.parametrize("kind", ["clsac", "baseline"])
def test_in_a_hold_the_rudder_goes_neutral_while_the_aileron_takes_what_is_applied(values, kind):
    """After 50 steps with a sideslip error (the rudder deflected), a failsafe hold applying 0.1 rad to the aileron:
    the rudder's command is 0 (neutral), not the command it held nor the aileron's 0.1, in the law and in its
    telemetry row; for CL-SAC the rudder's PFC state decays as its exact ZOH with zero input,
    x_d <- exp(-a2 T) x_d (D_2 = k_2/(s + a_2)), and the aileron's follows 0.1."""
    law = mimo.from_values(kind, values, control_rate_hz=100.0, limits=LIMITS)
    for _ in range(50):
        law.y2 = 0.2
        law(0.0, 0.0)
    assert abs(law.u2) > 1e-3  # deflected before the hold
    xd = None if kind != "clsac" else np.array(law.law.xd, dtype=float).ravel().copy()
    law.hold(0.1)
    assert law.u2 == 0.0 and law.u == 0.1 and law.frozen
    assert dict(zip(mimo.MIMO_FIELDS, law.mimo_row()))["u2"] == 0.0
    if xd is not None:
        a1, a2 = values["CLSAC_PFC_DEN0"], values["CLSAC_PFC2_DEN0"]
        after = np.array(law.law.xd, dtype=float).ravel()
        assert after[1] == pytest.approx(math.exp(-a2 * T) * xd[1], rel=1e-12, abs=1e-15)
        expect1 = math.exp(-a1 * T) * xd[0] + (1 - math.exp(-a1 * T)) / a1 * 0.1
        assert after[0] == pytest.approx(expect1, rel=1e-12, abs=1e-15)
