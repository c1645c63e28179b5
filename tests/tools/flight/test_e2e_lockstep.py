"""End to end, lockstep: SITL + autopilot + GCS as real processes over loopback UDP (ephemeral ports).

* metrics of a lockstep flight vs the in-process run of the same scenario (docs/spec.md, "Reference scenario"):
  equal to the last bit to the in-process run with the wire model, the same ControlStep on both sides;
* two identical runs: identical summary.json metrics and identical tlog payloads;
* a run across the 71.6-minute SERVO_OUTPUT_RAW.time_usec wrap.
"""

from __future__ import annotations

import subprocess

import pytest

from autopilot.shared.pwm import PwmMap
from autopilot.shared.tlog import payload_streams, read_tlog
from tests._mavlink_procs import PY, load_json, mavlink, run_cli
from tools.experiment.scenario import PAPER, PAPER_RUNS, Scenario, run_inprocess

pytestmark = pytest.mark.e2e  # real processes over loopback UDP

CLSAC = PAPER_RUNS[1]


def inprocess_quantised(scenario: Scenario, run) -> dict:
    """The in-process loop with exactly what the MAVLink path adds (float32 on the wire, 1 us PWM)."""
    return run_inprocess(scenario, run, wire=PwmMap()).metrics


def launch_cli(out, *extra) -> dict:
    r = run_cli("tools.launch", "--lockstep", "--quiet", "--out", str(out), *extra, timeout=180)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "OK" in r.stdout and "flight.tlog" in r.stdout
    assert "in-to-out latency" in r.stdout and "attitude age" not in r.stdout
    return load_json(out / "summary.json")


@pytest.fixture(scope="module")
def paper_clsac(tmp_path_factory):
    out = tmp_path_factory.mktemp("lockstep_a")
    return out, launch_cli(out)


def test_lockstep_metrics_agree_with_inprocess(paper_clsac, paper_runs):
    out, summary = paper_clsac
    assert summary["scenario"] == "paper" and summary["ok"] and summary["mode"] == "lockstep"
    (run,) = summary["runs"]
    assert run["name"] == "clsac" and run["Lv"] == 20.0 and run["steps"] == PAPER.steps
    flown = run["metrics"]
    ref = paper_runs[CLSAC.name].metrics
    for key in ("ise_ref", "ise_crm", "energy", "max_abs_u"):
        assert flown[key] == pytest.approx(ref[key], rel=0.02), key
    # tv (total variation of the command) is the one metric PWM quantisation moves by more than 2 %:
    # each 1 us step of the pulse is 1.05 mrad and the command dithers across steps (+13 % here).
    # Against the in-process loop with the same quantisation and float32 transport it is equal to the last
    # bit (summary.json keeps floats exactly): both call the one ControlStep, the transport adds nothing else.
    assert flown == inprocess_quantised(PAPER, CLSAC)


def test_lockstep_outputs_are_valid(paper_clsac):
    out, summary = paper_clsac
    tlog = out / "flight.tlog"
    records = list(read_tlog(str(tlog)))
    # every frame: ATTITUDE in, SERVO_OUTPUT_RAW out, plus the GCS stream
    assert len(records) > 2 * PAPER.steps
    assert tlog.stat().st_size == sum(8 + len(raw) for _t, raw in records)
    counters = summary["counters"]["autopilot"]
    assert counters["sitl"]["rx_by_type"]["ATTITUDE"] >= PAPER.steps
    assert counters["sitl"]["tx_by_type"]["SERVO_OUTPUT_RAW"] == PAPER.steps
    assert counters["sitl"]["rejected"] == {} and counters["gcs"]["rejected"] == {}
    assert summary["rtf"] > 1.0
    # pymavlink's own tool reads it
    dump = subprocess.run(
        [PY, "-m", "pymavlink.tools.mavlogdump", "--types", "SERVO_OUTPUT_RAW", str(tlog)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert dump.returncode == 0, dump.stderr
    assert dump.stdout.count("SERVO_OUTPUT_RAW") >= PAPER.steps


def test_lockstep_runs_are_deterministic(paper_clsac, tmp_path):
    out_a, summary_a = paper_clsac
    out_b = tmp_path / "b"
    summary_b = launch_cli(out_b)
    assert summary_a["runs"] == summary_b["runs"]
    a = payload_streams(str(out_a / "flight.tlog"))
    b = payload_streams(str(out_b / "flight.tlog"))
    assert set(a) == set(b)
    for key in a:
        assert a[key] == b[key], f"payload stream {key} differs"
    attitude_from_sitl = a[(1, 200, mavlink.MAVLINK_MSG_ID_ATTITUDE)]
    assert len(attitude_from_sitl) == PAPER.steps + 1  # every frame plus the end-of-run frame


def test_lockstep_sac_runs(tmp_path):
    # SAC with the paper's PFC leaves the flight envelope within 5 s (exit 3: test_flight.py); this test is about
    # its metrics, so the envelope is measured but not judged.
    summary = launch_cli(tmp_path, "--controller", "sac", "--duration", "5", "--no-envelope")
    (run,) = summary["runs"]
    assert run["name"] == "sac" and run["Lv"] == 0.0
    ref = run_inprocess(Scenario(duration_s=5.0), PAPER_RUNS[0]).metrics
    assert run["metrics"]["ise_ref"] == pytest.approx(ref["ise_ref"], rel=0.02)


@pytest.mark.parametrize("duration", ["0.05", "1.05"])
def test_a_lockstep_flight_that_ends_between_two_schedule_points_flies_to_its_end(tmp_path, duration):
    """The GCS script schedules a setpoint every 0.1 s of sim time, and the vehicle flies no frame past its
    schedule: a flight ending between two points (0.05 s, 1.05 s) waited for a point never sent, until the SITL
    gave up, and the verdict blamed the GCS.  The profile's last instant is now scheduled too."""
    summary = launch_cli(tmp_path, "--duration", duration, "--no-rrd", "--no-png", "--lockstep-idle-exit", "2")
    steps = round(float(duration) * 100)
    assert summary["runs"][0]["steps"] == steps and summary["flown"]["complete"], summary["flown"]


def test_lockstep_across_time_usec_wrap(tmp_path):
    """Start 3 s before SERVO_OUTPUT_RAW.time_usec wraps (2**32 us = 4294.967296 s) and fly 8 s across it.
    Sim time does not enter the dynamics, so the metrics equal those of the same flight from t = 0."""
    wrapped = launch_cli(tmp_path / "wrap", "--duration", "8", "--start-time", "4292")
    plain = launch_cli(tmp_path / "zero", "--duration", "8")
    assert wrapped["runs"][0]["steps"] == 800
    assert wrapped["runs"][0]["metrics"] == plain["runs"][0]["metrics"]
    mav = mavlink.MAVLink(None)
    usecs = []
    for _t, raw in read_tlog(str(tmp_path / "wrap" / "flight.tlog")):
        if raw[0] == 0xFD and raw[7] == mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW and raw[5:7] == b"\x01\x01":
            usecs.append(mav.decode(bytearray(raw)).time_usec)
    assert min(usecs) < 10_000_000 < 4_290_000_000 < max(usecs)  # both sides of the wrap were flown


def test_two_launches_at_once_do_not_collide(tmp_path):
    import subprocess

    procs = [
        subprocess.Popen(
            [PY, "-m", "tools.launch", "--lockstep", "--quiet", "--duration", "5", "--out", str(tmp_path / f"run{i}")],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for i in range(2)
    ]
    outs = [p.communicate(timeout=180) for p in procs]
    for p, (so, se) in zip(procs, outs):
        assert p.returncode == 0, so + se
    a, b = (load_json(tmp_path / f"run{i}" / "summary.json") for i in range(2))
    assert a["runs"] == b["runs"]


class LossyProxy:
    """A UDP relay between the autopilot and the SITL that drops and duplicates packets on a fixed pattern."""

    def __init__(self, sitl_addr, drop_every: int, dup_every: int):
        import socket
        import threading

        self.sitl_addr = sitl_addr
        self.front = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # the autopilot talks to this
        self.front.bind(("127.0.0.1", 0))
        self.back = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # this talks to the SITL
        self.back.bind(("127.0.0.1", 0))
        self.port = self.front.getsockname()[1]
        self.drop_every, self.dup_every = drop_every, dup_every
        self.ap_addr = None
        self.n = {"up": 0, "down": 0}
        self.dropped = self.duplicated = 0
        self.stop = False
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _relay(self, direction, data, sock, addr):
        self.n[direction] += 1
        k = self.n[direction]
        # only the lockstep traffic (ATTITUDE down, SERVO_OUTPUT_RAW up) is disturbed
        if len(data) > 8 and data[0] == 0xFD and data[7] in (30, 36) and k > 5:
            if k % self.drop_every == 0:
                self.dropped += 1
                return
            if k % self.dup_every == 0:
                self.duplicated += 1
                sock.sendto(data, addr)
        sock.sendto(data, addr)

    def _run(self):
        import select

        while not self.stop:
            ready, _, _ = select.select([self.front, self.back], [], [], 0.05)
            for s in ready:
                data, addr = s.recvfrom(4096)
                if s is self.front:
                    self.ap_addr = addr
                    self._relay("up", data, self.back, self.sitl_addr)
                elif self.ap_addr is not None:
                    self._relay("down", data, self.front, self.ap_addr)

    def close(self):
        self.stop = True
        self.thread.join(2)
        self.front.close()
        self.back.close()


def test_lost_and_duplicated_packets_neither_deadlock_nor_double_step(tmp_path):
    from tests._mavlink_procs import Proc, free_ports

    sitl_port, gcs_port = free_ports(2)
    proxy = LossyProxy(("127.0.0.1", sitl_port), drop_every=37, dup_every=23)
    d = "5"
    sitl = Proc(
        "sitl",
        [
            "--lockstep",
            "--listen",
            f"127.0.0.1:{sitl_port}",
            "--duration",
            d,
            "--resend-timeout",
            "0.02",
            "--stats-json",
            str(tmp_path / "sitl.json"),
        ],
        tmp_path / "sitl.log",
    )
    gcs = Proc(
        "tools.gcs",
        ["--lockstep", "--listen", f"127.0.0.1:{gcs_port}", "--duration", d, "--quiet"],
        tmp_path / "gcs.log",
    )
    ap = Proc(
        "autopilot",
        [
            "--lockstep",
            "--sitl",
            f"127.0.0.1:{proxy.port}",
            "--gcs",
            f"127.0.0.1:{gcs_port}",
            "--duration",
            d,
            "--stats-json",
            str(tmp_path / "ap.json"),
        ],
        tmp_path / "ap.log",
    )
    try:
        assert ap.p.wait(120) == 0, ap.output()
        assert sitl.p.wait(30) == 0, sitl.output()
    finally:
        for p in (ap, sitl, gcs):
            p.stop()
        proxy.close()
    assert proxy.dropped > 10 and proxy.duplicated > 10
    s, a = load_json(tmp_path / "sitl.json"), load_json(tmp_path / "ap.json")
    assert s["frames"] == 500 and a["steps"] == 500
    assert s["events"]["resends"] > 0 and s["events"]["stale_servo"] > 0  # lost answers resent, duplicates ignored
    assert a["events"]["duplicate_frames"] > 0  # answered from the stored reply, no second step
    # exactly the in-process loop (with PWM and float32), so no frame was stepped twice or skipped
    quant = inprocess_quantised(Scenario(duration_s=5.0), CLSAC)
    for key, value in quant.items():
        assert a["metrics"][key] == pytest.approx(value, rel=1e-6), key


def test_sitl_gives_up_with_a_clear_error(tmp_path):
    """No GCS paces the autopilot, so frame 0 is never answered: the SITL resends, then gives up (exit 1)."""
    from tests._mavlink_procs import Proc, free_ports

    (sitl_port,) = free_ports(1)
    sitl = Proc(
        "sitl",
        ["--lockstep", "--listen", f"127.0.0.1:{sitl_port}", "--give-up", "1.5", "--resend-timeout", "0.3"],
        tmp_path / "sitl.log",
    )
    ap = Proc(
        "autopilot",
        [
            "--lockstep",
            "--sitl",
            f"127.0.0.1:{sitl_port}",
            "--gcs",
            "127.0.0.1:9",
            "--stats-json",
            str(tmp_path / "ap.json"),
        ],
        tmp_path / "ap.log",
    )
    try:
        assert sitl.p.wait(60) == 1
    finally:
        assert ap.stop() == 0
        sitl.stop()
    out = sitl.output()
    assert "sitl: error: no SERVO_OUTPUT_RAW for frame t=0.000 s" in out and "resent" in out
    a = load_json(tmp_path / "ap.json")
    assert a["steps"] == 0 and a["events"]["duplicate_pending_frames"] >= 3
