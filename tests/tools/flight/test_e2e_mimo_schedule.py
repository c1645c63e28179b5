"""A square MIMO plant's sideslip setpoints in lockstep (issue 32): each SSA_SP rides in the roll's linked datagram,
just before the roll point of its time (``tools.gcs._send_linked``), and shares that point's verdict
(``autopilot.schedule``).  A relay between the GCS script and the autopilot drops 40 % of the datagrams that carry
SSA_SP (seeded): the GCS script sends them again as it sends the roll's, and the flight is, bit for bit, the flight
through a relay that drops nothing: the roll metrics, every AOA_SSA the autopilot took (the sideslip the rudder
flew to) and the count of sideslip setpoints queued.  Three real processes over UDP, signed, the JSBSim c172x."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from tests._mavlink_procs import Proc, free_ports, load_json
from tests._udp_relay import DroppingRelay

pytestmark = pytest.mark.e2e
PLANT = "jsbsim:c172x:surface=aileron+rudder"
NAMED_VALUE_FLOAT = 251
PROFILE = "time_s, roll_deg, sideslip_deg\n0, 10, 0\n3, -10, 3\n6, 5, -2\n8, 5, -2\n"


def _swap(argv: list[str], flag: str, value: str) -> None:
    argv[argv.index(flag) + 1] = value


def _flight(out: Path, drop: float, seed: int) -> dict:
    from tools.flight.command_lines import child_argvs
    from tools.flight.config import FlightConfig

    out.mkdir(parents=True)
    csv = out / "profile.csv"
    csv.write_text(PROFILE)
    cfg = FlightConfig(lockstep=True, duration=8.0, plant=PLANT, out=str(out), csv=str(csv), series=True)
    sitl_p, gcs_p, ap_sitl_p, ap_gcs_p = free_ports(4)
    key = out / "signing.key"  # signed, as the launcher flies: each packet's timestamp must increase in its datagram
    key.write_text(os.urandom(32).hex())
    key.chmod(0o600)
    argvs = child_argvs(cfg, out, sitl_p, gcs_p, key_file=key, ap_ports=(ap_sitl_p, ap_gcs_p))
    relay = DroppingRelay(ap_gcs_p, gcs_p, NAMED_VALUE_FLOAT, drop, seed)  # the schedule's SSA_SP
    ra, rb = "%s:%d" % relay.a.getsockname(), "%s:%d" % relay.b.getsockname()
    ap, gcs = argvs["autopilot"], argvs["gcs"]
    _swap(ap, "--gcs", ra)
    _swap(ap, "--gcs-peer", ra)
    _swap(gcs, "--vehicle", rb)
    procs = [Proc(a[3], a[4:], out / f"{name}.log") for name, a in (("sitl", argvs["sitl"]), ("gcs", gcs),
                                                                       ("autopilot", ap))]  # fmt: skip
    try:
        codes = [p.p.wait(180) for p in reversed(procs)]
    finally:
        for p in procs:
            p.stop(5)
        relay.close()
    import numpy as np

    series = np.load(out / "autopilot_series.npz")
    return {
        "codes": codes,
        "ap": load_json(out / "autopilot.json"),
        "gcs": load_json(out / "gcs.json"),
        "relay": (relay.matched, relay.dropped),
        "beta": series["beta"].copy(),
        "um2": series["um2"].copy(),
        "logs": {p.log.name: p.output()[-1500:] for p in procs},
    }


def test_sideslip_setpoints_lost_in_lockstep_are_sent_again_and_change_no_bit(tmp_path):
    clean = _flight(tmp_path / "clean", 0.0, 1)
    lossy = _flight(tmp_path / "lossy", 0.4, 7)
    for run in (clean, lossy):
        assert run["codes"][0] == 0 and run["codes"][1] == 0, (run["codes"], run["logs"])
        assert run["ap"]["steps"] == 800 and run["ap"]["exit_reason"].startswith("end of run")
    assert clean["relay"][0] >= 5 and clean["relay"][1] == 0 and clean["gcs"]["schedule_resends"] == 0
    assert lossy["relay"][1] >= 5 and lossy["gcs"]["schedule_resends"] >= 1, (lossy["relay"], lossy["gcs"])
    ev_c, ev_l = clean["ap"]["events"], lossy["ap"]["events"]
    assert ev_l["setpoints_unlinked"] >= 1 and ev_l["sideslip_setpoints_unlinked"] >= 1
    assert ev_l["sideslip_setpoints"] == ev_c["sideslip_setpoints"] == ev_c["setpoints"] == ev_l["setpoints"]
    assert not ev_c.get("sideslip_unpaired") and not ev_l.get("sideslip_unpaired")
    assert lossy["ap"]["links"]["gcs"]["rejected"].keys() <= {"replay"}  # resent copies only: none refused else
    # the command flown on the rudder's channel: the profile's, at its breakpoints (deg -> rad as float32 carries it)
    um2 = clean["um2"]
    assert {round(float(v), 4) for v in um2} == {0.0, 0.0524, -0.0349}
    assert (lossy["um2"] == um2).all() and (lossy["beta"] == clean["beta"]).all()
    assert lossy["ap"]["metrics"] == clean["ap"]["metrics"]
