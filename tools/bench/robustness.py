"""Fuzzing a flight: random datagrams and random valid messages of every common-dialect type at every port.

One real-time launcher flight (unsigned by default, the harder case: only the pinned addresses and the bounded
clocks protect it; ``--signed`` flies it signed); while it flies, one socket of this process sends to each of the
four UDP ports (SITL, GCS script, the autopilot's SITL and GCS links) ``--datagrams`` random datagrams (random
bytes, framed garbage, MAVLink 1, bit-flipped copies of valid packets, empty ones) and ``--messages`` random valid
MAVLink 2 packets, every message id of the common dialect in turn, random payloads with a correct CRC, mostly with
the IDs of the port's real peer (spoofed).  Figures, each with target 0:

* ``crashes``: processes that did not exit with status 0 (and the flight must be OK);
* ``control_steps_lost``: steps asked minus steps flown (``tools.flight.flown_report``: holds for want of attitude,
  steps later than the attitude timeout, the SITL's time on its servo timeout);
* ``accepted_from_non_peer``: packets a link accepted beyond what its real peer sent (per message type, from the
  peers' own send counters: anything more came from the fuzzer);
* ``counter_mismatch``: sum over the links of |rx_datagrams - rx_accepted - sum(rejected)|.
"""

from __future__ import annotations

import argparse
import random
import re
import socket
import tempfile
import time
from pathlib import Path

from tools.bench import figure, print_table

QUICK_ARGV = ["--datagrams", "5000", "--messages", "2000", "--duration", "12"]
_LINE = re.compile(r"SITL link [\d.]+:(\d+) -> [\d.]+:(\d+); GCS link [\d.]+:(\d+) -> [\d.]+:(\d+)")


def _valid(rng: random.Random, mav, msgid: int, ids: tuple[int, int], seq: int) -> bytes:
    """A MAVLink 2 packet of ``msgid`` with a random payload and a correct CRC (as the sender ``ids``)."""
    from autopilot.shared.fastmav import crc16

    cls = mav.mavlink_map[msgid]
    payload = bytes(rng.randrange(256) for _ in range(cls.unpacker.size)).rstrip(b"\x00") or b"\x00"
    hdr = bytes((len(payload), 0, 0, seq & 0xFF, ids[0], ids[1], msgid & 0xFF, (msgid >> 8) & 0xFF, msgid >> 16))
    c = crc16(hdr + payload + bytes([cls.crc_extra]))
    return b"\xfd" + hdr + payload + bytes((c & 0xFF, c >> 8))


def _garbage(rng: random.Random, valid: list[bytes]) -> bytes:
    kind = rng.randrange(6)
    if kind == 0:
        return bytes(rng.randrange(256) for _ in range(rng.randrange(1, 300)))
    if kind == 1:  # framed garbage: a MAVLink 2 start byte and a plausible header
        return b"\xfd" + bytes(rng.randrange(256) for _ in range(rng.randrange(1, 80)))
    if kind == 2:  # MAVLink 1
        return b"\xfe" + bytes(rng.randrange(256) for _ in range(rng.randrange(5, 60)))
    if kind == 3:  # a bit flip in a valid packet
        b = bytearray(rng.choice(valid))
        i = rng.randrange(len(b))
        b[i] ^= 1 << rng.randrange(8)
        return bytes(b)
    if kind == 4:  # truncated
        b = rng.choice(valid)
        return b[: rng.randrange(1, len(b))]
    return b""  # empty


def _ports(out: Path, timeout: float = 60.0) -> dict:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        try:
            m = _LINE.search((out / "autopilot.log").read_text())
            found = "gcs: vehicle " in (out / "gcs.log").read_text()
        except OSError:
            m, found = None, False
        if m and found:
            a_sitl, sitl, a_gcs, gcs = (int(g) for g in m.groups())
            return {"sitl": sitl, "gcs": gcs, "ap_sitl": a_sitl, "ap_gcs": a_gcs}
        time.sleep(0.02)
    raise RuntimeError(f"the flight in {out} did not start")


def _excess(rx: dict, peer_tx: dict) -> int:
    return sum(max(0, n - peer_tx.get(t, 0)) for t, n in rx.items())


def main(argv: list[str]) -> dict:
    p = argparse.ArgumentParser(prog="python -m tools.bench robustness", description=__doc__.split("\n\n")[0])
    p.add_argument("--datagrams", type=int, default=100_000, help="random datagrams per port (default 100000)")
    p.add_argument("--messages", type=int, default=20_000, help="random valid messages per port (default 20000)")
    p.add_argument("--duration", type=float, default=60.0, help="real-time flight length, s (default 60)")
    p.add_argument("--signed", action="store_true", help="fly signed (default: unsigned, the harder case)")
    p.add_argument("--seed", type=int, default=1)
    args = p.parse_args(argv)

    from autopilot.shared.mavlink import AUTOPILOT_ID, GCS_ID, SITL_ID, mavlink
    from autopilot.shared.mavlink import __dict__ as ids
    from tools.flight import Flight

    ap_sitl_id = ids.get("AUTOPILOT_SITL_ID", AUTOPILOT_ID)
    spoof = {"sitl": ap_sitl_id, "gcs": AUTOPILOT_ID, "ap_sitl": SITL_ID, "ap_gcs": GCS_ID}  # each port's real peer
    rng = random.Random(args.seed)
    msgids = sorted(mavlink.mavlink_map)
    t_gen = time.perf_counter()
    packets: dict[str, list[bytes]] = {}
    for where, peer in spoof.items():
        valid = [
            _valid(rng, mavlink, msgids[k % len(msgids)], peer if rng.random() < 0.9 else (rng.randrange(256),) * 2, k)
            for k in range(args.messages)
        ]
        junk = [_garbage(rng, valid) for _ in range(args.datagrams)]
        mixed = valid + junk
        rng.shuffle(mixed)
        packets[where] = mixed
    print(f"  generated {sum(map(len, packets.values()))} datagrams in {time.perf_counter() - t_gen:.1f} s", flush=True)

    sent = dict.fromkeys(packets, 0)
    with tempfile.TemporaryDirectory(prefix="bench-robustness-") as tmp:
        flight = Flight(duration=args.duration, out=Path(tmp), quiet=True, rrd=False, series=False, signing=args.signed)
        with flight:
            ports = _ports(flight.out)
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 1 << 20)
            total = sum(map(len, packets.values()))
            window = 0.6 * args.duration  # spread over most of the flight, at a steady rate
            t0 = time.perf_counter()
            k = 0
            iters = {w: iter(v) for w, v in packets.items()}
            while iters:
                for where in list(iters):
                    pkt = next(iters[where], None)
                    if pkt is None:
                        del iters[where]
                        continue
                    try:
                        sock.sendto(pkt, ("127.0.0.1", ports[where]))
                        sent[where] += 1
                    except OSError:  # ENOBUFS under load: the datagram never left
                        pass
                    k += 1
                ahead = k / total * window - (time.perf_counter() - t0)
                if ahead > 0.002:
                    time.sleep(ahead)
            fuzz_s = time.perf_counter() - t0
            sock.close()
            res = flight.wait(timeout=args.duration * 3 + 120)
        s = res.summary
    c = s["counters"]
    links = {"sitl": c["sitl"], "gcs": c["gcs"], "ap_sitl": c["autopilot"]["sitl"], "ap_gcs": c["autopilot"]["gcs"]}
    crashes = sum(1 for code in s["exit_codes"].values() if code != 0) + (0 if res.ok else 1)
    flown = s["flown"]
    non_peer = (
        _excess(links["ap_sitl"]["rx_by_type"], links["sitl"]["tx_by_type"])
        + _excess(links["sitl"]["rx_by_type"], links["ap_sitl"]["tx_by_type"])
        + _excess(links["ap_gcs"]["rx_by_type"], links["gcs"]["tx_by_type"])
        + _excess(links["gcs"]["rx_by_type"], links["ap_gcs"]["tx_by_type"])
    )
    mismatch = sum(abs(v["rx_datagrams"] - v["rx_accepted"] - sum(v["rejected"].values())) for v in links.values())
    rejected = {w: sum(v["rejected"].values()) for w, v in links.items()}
    figures = {
        "crashes": figure(crashes, "n", 0, ok=res.ok, reason=res.reason, exit_codes=s["exit_codes"]),
        "control_steps_lost": figure(
            flown["steps_asked"] - flown["steps"],
            "steps",
            0,
            steps=flown["steps"],
            asked=flown["steps_asked"],
            missed_deadlines=(s.get("timing") or {}).get("missed_deadlines"),
        ),
        "accepted_from_non_peer": figure(non_peer, "pkts", 0, admitted={w: v["admitted"] for w, v in links.items()}),
        "counter_mismatch": figure(mismatch, "dgrams", 0, rejected=rejected),
        "datagrams_sent": figure(sum(sent.values()), "dgrams", per_port=sent, seconds=round(fuzz_s, 1)),
        "fuzz_rate": figure(sum(sent.values()) / fuzz_s, "1/s", signed=args.signed),
    }
    for w, v in links.items():
        figures[f"rejected_{w}"] = figure(rejected[w], "dgrams", reasons=v["rejected"])
    print_table("Robustness: a flight fuzzed at every port", figures)
    return figures
