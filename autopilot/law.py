"""The law interface: what a control law is to the product; a user's own law from a file (docs/adding-a-law.md).

A law is a class with (the :class:`Law` protocol)::

    Config                 its configuration: a frozen dataclass whose keywords include control_rate_hz (Hz) and
                           u_limit_rad (rad); Config(control_rate_hz=..., u_limit_rad=...) is its default design
    PARAMETERS             its parameter table: rows (NAME, field, unit, lower, upper, description), NAME at most
                           16 characters under the law's own prefix, field a field of Config
    PARAMETER_ALIASES      optional: {OLD_NAME: NAME}, the names its parameters had before; a ground station's
                           PARAM_SET / PARAM_REQUEST_READ and a parameter file by OLD_NAME act on NAME
                           (autopilot.params, "Aliases"); PARAM_REQUEST_LIST lists NAME only; not under
                           CLSAC_ or SYS_ (the autopilot's own)
    TELEMETRY_FIELDS       the names of its own telemetry (telemetry() returns them, as floats)
    __init__(config)
    step(roll, roll_rate, yaw_rate, command) -> surface command (rad)   measured roll (rad), rates (rad/s), command
                           (rad); a step that takes a keyword ``sideslip`` (or ``**measurements``) gets the
                           measured sideslip too (rad, AOA_SSA's on a square MIMO plant; NaN where the autopilot
                           has none: every one-surface plant), a step without it is called as above (:data:`SIDESLIP`)
    reset()                back to rest
    hold(u_applied)        the surface it asked for was not applied (``u_applied`` flew): freeze what adapts
    telemetry() -> dict    its TELEMETRY_FIELDS after the last step
    reconfigure(config)    optional: fly ``config`` from the next step (a ground station's PARAM_SET); without it
                           the law's ``config`` attribute is replaced, and a law that reads ``self.config`` each
                           step flies the new values
    configure(**options)   optional classmethod: its configuration from the command line's options (control_rate_hz,
                           u_limit_rad, gains, ...; SI); without it Config(control_rate_hz=, u_limit_rad=)

Optional class attributes: ``NAME`` (its name in headers and summary.json; default the spec), ``LABEL`` (its
words in pictures; default NAME).  A square MIMO plant refuses such a law, with the reason (one surface only).

:func:`load` loads ``FILE.py:Class``, ``module:Class`` or an entry point of the group :data:`ENTRY_POINT_GROUP`
(``[project.entry-points."clsac_autopilot.laws"] NAME = "package.module:Class"``) and :func:`check` says, in one
line, what a class lacks.  Code is loaded from the command line or an installed entry point only: nothing a
socket carries names a module (the autopilot process gets the spec from its own argv).

:class:`Flown` is how the control step (``autopilot.step.ControlStep``) flies such a law: the measurements in,
the command limited to +-u_limit, the open-loop reference model y_m,ol of the metrics and the envelope (paper eq.
(3), A_m = -5, B_m = 5, C_m = 1, exact ZOH), and a law that raises or returns NaN/inf reported as
:class:`LawFailure` (the step flies a hold instead: rudder neutral).
"""

from __future__ import annotations

import dataclasses
import importlib
import importlib.util
import inspect
import keyword
import math
import sys
from pathlib import Path
from typing import Protocol, runtime_checkable

ENTRY_POINT_GROUP = "clsac_autopilot.laws"
METHODS = ("step", "reset", "hold", "telemetry")
PARAM_ID_LEN = 16  # PARAM_VALUE.param_id
RESERVED = ("CLSAC_", "SYS_")  # the autopilot's own parameters' prefixes (autopilot.params): no user law's alias


SIDESLIP = "sideslip"  # the optional keyword of step: the measured sideslip (rad), NaN where it is not measured


def takes_sideslip(step) -> bool:
    """Whether a law's ``step`` takes the sideslip: a parameter :data:`SIDESLIP` that can be given by keyword, or
    ``**kwargs``.  A step written before it (four positional measurements) is called as it was."""
    try:
        sig = inspect.signature(step)
    except (TypeError, ValueError):
        return False
    by_keyword = (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)
    return any(
        (p.name == SIDESLIP and p.kind in by_keyword) or p.kind is inspect.Parameter.VAR_KEYWORD
        for p in sig.parameters.values()
    )


class LawSpecError(ValueError):
    """A ``--controller`` spec that cannot be flown: one line saying what is missing."""


class LawFailure(RuntimeError):
    """A law raised, or returned NaN or inf, in mid-flight: the step flies a hold instead."""


@runtime_checkable
class Law(Protocol):
    """A control law (module docstring)."""

    PARAMETERS: tuple
    TELEMETRY_FIELDS: tuple

    def step(self, roll: float, roll_rate: float, yaw_rate: float, command: float) -> float: ...  # [, sideslip=]

    def reset(self) -> None: ...

    def hold(self, u_applied: float) -> None: ...

    def telemetry(self) -> dict: ...


def is_spec(name: str) -> bool:
    """A user's law (``FILE.py:Class``, ``module:Class``), not a registered name."""
    return ":" in str(name)


def _import_file(path: Path):
    """The module of a Python file, registered in ``sys.modules`` under a name of its own (so its classes pickle
    by reference in a process that loads the same file)."""
    name = "clsac_user_law_" + "".join(c if c.isalnum() else "_" for c in str(path.resolve()))
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:
        raise LawSpecError(f"{path}: not a Python file")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise
    return module


def _why(exc: BaseException) -> str:
    text = str(exc).splitlines()[0] if str(exc) else ""
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def load(spec: str):
    """The class a spec names: ``FILE.py:Class``, ``module:Class``, or the name of an installed entry point of
    :data:`ENTRY_POINT_GROUP`.  LawSpecError (one line) if it cannot be loaded, or lacks what a law needs."""
    spec = str(spec)
    where, _, cls_name = spec.rpartition(":")
    if not is_spec(spec):
        point = entry_point(spec)
        if point is None:
            raise LawSpecError(f"{spec}: no such law")
        try:
            cls = point.load()
        except Exception as exc:  # noqa: BLE001  (one line: whatever the package raised)
            raise LawSpecError(f"{spec}: entry point {point.value} does not load: {_why(exc)}") from None
        check(cls, spec)
        return cls
    if not where or not cls_name.isidentifier():
        raise LawSpecError(f"{spec}: expected FILE.py:Class or module:Class")
    try:
        if where.endswith(".py") or "/" in where or "\\" in where:
            path = Path(where)
            if not path.is_file():
                raise LawSpecError(f"{spec}: no file {where}")
            module = _import_file(path)
        else:
            module = importlib.import_module(where)
    except LawSpecError:
        raise
    except BaseException as exc:  # noqa: BLE001  (a user's file may raise anything while it imports)
        if isinstance(exc, KeyboardInterrupt):
            raise
        raise LawSpecError(f"{spec}: {where} does not import: {_why(exc)}") from None
    cls = getattr(module, cls_name, None)
    if cls is None:
        raise LawSpecError(f"{spec}: {where} has no {cls_name}")
    check(cls, spec)
    return cls


def entry_point(name: str):
    """The installed entry point ``name`` of :data:`ENTRY_POINT_GROUP`, or None."""
    from importlib.metadata import entry_points

    for point in entry_points(group=ENTRY_POINT_GROUP):
        if point.name == name:
            return point
    return None


def installed() -> tuple[str, ...]:
    """The names of the installed entry points of :data:`ENTRY_POINT_GROUP`."""
    from importlib.metadata import entry_points

    return tuple(sorted(p.name for p in entry_points(group=ENTRY_POINT_GROUP)))


def check(cls, spec: str = "") -> None:
    """LawSpecError naming the first thing ``cls`` lacks to be flown as a law (module docstring)."""
    who = spec or getattr(cls, "__name__", repr(cls))
    if not isinstance(cls, type):
        raise LawSpecError(f"{who}: not a class")
    missing = [m for m in METHODS if not callable(getattr(cls, m, None))]
    if missing:
        raise LawSpecError(f"{who}: the law has no {', '.join(missing)} (a law needs {', '.join(METHODS)})")
    config = getattr(cls, "Config", None)
    if not (isinstance(config, type) and dataclasses.is_dataclass(config)):
        raise LawSpecError(f"{who}: the law has no Config (a dataclass of its configuration)")
    fields = {f.name for f in dataclasses.fields(config)}
    lacks = [f for f in ("control_rate_hz", "u_limit_rad") if f not in fields]
    if lacks:
        raise LawSpecError(f"{who}: its Config has no {', '.join(lacks)}")
    telemetry = getattr(cls, "TELEMETRY_FIELDS", None)
    if not isinstance(telemetry, (tuple, list)) or not all(
        isinstance(f, str) and f.isidentifier() and not keyword.iskeyword(f) for f in telemetry
    ):
        raise LawSpecError(f"{who}: TELEMETRY_FIELDS must be a tuple of names, got {telemetry!r}")
    rows = getattr(cls, "PARAMETERS", None)
    if not isinstance(rows, (tuple, list)):
        raise LawSpecError(f"{who}: PARAMETERS must be a tuple of (NAME, field, unit, lower, upper, description)")
    for row in rows:
        if not (isinstance(row, (tuple, list)) and len(row) == 6):
            raise LawSpecError(f"{who}: a PARAMETERS row must be (NAME, field, unit, lower, upper, doc): {row!r}")
        name, field, _unit, lo, hi, _doc = row
        if not (isinstance(name, str) and name and len(name) <= PARAM_ID_LEN and name.isascii()):
            raise LawSpecError(f"{who}: parameter name {name!r} must be 1 to {PARAM_ID_LEN} ASCII characters")
        if field not in fields:
            raise LawSpecError(f"{who}: parameter {name}: its Config has no field {field!r}")
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in (lo, hi)):
            raise LawSpecError(f"{who}: parameter {name}: bounds must be finite numbers")
        if lo > hi:
            raise LawSpecError(f"{who}: parameter {name}: lower bound {lo:g} above upper {hi:g}")
    aliases = getattr(cls, "PARAMETER_ALIASES", None) or {}
    if not isinstance(aliases, dict):
        raise LawSpecError(f"{who}: PARAMETER_ALIASES must be a dict {{OLD_NAME: NAME}}, got {aliases!r}")
    names = {row[0] for row in rows}
    for old, new in aliases.items():
        if not (isinstance(old, str) and old and len(old) <= PARAM_ID_LEN and old.isascii()):
            raise LawSpecError(f"{who}: alias {old!r} must be 1 to {PARAM_ID_LEN} ASCII characters")
        if new not in names:
            raise LawSpecError(f"{who}: alias {old} names {new!r}, not a parameter of its table")
        if old in names:
            raise LawSpecError(f"{who}: alias {old} is a parameter's own name")
        if old.startswith(RESERVED):
            raise LawSpecError(f"{who}: alias {old}: {' and '.join(RESERVED)} names are the autopilot's own")


def configure(cls, **options):
    """A user law's configuration from the command line's options: its Config's defaults with the control rate and
    the command limit (``control_rate_hz``, ``u_limit_rad``); ConfigError (one line) if the Config refuses."""
    from autopilot.config import ConfigError

    try:
        own = getattr(cls, "configure", None)  # optional: the law reads the options it wants (every flag's value)
        if callable(own):
            return own(**options)
        return cls.Config(control_rate_hz=options["control_rate_hz"], u_limit_rad=options["u_limit_rad"])
    except ConfigError:
        raise
    except Exception as exc:  # noqa: BLE001  (a user's Config may raise anything)
        raise ConfigError(f"{cls.__name__}.Config: {_why(exc)}") from None


# The open-loop reference model of the metrics (paper eq. (3), sec. 5.1): x' = A_m x + B_m u_m, y = C_m x
AM, BM, CM = -5.0, 5.0, 1.0


class Flown:
    """A law on the interface as the control step flies it: ``u = flown(y, um, p, r)`` (rad in, rad out, limited).

    It keeps what the step, the metrics, the envelope and the recording's common row read of any law: ``um``,
    ``y`` (= ``ya``), ``ym_ol`` (= ``ym``: no closed-loop reference model), ``e`` = y_m,ol - y, ``u_raw``, ``u``,
    ``saturated``, ``config``; CL-SAC's PFC output and gains are NaN (not drawn); ``law_row()`` is the law's own
    telemetry, by its ``TELEMETRY_FIELDS``.

    ``y2``: the measured sideslip (rad), which the loop sets before each step where the plant measures it (a square
    MIMO plant's AOA_SSA: ``autopilot.loop.handlers``, in lockstep and real time; ``tools.experiment.mimo_inprocess``
    in-process), as it sets ``autopilot.mimo.MimoLaw``'s; NaN elsewhere.  A law whose step takes it
    (:func:`takes_sideslip`) gets it as ``sideslip=``."""

    MEASURES = True  # ControlStep passes the rates

    def __init__(self, inner, name: str):
        self.inner = inner
        self.name = name
        self.config = inner.config
        self.fields = tuple(inner.TELEMETRY_FIELDS)
        self.dt = 1.0 / float(self.config.control_rate_hz)
        self._phi = math.exp(AM * self.dt)  # exact ZOH of the scalar reference model
        self._gam = (self._phi - 1.0) / AM * BM
        self.registered_law = name
        self.y2 = math.nan  # the sideslip (rad): set by the loop where the plant measures it (class docstring)
        self._sideslip = takes_sideslip(inner.step)
        self._zero()

    def _zero(self) -> None:
        self.steps = 0
        self.xm = 0.0
        self.frozen = False
        self.um = self.y = self.ym = self.ym_ol = self.ya = self.e = 0.0
        self.u_raw = self.u = 0.0
        self.saturated = False
        # CL-SAC's own fields of the recording's row: not this law's, NaN (not drawn), never a faked 0
        nan = math.nan
        self.y_pfc = self.kpe = self.kie = self.ke = self.kpx = self.kix = self.kx = self.kpu = self.kiu = self.ku = nan

    def reset(self) -> None:
        self.inner.reset()
        self._zero()

    def reconfigure(self, config) -> None:
        own = getattr(self.inner, "reconfigure", None)
        if own is not None:
            own(config)
        else:
            self.inner.config = config
        self.config = config

    def __call__(self, y, um, p=0.0, r=0.0) -> float:
        from autopilot.config import NonFiniteInputError

        y, um, p, r = float(y), float(um), float(p), float(r)
        if not (math.isfinite(y) and math.isfinite(um) and math.isfinite(p) and math.isfinite(r)):
            raise NonFiniteInputError(f"controller inputs must be finite, got y={y!r}, um={um!r}, p={p!r}, r={r!r}")
        ym_ol = CM * self.xm  # y_m,ol = C_m x_m,ol (paper eq. (3))
        try:
            if self._sideslip:
                u_raw = float(self.inner.step(y, p, r, um, sideslip=float(self.y2)))
            else:
                u_raw = float(self.inner.step(y, p, r, um))
        except Exception as exc:  # noqa: BLE001  (any error of the law is its failure, never the loop's)
            raise LawFailure(f"law {self.name} raised {_why(exc)}") from exc
        if not math.isfinite(u_raw):
            raise LawFailure(f"law {self.name} returned {u_raw!r}")
        umax = float(self.config.u_limit_rad)
        u = umax if u_raw > umax else (-umax if u_raw < -umax else u_raw)
        self.xm = self._phi * self.xm + self._gam * um
        self.um, self.y, self.ym, self.ym_ol, self.ya, self.e = um, y, ym_ol, ym_ol, y, ym_ol - y
        self.u_raw, self.u, self.saturated = u_raw, u, u != u_raw
        self.frozen = False
        self.steps += 1
        return u

    def hold(self, u_applied=0.0) -> None:
        """Someone else's command flew: the law's own hold; the reference model stands still (as the baseline's).
        LawFailure if the law's hold raises."""
        self.u = self.u_raw = float(u_applied)
        self.frozen = True
        try:
            self.inner.hold(float(u_applied))
        except Exception as exc:  # noqa: BLE001  (any error of the law is its failure, never the loop's)
            raise LawFailure(f"law {self.name} raised {_why(exc)} in hold") from exc

    def telemetry(self) -> tuple:
        """The CL-SAC-shaped row of every flight recording (``autopilot.clsac.TELEMETRY_FIELDS``)."""
        from autopilot.clsac import telemetry_of

        return telemetry_of(self)

    def law_row(self) -> tuple[float, ...]:
        """The law's own telemetry, by its TELEMETRY_FIELDS (NaN for a field it did not give)."""
        try:
            values = self.inner.telemetry()
        except Exception:  # noqa: BLE001
            values = {}
        out = []
        for f in self.fields:
            try:
                out.append(float(values.get(f, math.nan)))
            except (TypeError, ValueError):
                out.append(math.nan)
        return tuple(out)
