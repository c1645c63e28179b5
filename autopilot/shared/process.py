"""Process plumbing shared by the three flight processes: exit codes, signals, atomic JSON, CPU and RT scheduling."""

from __future__ import annotations

import errno
import json
import os
import signal
import stat
import sys
import threading
import time

# Exit statuses every process and the launcher use.
EXIT_OK = 0
EXIT_FAILED = 1
EXIT_USAGE = 2  # a bad flag: one line on stderr (OneLineArgumentParser)
EXIT_OUT_OF_ENVELOPE = 3  # the launcher: flown to the end, but not controlled (autopilot.envelope)
EXIT_ADDRESS_IN_USE = 98  # a UDP port was taken (errno EADDRINUSE): the launcher retries with other ports
EXIT_INTERRUPTED = 130  # the launcher was stopped with Ctrl-C / SIGTERM


def exit_code_for(exc: OSError) -> int:
    """The exit status for a socket error at start-up: ``EXIT_ADDRESS_IN_USE`` for a taken port, else 1."""
    return EXIT_ADDRESS_IN_USE if getattr(exc, "errno", None) == errno.EADDRINUSE else EXIT_FAILED


def install_stop_handlers(callback) -> None:
    """SIGINT and SIGTERM call ``callback()`` (which should only set a flag); the loops then stop cleanly."""

    def _handler(signum, frame):  # noqa: ARG001
        callback()

    signal.signal(signal.SIGINT, _handler)
    signal.signal(signal.SIGTERM, _handler)


def not_regular(path: str | os.PathLike) -> str | None:
    """What ``path`` is if it exists and is not a regular file ("a character device", "a folder", "a FIFO", ...),
    else None (also for a path that does not exist).  Symbolic links are followed: a link to a regular file is one."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        return None
    except OSError as exc:
        return f"not readable ({exc.strerror})"
    if stat.S_ISREG(mode):
        return None
    kinds = (
        (stat.S_ISDIR, "a folder"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISFIFO, "a FIFO"),
        (stat.S_ISSOCK, "a socket"),
    )
    return next((what for test, what in kinds if test(mode)), "not a regular file")


class NotRegularFileError(OSError):
    """An output path that exists and is not a regular file: never replaced, never written into."""


def write_json_atomic(path: str | os.PathLike, doc: dict, *, indent: int = 1, allow_nan: bool = True) -> None:
    """Write ``doc`` as JSON to ``path`` via a temporary file and a rename, so readers never see half a file.

    A ``path`` that exists and is not a regular file (``/dev/null``, a FIFO) raises :class:`NotRegularFileError`:
    the rename would replace a device with a regular file (the command lines refuse such a path before anything
    runs, ``autopilot.shared.cli.output_file_problem``)."""
    path = os.fspath(path)
    what = not_regular(path)
    if what:
        raise NotRegularFileError(f"{path} is {what}, not a regular file: not replaced")
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(doc, f, indent=indent, allow_nan=allow_nan)
    os.replace(tmp, path)


def write_failure(path: str | os.PathLike, write) -> str | None:
    """Call ``write()``; an OSError (a full disk, a vanished folder) becomes one line naming ``path``, else None."""
    try:
        write()
    except OSError as exc:
        return f"{os.fspath(path)}: {exc.strerror or exc}"
    return None


def report_write_failures(who: str, failures: list[str], code: int) -> int:
    """Say each output that could not be written (``who: error: could not write PATH: reason``) and return the exit
    status: ``code``, or 1 if it was 0 and something failed (what was written is kept)."""
    for failure in failures:
        print(f"{who}: error: could not write {failure} (what was written before is kept)", file=sys.stderr, flush=True)
    return code or (EXIT_FAILED if failures else EXIT_OK)


def write_stats_json(path: str | os.PathLike, stats: dict) -> None:
    """A process's stats file (``--stats-json``): ``stats`` and ``cpu_s``, the CPU seconds (user plus system, every
    thread) this process has used so far, its start-up and imports included (``tools.bench launch`` reports them
    per process: on a shared machine the CPU says where the time goes, the wall clock says how busy it was)."""
    write_json_atomic(path, {**stats, "cpu_s": round(time.process_time(), 4)})


def apply_cpu(parser, cpu: int | None) -> None:
    """Pin this process to CPU ``cpu`` (``--cpu``); a bad CPU is a one-line parser error."""
    if cpu is None:
        return
    try:
        os.sched_setaffinity(0, {cpu})
    except (OSError, AttributeError, ValueError) as exc:
        parser.error(f"--cpu {cpu}: {exc}")


def move_other_threads(off_cpu: int) -> int:
    """Move every other thread of this process (telemetry writer, Rerun's own) off ``off_cpu`` onto the rest of
    the CPUs the process may use, so the calling (control) thread has that CPU to itself. Returns how many
    threads were moved. Linux only (per-thread affinity); elsewhere does nothing."""
    try:
        tids = [int(t) for t in os.listdir("/proc/self/task")]
        allowed = set(range(os.cpu_count() or 1)) - {off_cpu}
    except (OSError, ValueError):
        return 0
    me = threading.get_native_id()
    moved = 0
    for tid in tids:
        if tid == me or not allowed:
            continue
        try:
            os.sched_setaffinity(tid, allowed)
            moved += 1
        except OSError:  # the thread ended meanwhile, or no right to
            pass
    return moved


def rt_throttling() -> str:
    """The kernel's real-time throttling as text ("" when off or unknown): SCHED_FIFO threads together get at
    most sched_rt_runtime_us of every sched_rt_period_us, then are stopped until the period ends."""
    try:
        with open("/proc/sys/kernel/sched_rt_runtime_us") as f:
            runtime = int(f.read())
        with open("/proc/sys/kernel/sched_rt_period_us") as f:
            period = int(f.read())
    except (OSError, ValueError):
        return ""
    if runtime < 0:
        return ""
    return f"sched_rt_runtime_us {runtime} of sched_rt_period_us {period}"


def apply_rt_priority(prio: int, who: str) -> str:
    """SCHED_FIFO at ``prio`` for the calling thread only (a control loop's usual set-up); returns a note.

    Call it after the helper threads exist (telemetry writer, rerun's own): Linux scheduling policies are
    per thread, so they stay normal and cannot hold the control thread off its CPU at equal FIFO priority.
    ``SCHED_RESET_ON_FORK`` makes any thread or process started later begin as a normal one too.
    """
    if not prio:
        return ""
    try:
        policy = os.SCHED_FIFO | getattr(os, "SCHED_RESET_ON_FORK", 0)
        os.sched_setscheduler(0, policy, os.sched_param(prio))
        return f"; SCHED_FIFO priority {prio}"
    except (OSError, AttributeError) as exc:
        print(f"{who}: warning: cannot use SCHED_FIFO ({exc}); normal priority", file=sys.stderr, flush=True)
        return ""


class _ClosedPipeSafe:
    """A text stream whose reader may go away (``python -m tools.launch | head``): the first BrokenPipeError points
    the file descriptor at /dev/null, and the flight goes on to its end, its files and its exit code."""

    def __init__(self, stream):
        self._stream = stream

    def _closed(self) -> None:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, self._stream.fileno())
        os.close(devnull)

    def write(self, text: str) -> int:
        try:
            return self._stream.write(text)
        except BrokenPipeError:
            self._closed()
            return len(text)

    def flush(self) -> None:
        try:
            self._stream.flush()
        except BrokenPipeError:
            self._closed()

    def __getattr__(self, name):
        return getattr(self._stream, name)


def survive_closed_stdout() -> None:
    """``sys.stdout`` made safe against a reader that closes the pipe early (see ``_ClosedPipeSafe``)."""
    if not isinstance(sys.stdout, _ClosedPipeSafe):
        sys.stdout = _ClosedPipeSafe(sys.stdout)
