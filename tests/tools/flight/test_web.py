"""``--web``: the launcher's own ``rerun --serve-web``, on loopback, ended with the launch (tools.flight.web).

Real launches (lockstep, a few seconds each) and real sockets: what listens is read from the kernel's tables
(``/proc/net/tcp`` and ``tcp6``, what ``ss -lnt`` shows), the server's process from ``/proc/<pid>/cmdline``.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests._browser import free_tcp_port
from tests._mavlink_procs import load_json
from tools.flight.web import WebServer, WebServerError, bind_host

pytestmark = pytest.mark.e2e
ROOT = Path(__file__).resolve().parents[3]


# ------------------------------------------------------------------------------------------ the kernel's view
def _hex_addr(hex_addr: str) -> str:
    """A /proc/net/tcp[6] local address (little-endian words) as text."""
    raw = bytes.fromhex(hex_addr)
    if len(raw) == 4:
        return socket.inet_ntop(socket.AF_INET, raw[::-1])
    words = b"".join(raw[i : i + 4][::-1] for i in range(0, 16, 4))
    return socket.inet_ntop(socket.AF_INET6, words)


def listeners(port: int) -> set[str]:
    """The addresses a TCP socket LISTENs on at ``port`` (state 0A), IPv4 and IPv6: what ``ss -lnt`` lists."""
    found = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            lines = Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            local, state = line.split()[1], line.split()[3]
            addr, hex_port = local.rsplit(":", 1)
            if state == "0A" and int(hex_port, 16) == port:
                found.add(_hex_addr(addr))
    return found


def _processes():
    """(pid, argv as bytes) of every process the kernel lists (one that ends meanwhile is passed over)."""
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            yield int(d.name), (d / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue


def serve_web_pids(port: int) -> list[int]:
    """Processes whose command line is a ``rerun --serve-web`` with ``port``."""
    return [pid for pid, argv in _processes() if b"--serve-web" in argv and str(port).encode() in argv]


def _launch(out: Path, *flags: str, duration: float = 3.0) -> list[str]:
    return [sys.executable, "-m", "tools.launch", "--lockstep", "--duration", repr(duration), "--quiet"] + [
        "--out",
        str(out),
        *flags,
    ]


def _web_flags(http: int, grpc: int) -> list[str]:
    return ["--web", "--web-port", str(http), "--web-grpc-port", str(grpc)]


# ------------------------------------------------------------------------------------------ tests
def test_web_listens_on_loopback_only_during_the_flight_and_nothing_after(tmp_path):
    http, grpc = free_tcp_port(), free_tcp_port()
    proc = subprocess.Popen(
        _launch(tmp_path / "f", *_web_flags(http, grpc), "--no-png", duration=60.0),
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        stdin=subprocess.DEVNULL,
    )
    try:
        seen: dict[int, set[str]] = {}
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and proc.poll() is None:
            seen = {p: listeners(p) for p in (http, grpc)}
            if all(seen.values()):
                break
            time.sleep(0.05)
        assert proc.poll() is None, "the flight ended before the web viewer was seen listening"
        assert seen == {http: {"127.0.0.1"}, grpc: {"127.0.0.1"}}  # loopback only, both ports
        assert len(serve_web_pids(grpc)) == 1
        stdout, _ = proc.communicate(timeout=180)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, stdout
    assert f"open http://127.0.0.1:{http}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{grpc}%2Fproxy" in stdout
    assert f"ssh -L {http}:127.0.0.1:{http} -L {grpc}:127.0.0.1:{grpc}" in stdout
    assert "WARNING" not in stdout
    # the launch has ended: nothing listens on either port and the server process is gone (not left to pid 1)
    assert listeners(http) == set() and listeners(grpc) == set()
    assert serve_web_pids(grpc) == []


def test_a_taken_port_refuses_the_flight_in_one_line_and_reuses_nothing(tmp_path):
    http, grpc = free_tcp_port(), free_tcp_port()
    with WebServer("127.0.0.1", free_tcp_port(), grpc) as other:  # someone else's server on our gRPC port
        r = subprocess.run(
            _launch(tmp_path / "f", *_web_flags(http, grpc)),
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=120,
            stdin=subprocess.DEVNULL,
        )
        assert other.running  # left alone
    assert r.returncode == 2, r.stdout + r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    assert f"TCP port {grpc} (--web-grpc-port) on 127.0.0.1 is not free" in lines[0]
    summary = load_json(tmp_path / "f" / "summary.json")
    assert summary["ok"] is False and summary["failed"] == "web" and summary["flown"]["steps"] == 0
    assert not (tmp_path / "f" / "autopilot.log").exists()  # nothing was started
    assert listeners(http) == set()  # our own server was never started either


def test_all_interfaces_is_explicit_and_warns(tmp_path):
    http, grpc = free_tcp_port("0.0.0.0"), free_tcp_port("0.0.0.0")
    r = subprocess.run(
        _launch(tmp_path / "f", *_web_flags(http, grpc), "--web-host", "0.0.0.0", "--no-png"),
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=180,
        stdin=subprocess.DEVNULL,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    assert f"web viewer on 0.0.0.0: open http://<this host>:{http}/" in r.stdout
    assert (
        f"WARNING: anyone who reaches ports {http} and {grpc} of this host can read the whole recording and "
        "write into it (no authentication)" in r.stdout
    )
    assert listeners(http) == set() and listeners(grpc) == set()


def test_the_server_dies_with_a_killed_launcher(tmp_path):
    """SIGKILL leaves the launcher no time to stop anything: the kernel ends the server (PR_SET_PDEATHSIG)."""
    http, grpc = free_tcp_port(), free_tcp_port()
    proc = subprocess.Popen(
        _launch(tmp_path / "f", *_web_flags(http, grpc), "--no-png", duration=30.0),
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        stdin=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not serve_web_pids(grpc):
            time.sleep(0.05)
        pids = serve_web_pids(grpc)
        assert len(pids) == 1
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(10)
        deadline = time.monotonic() + 10  # an exiting process drops its command line before its sockets
        while time.monotonic() < deadline and (serve_web_pids(grpc) or listeners(grpc)):
            time.sleep(0.05)
        assert serve_web_pids(grpc) == [] and listeners(grpc) == set()
    finally:
        if proc.poll() is None:
            proc.kill()
        _stop_orphans(tmp_path / "f")


def _stop_orphans(out: Path) -> None:
    """The flight's children outlive a SIGKILLed launcher (their own sessions): end them by their command line."""
    for pid, argv in _processes():
        if any(str(out).encode() in a for a in argv) and pid != os.getpid():
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass


def test_flags_are_checked():
    import argparse

    assert bind_host("127.0.0.1") == "127.0.0.1" and bind_host("::") == "::"
    with pytest.raises(argparse.ArgumentTypeError, match="expected an IP address"):
        bind_host("localhost")
    with pytest.raises(WebServerError, match="must differ"):
        WebServer("127.0.0.1", 9999, 9999)
    r = subprocess.run(
        [sys.executable, "-m", "tools.launch", "--web", "--web-port", "70000"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 2 and r.stderr.strip().count("\n") == 0, r.stderr
    assert "--web-port: expected a TCP port in 1..65535, got 70000" in r.stderr


def test_an_exception_in_the_caller_ends_the_server(tmp_path):
    """``Flight`` as a context manager: an exception in the ``with`` body still ends the server (``__exit__``)."""
    from tools.flight import Flight

    http, grpc = free_tcp_port(), free_tcp_port()
    flight = Flight(lockstep=True, duration=60, web=True, web_port=http, web_grpc_port=grpc, out=tmp_path / "f")
    with pytest.raises(RuntimeError, match="the caller failed"):
        with flight:
            assert listeners(grpc) == {"127.0.0.1"} and listeners(http) == {"127.0.0.1"}
            raise RuntimeError("the caller failed")
    assert listeners(grpc) == set() and listeners(http) == set()
    assert serve_web_pids(grpc) == []
    assert flight.result is not None and not flight.result.ok  # stopped by the caller


def test_equal_web_ports_are_refused_in_one_line():
    r = subprocess.run(
        [sys.executable, "-m", "tools.launch", "--web", "--web-port", "9000", "--web-grpc-port", "9000"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 2 and r.stderr.strip().count("\n") == 0, r.stderr
    assert "--web-port must differ from the gRPC port (web_grpc_port), both are 9000" in r.stderr
