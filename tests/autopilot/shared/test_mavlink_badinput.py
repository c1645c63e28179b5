"""Bad input at the real ports of running processes (real time SITL + autopilot, real UDP packets).

Each kind is rejected and counted (the counters the processes write at exit), nothing crashes, both
exit 0, and the flight keeps its rates (all steps done in the expected wall time, few missed
deadlines, the SITL's sensor stream at 200 Hz; loose bounds for a loaded machine, and a flight that missed them is
flown once more: ``_fly``; the strict targets are in the benchmark).
"""

from __future__ import annotations

import math
import random
import time

import pytest

from tests._mavlink_procs import Proc, free_ports, load_json, mav, mavlink, pack, udp

pytestmark = pytest.mark.e2e  # real processes over loopback UDP

RATE = 100.0
DURATION = 3.0


class Flight:
    def __init__(self, tmp_path):
        self.sitl_port, self.ap_sitl_port, self.ap_gcs_port = free_ports(3)
        self.dir = tmp_path
        self.sitl = Proc(
            "sitl",
            ["--listen", f"127.0.0.1:{self.sitl_port}", "--stats-json", str(tmp_path / "sitl.json")],
            tmp_path / "sitl.log",
        )
        self.ap = Proc(
            "autopilot",
            [
                "--sitl",
                f"127.0.0.1:{self.sitl_port}",
                "--sitl-bind",
                f"127.0.0.1:{self.ap_sitl_port}",
                "--listen",
                f"127.0.0.1:{self.ap_gcs_port}",
                "--gcs",
                "127.0.0.1:9",
                "--rate",
                str(RATE),
                "--duration",
                str(DURATION),
                "--stats-json",
                str(tmp_path / "ap.json"),
            ],
            tmp_path / "ap.log",
        )
        self.tx = udp()

    def targets(self):
        return {
            "ap_sitl": ("127.0.0.1", self.ap_sitl_port),
            "ap_gcs": ("127.0.0.1", self.ap_gcs_port),
            "sitl": ("127.0.0.1", self.sitl_port),
        }

    def send(self, where: str, payloads):
        addr = self.targets()[where]
        for p in payloads:
            self.tx.sendto(p, addr)

    def finish(self):
        """Both processes' stats after the flight, both exited 0 (whether it kept its rates: ``_late``)."""
        try:
            assert self.ap.p.wait(60) == 0, self.ap.output()
        finally:
            self.ap.stop()
            code = self.sitl.stop()
            self.tx.close()
        assert code == 0, self.sitl.output()
        ap = load_json(self.dir / "ap.json")
        sitl = load_json(self.dir / "sitl.json")
        assert ap["steps"] == round(DURATION * RATE)  # every step done
        assert "rejected:" in self.ap.output() and "rejected:" in self.sitl.output()
        return ap, sitl


def _late(ap: dict, sitl: dict | None = None) -> str | None:
    """Why the flight did not keep its rates (the autopilot's wall time off by more than 5 %, or more than 5 % of its
    steps past their deadlines; the SITL's sensor stream off its 200 Hz by more than 10 %), or None."""
    wall, missed = ap["wall_s"], ap["timing"]["missed_deadlines"]
    if wall != pytest.approx(DURATION - 1.0 / RATE, rel=0.05) or missed > 0.05 * ap["steps"]:
        return f"{missed} missed deadlines of {ap['steps']} steps, {wall:.3f} s of wall clock"
    if sitl is not None and sitl["frames"] / sitl["wall_s"] != pytest.approx(200, rel=0.1):
        return f"the SITL's sensor stream at {sitl['frames'] / sitl['wall_s']:.1f} Hz, not 200 Hz +- 10 %"
    return None


def _started(where) -> Flight:
    where.mkdir(parents=True, exist_ok=True)
    f = Flight(where)
    if not (f.sitl.wait_for("listening on") and f.ap.wait_for("autopilot: clsac")):
        f.ap.stop()  # no process outlives a failed start
        f.sitl.stop()
        raise AssertionError(f"the flight did not start:\n{f.sitl.output()[-1000:]}\n{f.ap.output()[-1000:]}")
    time.sleep(0.3)
    return f


def _fly(tmp_path, send) -> tuple[Flight, dict, dict]:
    """A flight, ``send(flight)`` its bad input, its stats.  These floods are at the edge of what a loaded machine
    keeps in time (CI, beside another real-time flight: 19 missed deadlines of 300, a 177 Hz sensor stream): a
    flight that did not keep its rates (``_late``) is flown once more, said on the test's output; what is asserted
    holds of the last flight, which must keep them."""
    for attempt in range(2):
        flight = _started(tmp_path / f"flight{attempt}")
        send(flight)
        ap, sitl = flight.finish()
        late = _late(ap, sitl)
        if late is None or attempt == 1:
            break
        print(f"flight {attempt + 1} did not keep its rates, flown again: {late}")
    assert late is None, late
    return flight, ap, sitl


def _rejected(stats, link):
    return stats["links"][link]["rejected"] if "links" in stats else stats["link"]["rejected"]


def _attitude(m, roll=0.1, p=0.0, r=0.0):
    return pack(m, mavlink.MAVLink_attitude_message(1000, roll, 0.0, 0.0, p, 0.0, r))


def _setpoint(m, q):
    return pack(m, mavlink.MAVLink_set_attitude_target_message(0, 1, 1, 71, q, 0.0, 0.0, 0.0, 0.0))


def _servo(m, time_usec=0, pwm=1500):
    s = [0] * 16
    s[3] = pwm
    return pack(m, mavlink.MAVLink_servo_output_raw_message(time_usec, 0, *s))


def test_random_bytes(tmp_path):
    """900 datagrams of random bytes at once, the heaviest flood here."""
    n = 300

    def send(flight):
        rng = random.Random(7)
        for where in ("ap_sitl", "ap_gcs", "sitl"):
            flight.send(where, [bytes(rng.randrange(256) for _ in range(rng.randrange(1, 280))) for _ in range(n)])

    _flight, ap, sitl = _fly(tmp_path, send)
    for rej in (_rejected(ap, "sitl"), _rejected(ap, "gcs"), _rejected(sitl, None)):
        # a burst of 300 at once: beyond the per-poll budget the rest is read and dropped (over_budget)
        assert sum(rej.values()) >= n and rej.get("bad_magic", 0) + rej.get("over_budget", 0) > 0.9 * n


def test_truncated_packets(tmp_path):
    n = 100
    good_sitl, good_gcs, good_ap = mav(1, 200), mav(255, 190), mav(1, 140)

    def send(flight):
        flight.send("ap_sitl", [_attitude(good_sitl)[: 8 + k % 10] for k in range(n)])
        flight.send("ap_gcs", [_setpoint(good_gcs, [1.0, 0.0, 0.0, 0.0])[: -1 - k % 20] for k in range(n)])
        flight.send("sitl", [_servo(good_ap)[: 12 + k % 5] for k in range(n)])

    _flight, ap, sitl = _fly(tmp_path, send)
    assert _rejected(ap, "sitl")["truncated"] == n
    assert _rejected(ap, "gcs")["truncated"] == n
    assert _rejected(sitl, None)["truncated"] == n


def test_wrong_system_ids(tmp_path):
    n = 100

    def send(flight):
        flight.send("ap_sitl", [_attitude(mav(2, 200), roll=1.0) for _ in range(n)])
        flight.send("ap_gcs", [_setpoint(mav(254, 190), [0.0, 1.0, 0.0, 0.0]) for _ in range(n)])
        flight.send("sitl", [_servo(mav(1, 2), pwm=2000) for _ in range(n)])

    _flight, ap, sitl = _fly(tmp_path, send)
    assert _rejected(ap, "sitl")["wrong_id"] == n
    assert _rejected(ap, "gcs")["wrong_id"] == n
    assert _rejected(sitl, None)["wrong_id"] == n
    assert ap["metrics"]["max_abs_u"] < 1e-9  # nothing they said was flown (no setpoint: wings level)


def test_forged_attitude_and_servo_from_another_port(tmp_path):
    m = mav(1, 200)
    bad = [_attitude(m, roll=v) for v in (math.nan, math.inf, -math.inf)] * 30
    bad += [_attitude(m, p=math.nan), _attitude(m, r=math.inf)] * 5
    # a valid attitude from the past (time_boot_ms 1 is long gone): out of order, not used
    old = [pack(m, mavlink.MAVLink_attitude_message(1, 0.5, 0.0, 0.0, 0.0, 0.0, 0.0)) for _ in range(20)]

    def send(flight):
        flight.send("ap_sitl", bad)
        flight.send("ap_sitl", old)
        # servo messages with the autopilot's IDs but time stamps 10 s old (real time: time_usec is the autopilot's
        # Unix-clock microseconds mod 2**32): stale, not applied
        old_usec = (time.time_ns() // 1000 - 10_000_000) % (1 << 32)
        flight.send("sitl", [_servo(mav(1, 140), time_usec=(old_usec + k) % (1 << 32), pwm=2000) for k in range(50)])

    _flight, ap, sitl = _fly(tmp_path, send)
    # the links are pinned to their peers: the right IDs from any other port are not even decoded
    assert _rejected(ap, "sitl")["not_peer"] == len(bad) + len(old)
    assert _rejected(sitl, None)["not_peer"] == 50
    assert ap["events"].get("failsafes", 0) == 0
    assert sitl["events"].get("stale_servo", 0) == 0
    assert ap["metrics"]["max_abs_u"] < 0.01  # nothing of it was flown (no setpoint: wings level)


def test_nonfinite_and_out_of_range_setpoints(tmp_path):
    g = mav(255, 190)
    bad = [_setpoint(g, q) for q in ([math.nan, 0, 0, 0], [1, math.inf, 0, 0], [0, 0, 0, 0], [1, 0, -math.inf, 0])] * 10
    big = math.radians(60)

    def send(flight):
        flight.send("ap_gcs", bad)
        flight.send("ap_gcs", [_setpoint(g, [math.cos(big / 2), math.sin(big / 2), 0, 0])])

    flight, ap, _sitl = _fly(tmp_path, send)
    assert _rejected(ap, "gcs")["nonfinite_setpoint"] == len(bad)
    assert ap["events"]["setpoints_clamped"] == 1 and ap["events"]["setpoints"] == 1
    assert "clamped to 45" in flight.ap.output()


def _flood_payloads(rng, right_id):
    """A mix: random bytes, valid packets from a wrong system, valid packets of a message nobody uses."""
    wrong = mav(99, 99)
    right = mav(*right_id)
    out = []
    for k in range(300):
        kind = k % 3
        if kind == 0:
            out.append(bytes(rng.randrange(256) for _ in range(rng.randrange(1, 100))))
        elif kind == 1:
            out.append(_attitude(wrong, roll=0.5))
        else:
            out.append(pack(right, mavlink.MAVLink_named_value_int_message(0, b"unused", 1)))
    return out


@pytest.mark.parametrize("where,right_id", [("ap_sitl", (1, 200)), ("ap_gcs", (255, 190)), ("sitl", (1, 140))])
def test_flood_of_10000_packets_per_second(tmp_path, where, right_id):
    payloads = _flood_payloads(random.Random(3), right_id)
    sent = 0

    def send(flight):
        nonlocal sent
        addr = flight.targets()[where]
        sent = 0
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < 1.0:  # 10,000 packets/s for 1 s, in bursts of 100 every 10 ms
            burst_start = time.perf_counter()
            for _ in range(100):
                flight.tx.sendto(payloads[sent % len(payloads)], addr)
                sent += 1
            pause = 0.01 - (time.perf_counter() - burst_start)
            if pause > 0:
                time.sleep(pause)

    _flight, ap, sitl = _fly(tmp_path, send)  # the SITL kept its 200 Hz sensor stream (``_late``)
    link = {"ap_sitl": ap["links"]["sitl"], "ap_gcs": ap["links"]["gcs"], "sitl": sitl["link"]}[where]
    assert sent >= 8000
    # every datagram that reached the process was read and rejected (the kernel may drop a few)
    assert sum(link["rejected"].values()) >= 0.9 * sent
    assert ap["events"].get("failsafes", 0) == 0
