"""Helpers for the MAVLink end-to-end tests: real subprocesses on free loopback ports, real sockets."""

from __future__ import annotations

import json
import os
import random
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import common as mavlink  # noqa: E402

PY = sys.executable


def free_ports(n: int) -> list[int]:
    """``n`` free UDP ports below the kernel's ephemeral range (``free_base_port``)."""
    base = free_base_port(n)
    return list(range(base, base + n))


def free_base_port(n: int = 4) -> int:
    """The first of ``n`` consecutive free UDP ports (``--base-port``, ``Flight(base_port=...)``), below the kernel's
    ephemeral range: a socket that sends unbound, or binds port 0, anywhere on the machine between this check and the
    flight's bind cannot take one of them (a flood's 200 sockets, started after the check, took the flight's
    ground-station port in CI: an ephemeral range of 28,232 ports, 200 sockets, 3 ports, about 2 % a flight)."""
    try:
        low = int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        low = 32768
    below = low - n >= 10000
    for _ in range(100):
        base = random.randrange(10000, low - n) if below else random.randrange(20000, 65536 - n)
        socks = []
        try:
            for i in range(n):
                s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                socks.append(s)
                s.bind(("127.0.0.1", base + i))
            return base
        except OSError:
            continue
        finally:
            for s in socks:
                s.close()
    raise AssertionError(f"no {n} free consecutive UDP ports")


class Proc:
    """A module run as a subprocess, output to a file (so a full pipe never blocks it)."""

    def __init__(self, module: str, args: list[str], log: Path):
        self.log = log
        self._f = open(log, "w")
        self.p = subprocess.Popen(
            [PY, "-u", "-m", module, *args],
            stdout=self._f,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            env=dict(os.environ, PYTHONUNBUFFERED="1"),
        )

    def output(self) -> str:
        if not self._f.closed:
            self._f.flush()
        return self.log.read_text()

    def wait_for(self, text: str, timeout: float = 30.0) -> bool:
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout:
            if text in self.output():
                return True
            if self.p.poll() is not None:
                return text in self.output()
            time.sleep(0.05)
        return False

    def stop(self, timeout: float = 15.0) -> int:
        if self.p.poll() is None:
            self.p.send_signal(signal.SIGINT)
        try:
            return self.p.wait(timeout)
        except subprocess.TimeoutExpired:
            self.p.kill()
            self.p.wait()
            return -9
        finally:
            self._f.close()

    def kill(self):
        self.p.kill()
        self.p.wait()
        self._f.close()


def load_json(path) -> dict:
    with open(path) as f:
        return json.load(f)


def mav(sysid: int, compid: int) -> mavlink.MAVLink:
    return mavlink.MAVLink(None, sysid, compid)


def pack(m: mavlink.MAVLink, msg) -> bytes:
    buf = msg.pack(m)
    m.seq = (m.seq + 1) & 0xFF
    return buf


def udp() -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    return s


def run_cli(module: str, *args: str, timeout: float = 120.0) -> subprocess.CompletedProcess:
    return subprocess.run(
        [PY, "-m", module, *args], capture_output=True, text=True, timeout=timeout, stdin=subprocess.DEVNULL
    )
