"""Helpers for the MAVLink end-to-end tests: real subprocesses on ephemeral loopback ports, real sockets."""

from __future__ import annotations

import json
import os
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
    from tools.flight.children import free_udp_ports

    return free_udp_ports(n)


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
