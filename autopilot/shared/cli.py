"""Command-line plumbing shared by every entry point: a one-line-error parser and checked argument types.

Every command exits with status 2 and one line ``prog: error: ...`` on a bad flag (``OneLineArgumentParser``).
The argument types reject values that parse but cannot be used (NaN, infinities, out-of-range ports and rates)
with the allowed range in the message.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
from pathlib import Path

from autopilot.shared.process import not_regular
from autopilot.shared.pwm import PwmConfigError, PwmMap


class OneLineArgumentParser(argparse.ArgumentParser):
    """argparse with a one-line error (``prog: error: ...``) and exit status 2 on bad flags."""

    last_error: str | None = None  # the message of the last error (a caller may report it elsewhere too)

    def error(self, message: str):  # noqa: D401
        self.last_error = message
        sys.stderr.write(f"{self.prog}: error: {message}\n")
        raise SystemExit(2)

    def parse_known_args(self, args=None, namespace=None):
        """An unknown ``--flag`` is named first (with the flag it most resembles): otherwise argparse would pass
        its value on to a positional argument and complain of that instead (``--turbulance moderate``: "argument
        profile: invalid choice: 'moderate'")."""
        argv = list(sys.argv[1:] if args is None else args)
        # a command with subcommands leaves their flags to them (each one a parser of this class)
        sub = any(isinstance(a, argparse._SubParsersAction) for a in self._actions)  # noqa: SLF001
        for arg in [] if sub else argv:
            if arg == "--":
                break
            if arg.startswith("--") and len(arg) > 2:
                flag = arg.split("=", 1)[0]
                known = [s for s in self._option_string_actions if s.startswith("--")]
                if flag not in known and not (self.allow_abbrev and any(k.startswith(flag) for k in known)):
                    import difflib

                    like = difflib.get_close_matches(flag, known, n=1)
                    self.error(f"unrecognized argument {flag}" + (f" (did you mean {like[0]}?)" if like else ""))
        return super().parse_known_args(argv, namespace)


def _number(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None


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


def peer_endpoint(text: str) -> tuple[str, int]:
    """``HOST:PORT`` of a peer to send to (port 1..65535): port 0 means "any port" only where a socket is bound,
    and nothing listens on it."""
    host, port = endpoint(text)
    if port == 0:
        raise argparse.ArgumentTypeError(f"a peer's port must be in 1..65535 (0 only binds), got 0 in {text!r}")
    return host, port


def positive_float(text: str) -> float:
    v = _number(text)
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"must be a positive finite number, got {text!r}")
    return v


def nonneg_float(text: str) -> float:
    v = _number(text)
    if not (math.isfinite(v) and v >= 0):
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text!r}")
    return v


def finite_float(text: str) -> float:
    v = _number(text)
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"must be finite, got {text!r}")
    return v


def rate_hz(text: str) -> float:
    """A control or frame rate: positive, at most 1 kHz (a lockstep frame is identified by its millisecond)."""
    from autopilot.shared.mavlink import MAX_LOCKSTEP_RATE_HZ  # pymavlink: only for the commands that fly

    v = positive_float(text)
    if v > MAX_LOCKSTEP_RATE_HZ:
        raise argparse.ArgumentTypeError(f"rate must be at most {MAX_LOCKSTEP_RATE_HZ:g} Hz, got {text!r}")
    return v


def bounds_text(lo: float, hi: float, unit: str, *, lo_open: bool = False, hi_open: bool = False) -> str:
    """``[lo, hi] unit`` with ``(`` / ``)`` for an open end: the range an error message gives."""
    return f"{'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'} {unit}".rstrip()


def in_bounds(v: float, lo: float, hi: float, *, lo_open: bool = False, hi_open: bool = False) -> bool:
    """``v`` finite and in the range (``lo_open`` / ``hi_open``: that end excluded)."""
    return math.isfinite(v) and (v > lo if lo_open else v >= lo) and (v < hi if hi_open else v <= hi)


def bounded(lo: float, hi: float, unit: str, *, lo_open: bool = False, hi_open: bool = False, name: str = "bounded"):
    """An argument type: a finite number in [lo, hi] (``lo_open``: (lo, ...; ``hi_open``: ..., hi)); the error
    gives the allowed range.

    For values that parse but cannot be flown: a duration or a clock beyond a day of sim time, a rate the
    process cannot keep, a gain that overflows the law."""
    lo_txt = bounds_text(lo, hi, unit, lo_open=lo_open, hi_open=hi_open)

    def check(text) -> float:
        v = _number(text)
        if not in_bounds(v, lo, hi, lo_open=lo_open, hi_open=hi_open):
            raise argparse.ArgumentTypeError(f"must be in {lo_txt}, got {text!r}")
        return v

    check.__name__ = name
    return check


MAX_SIM_S = 86_400.0  # one day of sim time: the longest flight and the latest start clock
# A square MIMO plant's sideslip envelope, |beta| <= this (deg): a coordinated flight stays within it (autopilot.mimo's
# verdict), so a sideslip setpoint is bounded by it too (refused on a command line or in a CSV, clamped over MAVLink)
SIDESLIP_ENVELOPE_DEG = 10.0
MAX_PHYSICS_RATE_HZ = 100_000.0
MAX_SENSOR_RATE_HZ = 1_000.0
MAX_GAIN = 10_000.0  # L_v, sigma: beyond this the discretised law is meaningless at any control rate
duration_s = bounded(0.0, MAX_SIM_S, "s", lo_open=True, name="duration_s")  # a flight's length
duration_or_0 = bounded(0.0, MAX_SIM_S, "s (0 = until stopped)", name="duration_or_0")
clock_s = bounded(0.0, MAX_SIM_S, "s", name="clock_s")  # a start clock
timeout_s = bounded(0.0, MAX_SIM_S, "s", lo_open=True, name="timeout_s")
physics_rate_hz = bounded(0.0, MAX_PHYSICS_RATE_HZ, "Hz", lo_open=True, name="physics_rate_hz")
sensor_rate_hz = bounded(0.0, MAX_SENSOR_RATE_HZ, "Hz", lo_open=True, name="sensor_rate_hz")
gain = bounded(0.0, MAX_GAIN, "", name="gain")
angle_deg = bounded(-180.0, 180.0, "deg", name="angle_deg")
limit_deg = bounded(0.0, 90.0, "deg", lo_open=True, name="limit_deg")
MAX_MESSAGE_RATE_HZ = 1_000.0  # a stream or a setpoint rate: at most one message a millisecond
message_rate_hz = bounded(0.0, MAX_MESSAGE_RATE_HZ, "Hz", lo_open=True, name="message_rate_hz")
stream_rate_or_0 = bounded(0.0, MAX_MESSAGE_RATE_HZ, "Hz (0 = off)", name="stream_rate_or_0")
spin_us = bounded(0.0, 1e6, "us", name="spin_us")  # a busy-wait before a deadline: at most a second
MAX_SEED = 2**63 - 1  # numpy's SeedSequence takes any integer >= 0; this one fits an int64 everywhere


def seed(text) -> int:
    """A random seed: a whole number in [0, 2^63 - 1] (numpy refuses negative ones with a traceback)."""
    try:
        v = int(str(text).strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number in [0, 2^63-1], got {text!r}") from None
    if not 0 <= v <= MAX_SEED:
        raise argparse.ArgumentTypeError(f"must be in [0, 2^63-1], got {text!r}")
    return v


def count(lo: int, hi: int, what: str = "", name: str = "count"):
    """An argument type: a whole number in [lo, hi] (runs, samples, workers)."""

    def check(text) -> int:
        try:
            v = int(str(text).strip())
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number in [{lo}, {hi}], got {text!r}") from None
        if not lo <= v <= hi:
            raise argparse.ArgumentTypeError(f"must be in [{lo}, {hi}]{' ' + what if what else ''}, got {text!r}")
        return v

    check.__name__ = name
    return check


VIEWER_SCHEMES = ("rerun", "rerun+http", "rerun+https")  # rerun.connect_grpc (rerun-sdk 0.41)


def viewer_url(text) -> str:
    """A Rerun viewer's gRPC address for ``--connect``: ``SCHEME://HOST:PORT/proxy`` with SCHEME one of
    rerun, rerun+http, rerun+https (what ``rerun.connect_grpc`` takes), e.g. rerun+http://127.0.0.1:9876/proxy."""
    from urllib.parse import urlsplit

    example = "e.g. rerun+http://127.0.0.1:9876/proxy"
    u = urlsplit(str(text))
    try:
        port = u.port
    except ValueError:
        port = None
    if u.scheme not in VIEWER_SCHEMES or not u.hostname or port is None or not 1 <= port <= 65535:
        raise argparse.ArgumentTypeError(
            f"expected {'|'.join(VIEWER_SCHEMES)}://HOST:PORT/proxy (port 1..65535), {example}; got {text!r}"
        )
    if u.path.rstrip("/") != "/proxy" or u.query or u.fragment:
        raise argparse.ArgumentTypeError(f"the path must be /proxy, {example}; got {text!r}")
    return str(text)


def rt_priority_arg(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer 0..99, got {text!r}") from None
    if not 0 <= v <= 99:
        raise argparse.ArgumentTypeError(f"must be 0..99 (0 = normal scheduling), got {v}")
    return v


def sysid_arg(text: str) -> int:
    """The vehicle's MAVLink system id: an integer 1..254 (0 is the broadcast id, 255 the ground stations')."""
    from autopilot.shared.mavlink import SYSID_RANGE

    lo, hi = SYSID_RANGE
    try:
        if isinstance(text, bool) or not isinstance(text, (int, str)):  # 1.5 or True is no system id
            raise ValueError(text)
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer {lo}..{hi}, got {text!r}") from None
    if not lo <= v <= hi:
        raise argparse.ArgumentTypeError(
            f"must be {lo}..{hi} (0 is the broadcast id, 255 the ground stations'), got {v}"
        )
    return v


def add_sysid_argument(parser: argparse.ArgumentParser, what: str) -> None:
    """``--sysid N``: the vehicle's system id, the same on the autopilot, the SITL and the GCS script."""
    parser.add_argument("--sysid", type=sysid_arg, default=1, metavar="N", help=f"{what} (1..254, default 1)")


def default_physics_rate(control_rate: float, minimum: float = 1000.0) -> float:
    """The smallest whole multiple of the control rate that is at least ``minimum`` Hz (1 kHz): 1000 Hz at
    100 Hz control, 1200 Hz at 400 Hz (lockstep advances a whole number of physics steps per frame)."""
    return control_rate * max(1, math.ceil(minimum / control_rate - 1e-9))


def _probe_folder(folder: Path) -> str | None:
    """Whether a file can really be created in ``folder`` (``os.access`` says yes to root on /proc or a read-only
    mount): a temporary folder made and removed at once; None, or the system's reason."""
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".write-test-", dir=folder))
    except OSError as exc:
        return exc.strerror or str(exc)
    return None


def output_dir_problem(path) -> str | None:
    """None if ``path`` is a writable folder or can be created as one, else why not (one line).  Nothing is
    created: the folder (or the nearest one above it that exists) is probed with a temporary folder."""
    p = Path(path)
    if p.exists():
        if not p.is_dir():
            return f"{path} exists and is not a folder"
        if not os.access(p, os.W_OK | os.X_OK):
            return f"{path}: the folder is not writable"
        why = _probe_folder(p)
        return None if why is None else f"{path}: cannot write in the folder ({why})"
    parent = p.absolute().parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        return f"{path}: {parent} is not a folder"
    if not os.access(parent, os.W_OK | os.X_OK):
        return f"{path}: cannot create it ({parent} is not writable)"
    why = _probe_folder(parent)
    return None if why is None else f"{path}: cannot create it in {parent} ({why})"


def output_file_problem(path) -> str | None:
    """None if the file ``path`` can be written (its folder exists and is writable, it is not a folder), else why
    not (one line).  A path that exists must be a regular file: a character device (``/dev/null``, ``/dev/full``),
    a FIFO or a socket is refused, never replaced by a regular file (the stats are written by a rename) nor
    written into (``/dev/full`` would fail the first flush)."""
    p = Path(path)
    if p.is_dir():
        return f"{path} is a folder"
    what = not_regular(p)
    if what:
        return f"{path} is {what}, not a regular file: give the path of a file (it is never written over)"
    folder = p.absolute().parent
    if not folder.is_dir():
        return f"{path}: no folder {folder}"
    if not os.access(folder, os.W_OK | os.X_OK):
        return f"{path}: the folder {folder} is not writable"
    if p.exists() and not os.access(p, os.W_OK):
        return f"{path}: the file is not writable"
    if p.exists():
        try:
            with open(p, "ab"):
                pass
        except OSError as exc:
            return f"{path}: cannot write the file ({exc.strerror})"
        return None
    why = _probe_folder(folder)
    return None if why is None else f"{path}: cannot create a file in {folder} ({why})"


def check_output_files(parser: argparse.ArgumentParser, args: argparse.Namespace, *names: str) -> None:
    """Before anything runs: each output file flag given (``--stats-json`` for ``stats_json``, ...) must be
    writable, else a one-line parser error (exit 2), so no flight ends with a traceback over a bad path."""
    for name in names:
        path = getattr(args, name, None)
        problem = output_file_problem(path) if path else None
        if problem:
            parser.error(f"--{name.replace('_', '-')}: {problem}")


def add_signing_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--signing-key",
        default=None,
        metavar="FILE",
        help="MAVLink 2 signing: sign everything sent and accept only packets signed with this key (a file of 64 "
        "hex digits, mode 0600: python -m tools.flight.keygen FILE); default off",
    )


def signing_key_from_args(parser: argparse.ArgumentParser, args: argparse.Namespace) -> bytes | None:
    """The key of ``--signing-key`` (None without it); a missing, unreadable, world-readable or short key file is a
    one-line parser error."""
    if args.signing_key is None:
        return None
    from autopilot.shared.signing import KeyFileError, load_key

    try:
        return load_key(args.signing_key)
    except KeyFileError as exc:
        parser.error(f"--signing-key: {exc}")
        raise  # unreachable


def fmt_endpoint(ep) -> str:
    return f"{ep[0]}:{ep[1]}" if ep else "-"


def add_cpu_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--cpu",
        type=int,
        default=None,
        metavar="N",
        help="pin this process to CPU N (Linux sched_setaffinity; default: not pinned)",
    )


def add_rt_priority_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--rt-priority",
        type=rt_priority_arg,
        default=0,
        metavar="N",
        help="run the control thread under SCHED_FIFO priority N (1..99; needs the right to; default 0 = normal)",
    )


def add_pwm_arguments(parser: argparse.ArgumentParser) -> None:
    """The servo calibration flags (``PwmMap``); they must match on the SITL and the autopilot."""
    g = parser.add_argument_group("servo calibration (must match on the SITL and the autopilot)")
    g.add_argument("--pwm-min", type=int, default=1000, help="pulse at -rudder-max, us (default 1000)")
    g.add_argument("--pwm-max", type=int, default=2000, help="pulse at +rudder-max, us (default 2000)")
    g.add_argument("--pwm-trim", type=int, default=1500, help="pulse at 0 deg (neutral), us (default 1500)")
    g.add_argument("--rudder-max-deg", type=float, default=30.0, help="deflection at pwm-min/max, deg (default 30)")
    g.add_argument(
        "--rudder-channel", type=int, default=4, help="SERVO_OUTPUT_RAW channel of the rudder, 1..16 (default 4)"
    )
    g.add_argument(
        "--channel2",
        type=int,
        default=0,
        metavar="N",
        help="a square MIMO plant (jsbsim:MODEL:surface=aileron+rudder): the SERVO_OUTPUT_RAW channel of the second "
        "surface, 1..16, the first on --rudder-channel (the launcher: aileron 1, rudder 4, as ArduPilot Plane); "
        "default 0: one surface",
    )


def pwm2_from_args(parser: argparse.ArgumentParser, args: argparse.Namespace) -> PwmMap | None:
    """The second surface's map (``--channel2``: the same calibration on its own channel), None without it."""
    if not args.channel2:
        return None
    if args.channel2 == args.rudder_channel:
        parser.error(f"--channel2 {args.channel2} is the first surface's channel (--rudder-channel)")
    try:
        return PwmMap(args.pwm_min, args.pwm_max, args.pwm_trim, math.radians(args.rudder_max_deg), args.channel2)
    except PwmConfigError as exc:
        parser.error(str(exc))
        raise  # unreachable


def pwm_from_args(parser: argparse.ArgumentParser, args: argparse.Namespace) -> PwmMap:
    try:
        return PwmMap(args.pwm_min, args.pwm_max, args.pwm_trim, math.radians(args.rudder_max_deg), args.rudder_channel)
    except PwmConfigError as exc:
        parser.error(str(exc))
        raise  # unreachable
