"""MAVLink conventions shared by the SITL, the autopilot and the GCS script (DESIGN.md section 5).

System/component IDs, the lockstep frame clock (and its uint32 wrap), the roll <-> quaternion mapping,
endpoint parsing and a one-line-error argument parser.  No sockets here (see ``autopilot.link``).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import threading

os.environ.setdefault("MAVLINK20", "1")  # before any pymavlink import (mavutil reads it)

from pymavlink.dialects.v20 import common as mavlink  # noqa: E402, F401  (MAVLink 2, common dialect; re-exported)

# ---------------------------------------------------------------------------------------------- IDs
AUTOPILOT_ID = (1, 1)
SITL_ID = (1, 200)
GCS_ID = (255, 190)

# ---------------------------------------------------------------------------------------- frames
USEC_WRAP = 1 << 32  # SERVO_OUTPUT_RAW.time_usec is uint32: wraps every 4294.967296 s (71.6 min)
MS_WRAP = 1 << 32  # ATTITUDE.time_boot_ms is uint32 too (49.7 days, not handled)
MAX_LOCKSTEP_RATE_HZ = 1000.0  # a frame must be identifiable from a millisecond timestamp


def frame_ms(k: int, rate: float) -> int:
    """time_boot_ms of global frame ``k`` (sim time k / rate), floored to the millisecond."""
    if float(rate).is_integer():
        return (k * 1000) // int(rate)
    return int(math.floor(k * 1000.0 / rate + 1e-6))


def frame_from_ms(ms: int, rate: float) -> int:
    """The global frame index whose :func:`frame_ms` is ``ms`` (exact for rates up to 1 kHz).

    frame_ms floors k*1000/rate, so k lies in [ms*rate/1000, (ms+1)*rate/1000): one integer when rate <= 1000.
    """
    if float(rate).is_integer():
        r = int(rate)
        return -((-ms * r) // 1000)  # ceil(ms * r / 1000)
    return int(math.ceil(ms * rate / 1000.0 - 1e-6))


def frame_usec(k: int, rate: float) -> int:
    """SERVO_OUTPUT_RAW.time_usec that answers frame ``k``: the frame's sim time in microseconds, mod 2**32."""
    if float(rate).is_integer() and 1_000_000 % int(rate) == 0:
        us = k * (1_000_000 // int(rate))
    else:
        us = int(round(k * 1e6 / rate))
    return us % USEC_WRAP


def usec_diff(a: int, b: int) -> int:
    """Signed difference a - b of two uint32 microsecond stamps, assuming |a - b| < 2**31 (wrap-aware)."""
    d = (a - b) % USEC_WRAP
    return d - USEC_WRAP if d >= (USEC_WRAP >> 1) else d


def usec_newer(a: int, b: int) -> bool:
    """True if uint32 stamp ``a`` is strictly after ``b`` (across the 71.6-minute wrap)."""
    return usec_diff(a, b) > 0


def frame_of_time(t: float, rate: float) -> int:
    """The global frame index nearest to sim time ``t`` seconds."""
    return int(round(t * rate))


# ------------------------------------------------------------------------------------- attitude
def roll_to_quaternion(roll: float) -> list[float]:
    """Quaternion [w, x, y, z] of a pure roll (pitch = yaw = 0)."""
    return [math.cos(0.5 * roll), math.sin(0.5 * roll), 0.0, 0.0]


def quaternion_to_roll(q) -> float:
    """Roll angle (rad) of quaternion [w, x, y, z] (ZYX Euler); NaN if the quaternion is unusable."""
    w, x, y, z = (float(v) for v in q)
    n = w * w + x * x + y * y + z * z
    if not math.isfinite(n) or n < 1e-12:
        return math.nan
    return math.atan2(2.0 * (w * x + y * z), n - 2.0 * (x * x + y * y))


# Bits of SET_ATTITUDE_TARGET.type_mask (ATTITUDE_TARGET_TYPEMASK)
TYPEMASK_IGNORE_RATES = 1 | 2 | 4
TYPEMASK_IGNORE_THRUST = 64
TYPEMASK_IGNORE_ATTITUDE = 128
SETPOINT_TYPEMASK = TYPEMASK_IGNORE_RATES | TYPEMASK_IGNORE_THRUST


# ------------------------------------------------------------------------------------------ CLI
class OneLineArgumentParser(argparse.ArgumentParser):
    """argparse with a one-line error (``prog: error: ...``) and exit status 2 on bad flags."""

    def error(self, message: str):  # noqa: D401
        sys.stderr.write(f"{self.prog}: error: {message}\n")
        raise SystemExit(2)


def endpoint(text: str) -> tuple[str, int]:
    """``HOST:PORT`` (port 0..65535) for argparse."""
    host, sep, port = str(text).rpartition(":")
    if not sep or not host:
        raise argparse.ArgumentTypeError(f"expected HOST:PORT, got {text!r}")
    try:
        p = int(port)
    except ValueError:
        raise argparse.ArgumentTypeError(f"port must be an integer, got {port!r} in {text!r}") from None
    if not 0 <= p <= 65535:
        raise argparse.ArgumentTypeError(f"port must be in 0..65535, got {p} in {text!r}")
    return host, p


def positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"must be a positive finite number, got {text!r}")
    return v


def nonneg_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (math.isfinite(v) and v >= 0):
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text!r}")
    return v


def finite_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"must be finite, got {text!r}")
    return v


def rate_hz(text: str) -> float:
    v = positive_float(text)
    if v > MAX_LOCKSTEP_RATE_HZ:
        raise argparse.ArgumentTypeError(f"rate must be at most {MAX_LOCKSTEP_RATE_HZ:g} Hz, got {text!r}")
    return v


def default_physics_rate(control_rate: float, minimum: float = 1000.0) -> float:
    """The smallest whole multiple of the control rate that is at least ``minimum`` Hz (1 kHz): 1000 Hz at
    100 Hz control, 1200 Hz at 400 Hz (lockstep advances a whole number of physics steps per frame)."""
    return control_rate * max(1, math.ceil(minimum / control_rate - 1e-9))


def fmt_endpoint(ep) -> str:
    return f"{ep[0]}:{ep[1]}" if ep else "-"


def add_cpu_argument(parser) -> None:
    parser.add_argument("--cpu", type=int, default=None, metavar="N",
                        help="pin this process to CPU N (Linux sched_setaffinity; default: not pinned)")


def apply_cpu(parser, cpu) -> None:
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


def rt_priority_arg(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer 0..99, got {text!r}") from None
    if not 0 <= v <= 99:
        raise argparse.ArgumentTypeError(f"must be 0..99 (0 = normal scheduling), got {v}")
    return v


def add_rt_priority_argument(parser) -> None:
    parser.add_argument("--rt-priority", type=rt_priority_arg, default=0, metavar="N",
                        help="run the control thread under SCHED_FIFO priority N (1..99; needs the right to; "
                             "default 0 = normal)")


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


def install_stop_handlers(callback) -> None:
    """SIGINT and SIGTERM call ``callback()`` (which should only set a flag); the loops then stop cleanly."""
    import signal

    def _handler(signum, frame):
        callback()

    signal.signal(signal.SIGINT, _handler)
    signal.signal(signal.SIGTERM, _handler)


def write_json_atomic(path: str, doc: dict) -> None:
    """Write ``doc`` as JSON to ``path`` via a temporary file and a rename, so readers never see half a file."""
    import json

    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(doc, f, indent=1)
    os.replace(tmp, path)
