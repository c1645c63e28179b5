"""Process plumbing shared by the three flight processes: exit codes, signals, atomic JSON, CPU and RT scheduling."""

from __future__ import annotations

import errno
import json
import math
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


NO_SPACE = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)  # a full disk, a quota, a file-size limit


def json_safe(doc):
    """``doc`` with every non-finite float (NaN, +-Infinity) made None, in dicts, lists and tuples at any depth:
    what the product writes is standard JSON (RFC 8259 has no NaN or Infinity; ``null`` stands for a number that
    has no finite value, e.g. a recovery time never reached)."""
    if isinstance(doc, float):
        return doc if math.isfinite(doc) else None
    if isinstance(doc, dict):
        return {k: json_safe(v) for k, v in doc.items()}
    if isinstance(doc, (list, tuple)):
        return [json_safe(v) for v in doc]
    if type(doc).__module__ == "numpy" and hasattr(doc, "item"):  # a numpy scalar
        return json_safe(doc.item())
    return doc


def standard_json(doc, **kwargs) -> str:
    """``json.dumps`` of ``doc`` as standard JSON: non-finite numbers as null (``json_safe``), never NaN."""
    return json.dumps(json_safe(doc), allow_nan=False, **kwargs)


class SpaceReserve:
    """Disk space held back for a process's last write: ``nbytes`` written to ``path`` at start (as many as fit,
    never an error), deleted when a write fails for want of space, so that the write can be tried again
    (``write_json_atomic(..., reserve=...)``), and deleted at the end (``release``) whatever happened."""

    def __init__(self, path: str | os.PathLike, nbytes: int = 64 * 1024):
        self.path = os.fspath(path)
        self.held = 0
        try:
            with open(self.path, "wb") as f:
                block = os.urandom(4096)  # not zeros: a compressing file system would store those in no space
                while self.held < nbytes:
                    f.write(block)
                    f.flush()
                    self.held += len(block)
        except OSError:  # the disk is full already: what was held is kept
            pass

    def release(self) -> bool:
        """Delete the reserve; True if it held space."""
        held, self.held = self.held, 0
        try:
            os.unlink(self.path)
        except OSError:
            return False
        return held > 0


def reserve_for(path: str | os.PathLike, nbytes: int = 16 * 1024) -> SpaceReserve:
    """The reserve for output ``path``: a hidden file beside it, ``.NAME.reserve``."""
    head, name = os.path.split(os.fspath(path))
    return SpaceReserve(os.path.join(head, f".{name}.reserve"), nbytes)


def write_json_atomic(
    path: str | os.PathLike, doc: dict, *, indent: int = 1, allow_nan: bool = False, reserve: SpaceReserve | None = None
) -> None:
    """Write ``doc`` as JSON to ``path`` via a temporary file and a rename, so readers never see half a file.

    Standard JSON: non-finite numbers are written as ``null`` (``json_safe``; ``allow_nan`` is kept for callers
    and has no effect).  A write that fails leaves no temporary file behind; one that fails for want of space
    (ENOSPC, EDQUOT, EFBIG) is tried once more after ``reserve`` (``SpaceReserve``) is deleted.

    A ``path`` that exists and is not a regular file (``/dev/null``, a FIFO) raises :class:`NotRegularFileError`:
    the rename would replace a device with a regular file (the command lines refuse such a path before anything
    runs, ``autopilot.shared.cli.output_file_problem``)."""
    del allow_nan
    path = os.fspath(path)
    what = not_regular(path)
    if what:
        raise NotRegularFileError(f"{path} is {what}, not a regular file: not replaced")
    text = standard_json(doc, indent=indent)
    try:
        _write_replace(path, text)
    except OSError as exc:
        if exc.errno not in NO_SPACE or reserve is None or not reserve.release():
            raise
        _write_replace(path, text)


def _write_replace(path: str, text: str) -> None:
    tmp = path + ".tmp"
    try:
        with open(tmp, "w") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException as exc:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        if isinstance(exc, OSError) and exc.errno is not None:  # a failed write() names no file: this one does
            raise OSError(exc.errno, exc.strerror, path) from exc
        raise


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


def write_stats_json(path: str | os.PathLike, stats: dict, reserve: SpaceReserve | None = None) -> None:
    """A process's stats file (``--stats-json``): ``stats`` and ``cpu_s``, the CPU seconds (user plus system, every
    thread) this process has used so far, its start-up and imports included (``tools.bench launch`` reports them
    per process: on a shared machine the CPU says where the time goes, the wall clock says how busy it was)."""
    write_json_atomic(path, {**stats, "cpu_s": round(time.process_time(), 4)}, reserve=reserve)


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
