"""The three child processes of a flight: start with output captured to a log, stop cleanly, free ports.

Used by ``tools.flight.Flight``; nothing here knows what the processes are."""

from __future__ import annotations

import os
import select
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

from autopilot.shared import crash

STOP_GRACE_S = 5.0  # after SIGINT, how long the children get to write their files before they are killed

# One OpenBLAS thread for the flight's processes unless the environment says otherwise: their matrices are a few rows
# wide, and numpy's import starting a BLAS thread per core costs each process about 0.06 CPU s at the flight's start,
# when the processes contend for the cores (0.13 -> 0.07 CPU s for `import numpy` on the 2-core VM).
BLAS_THREADS = {"OPENBLAS_NUM_THREADS": "1"}


def child_env(**overrides: str) -> dict[str, str]:
    """This process's environment for one of the flight's processes: ``BLAS_THREADS`` where it sets none, then
    ``overrides``."""
    return {**BLAS_THREADS, **os.environ, **overrides}


class Child:
    """A child process whose output goes to DIR/<name>.log (and, if echo, to the console with a prefix)."""

    def __init__(self, name: str, argv: list[str], log_path: Path, echo: bool, ready_marker: str | None = None):
        self.name = name
        self.argv = argv
        self.log_path = log_path
        self.echo = echo
        self.ready = threading.Event()  # set when it says ready_marker, or at the end of its output
        self.ready_marker = ready_marker
        self.marker_seen = False  # it said ready_marker
        self.tail: list[str] = []
        self.log_error: str | None = None  # the log could not be written (a full disk): the output is still read
        self._log = open(log_path, "w", buffering=1)
        self._write_log("$ " + " ".join(argv) + "\n")
        self.proc = subprocess.Popen(
            argv,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            # its internal error's traceback comes as lines for the log only (autopilot.shared.crash)
            env=child_env(PYTHONUNBUFFERED="1", MAVLINK20="1", **{crash.LOG_ENV: str(log_path)}),
            # A process group of its own (the terminal's Ctrl-C reaches the launcher only, which stops the children in
            # order) in the launcher's session: not a session of its own, which the kernel's autogroups
            # (/proc/sys/kernel/sched_autogroup_enabled) would weigh as a separate desktop session, at full weight,
            # whatever the launcher's priority.  So `nice` or SCHED_IDLE on the launcher holds for its whole flight
            # (docs/tests.md, "Parallel"; `python -m tools.bench isolation`: a 10 ms loop beside idle-priority busy
            # loops woke late in 1-9 periods of 1200 with them started here, 16-23 with them in sessions of their own).
            process_group=0,
            text=True,
            bufsize=1,
        )
        self.started = time.monotonic()
        # A descriptor that becomes readable when the process exits (Linux 5.3+): wait() wakes at the exit itself
        # instead of polling (Popen.wait with a timeout sleeps up to 50 ms between looks).
        try:
            self._pidfd = os.pidfd_open(self.proc.pid)
        except (AttributeError, OSError):
            self._pidfd = None
        self.exited_at: float | None = None  # monotonic time its exit was first seen (the verdict's exit order)
        self._reader = threading.Thread(target=self._read, name=f"read-{name}", daemon=True)
        self._reader.start()

    def _write_log(self, line: str) -> None:
        """One line to the log; a full disk stops the log there (said once, ``log_error``), never the reading: a
        child whose output is not read blocks on its next print."""
        if self.log_error is not None:
            return
        try:
            self._log.write(line)
        except OSError as exc:
            self.log_error = f"{self.log_path}: {exc.strerror or exc}"

    def _read(self):
        for line in self.proc.stdout:
            self._write_log(line)
            if crash.is_traceback_line(line, self.name):
                continue  # the log's alone: the console and the reason get the error's one line after it
            line = line.rstrip("\n")
            self.tail.append(line)
            if len(self.tail) > 40:
                del self.tail[:20]
            if self.ready_marker and self.ready_marker in line:
                self.marker_seen = True
                self.ready.set()
            if self.echo:
                sys.stdout.write(f"[{self.name}] {line}\n")
                sys.stdout.flush()
        self.ready.set()  # EOF: whoever waits for readiness must look at the exit code

    @property
    def code(self):
        code = self.proc.poll()
        if code is not None and self.exited_at is None:
            self.exited_at = time.monotonic()
        return code

    def interrupt(self):
        if self.proc.poll() is None:
            try:
                self.proc.send_signal(signal.SIGINT)
            except ProcessLookupError:
                pass

    def wait(self, timeout: float) -> int | None:
        """The exit code, waiting up to ``timeout`` s for the exit; None if it still runs."""
        if self._pidfd is not None and self.proc.returncode is None:
            if not select.select([self._pidfd], [], [], max(0.0, timeout))[0]:
                return None
        try:
            self.proc.wait(timeout=max(0.0, timeout))
        except subprocess.TimeoutExpired:
            return None
        self._close_pidfd()
        return self.code

    def _close_pidfd(self):
        if self._pidfd is not None:
            os.close(self._pidfd)
            self._pidfd = None

    def kill(self):
        if self.proc.poll() is None:
            try:
                self.proc.kill()
            except ProcessLookupError:
                pass
            self.proc.wait()

    def finish(self):
        self._reader.join(timeout=5)
        try:
            self._log.close()
        except OSError as exc:  # its last buffered bytes did not fit
            self.log_error = self.log_error or f"{self.log_path}: {exc.strerror or exc}"
        self._close_pidfd()

    def reason(self) -> str:
        """The child's last error line, for the flight's reason; for a child killed by a signal, that signal."""
        if self.code is not None and self.code < 0:
            try:
                return f"killed by {signal.Signals(-self.code).name}"
            except ValueError:
                return f"killed by signal {-self.code}"
        for line in reversed(self.tail):
            if "error" in line.lower():
                return line.strip()
        return self.tail[-1].strip() if self.tail else "(no output)"


def stop_children(children) -> None:
    """SIGINT to each running child, up to STOP_GRACE_S for all of them to exit, then kill; close their logs."""
    running = [c for c in children if c.code is None]
    for c in running:
        c.interrupt()
    deadline = time.monotonic() + STOP_GRACE_S
    for c in running:
        if c.wait(deadline - time.monotonic()) is None:
            c.kill()
    for c in children:
        c.finish()


# ---------------------------------------------------------------------------------------- ports, folders, argv
def free_udp_ports(n: int) -> list[int]:
    socks = []
    try:
        for _ in range(n):
            s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            s.bind(("127.0.0.1", 0))
            socks.append(s)
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


def new_run_dir(base: str = "runs", tag: str = "") -> Path:
    stamp = time.strftime("%Y%m%d-%H%M%S")
    root = Path(base)
    root.mkdir(parents=True, exist_ok=True)
    for i in range(1000):
        d = root / (f"{stamp}{tag}" + (f"-{i + 1}" if i else ""))
        try:
            d.mkdir()
            return d
        except FileExistsError:
            continue
    raise RuntimeError(f"cannot create a new run folder under {root}")


def cpu_times() -> tuple[float, float] | None:
    """The machine's CPU time so far, (busy, total) in clock ticks of every CPU (``/proc/stat``), or None where there
    is no such file."""
    try:
        with open("/proc/stat") as f:
            fields = [float(v) for v in f.readline().split()[1:]]
    except (OSError, ValueError):
        return None
    idle = fields[3] + (fields[4] if len(fields) > 4 else 0.0)  # idle and iowait
    return sum(fields) - idle, sum(fields)


def machine_load(since: tuple[float, float] | None) -> dict | None:
    """How busy the machine was since ``cpu_times()`` gave ``since``: ``busy`` (share of every CPU's time), ``load1``
    (the 1-minute load average), ``cpus``; None without /proc/stat."""
    now = cpu_times()
    if since is None or now is None or now[1] <= since[1]:
        return None
    try:
        load1 = os.getloadavg()[0]
    except OSError:
        load1 = None
    return {"busy": (now[0] - since[0]) / (now[1] - since[1]), "load1": load1, "cpus": os.cpu_count() or 1}
