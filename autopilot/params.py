"""The autopilot's parameter table: every controller value as a named MAVLink parameter (docs/spec.md, "MAVLink").

Names are at most 16 characters (PARAM_VALUE.param_id), ``CLSAC_*`` (CL-SAC's and the autopilot's options) but PX4's
``SYS_FAILURE_EN`` and each other law's under its own prefix (the PID's ``PID_*``), values SI
(rad, s, Hz) and sent as REAL32, but for SYS_FAILURE_EN, an INT32 as PX4's (``encode``, ``decode``).
:class:`ParamTable` holds the values, validates a set (a rejected set leaves the value unchanged and raises
:class:`ParamError` with a one-line reason) and builds the :class:`~autopilot.config.ClSacConfig` the law flies.
:func:`load_file` / :func:`save_file` read and write the two parameter-file formats of the ground stations:
MAVProxy's ``NAME VALUE`` lines and QGroundControl's tab-separated ``SYS COMP NAME VALUE TYPE``.

Each law's parameters are under its own prefix (CL-SAC's ``CLSAC_*``, the PID's ``PID_*``, a bench law's
``MRAC_*``, ``L1_*``, ...).  **Aliases**: a parameter keeps the names it had before (``Param.aliases``; a law on
``autopilot.law``'s interface: its ``PARAMETER_ALIASES``), as ``CLSAC_PID_KP`` for ``PID_KP``.  A PARAM_SET or
PARAM_REQUEST_READ by an alias acts on the parameter and is answered by the name asked (the ground station's
handshake waits for that name), a set then also by the parameter's own name, so that every station's list sees the
change; PARAM_REQUEST_LIST lists each parameter once, by its own name; :func:`load_file` reads an alias as the
parameter's own name (a parameter file written before the rename loads as it did).  ArduPilot converts renamed
parameters once and answers by the new name only.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from autopilot.shared import cli
from autopilot.shared.mavlink import MAX_LOCKSTEP_RATE_HZ, mavlink

PARAM_ID_LEN = 16  # PARAM_VALUE.param_id: char[16], no terminator when full (every name here fits)
if TYPE_CHECKING:  # numpy, only where a law is built: the flags' types (arg_type) need none
    from autopilot.config import ClSacConfig

G = cli.MAX_GAIN  # the bound of every gain, weight and coefficient: beyond it the discretised law is meaningless


class ParamError(ValueError):
    """A parameter set or file line was rejected; the message says which name and why."""


@dataclass(frozen=True)
class Param:
    """One parameter: ``name`` (<= 16 chars), the ``ClSacConfig`` field it sets (``field``) or an autopilot
    option (``option``, a key of :class:`ParamTable` ``options``), a unit and a one-line description.

    ``low``/``high`` (``low_open``/``high_open``: that end excluded) bound the value, in SI: the one table of
    bounds that the command-line flags (:func:`arg_type`), parameter files and PARAM_SET all check
    (``ClSacConfig`` checks the law again; for the SISO law every value inside the bounds is a valid law,
    CLSAC_ANTIWINDUP takes 0 or 1 only).
    ``flying_read_only``: rejected once the loop runs."""

    name: str
    unit: str
    doc: str
    field: str | None = None
    option: str | None = None
    low: float = -G
    high: float = G
    low_open: bool = False
    high_open: bool = False
    flying_read_only: bool = False
    mav_type: int = mavlink.MAV_PARAM_TYPE_REAL32  # PARAM_VALUE.param_type (INT32: sent bytewise, ``encode``)
    # The names it had before (``CLSAC_PID_KP`` for ``PID_KP``): a PARAM_SET / PARAM_REQUEST_READ, a parameter file
    # or a flag by one of them acts on this parameter (module docstring, "Aliases"); PARAM_REQUEST_LIST lists
    # ``name`` only
    aliases: tuple[str, ...] = ()

    def bounds(self, per: float = 1.0, unit: str | None = None) -> str:
        """The allowed range as an error message gives it, in units of ``per`` SI units (``unit``)."""
        u = self.unit if unit is None else unit
        return cli.bounds_text(self.low / per, self.high / per, u, lo_open=self.low_open, hi_open=self.high_open)

    def admits(self, value: float) -> bool:
        return cli.in_bounds(value, self.low, self.high, lo_open=self.low_open, hi_open=self.high_open)


# The attitude failsafe's default (CLSAC_FS_ATT_TMO, ``AutopilotOptions.attitude_timeout_s``): here, so that the
# launcher checks a flight's sensor rate against it without importing the loop (35 ms before its children start).
ATTITUDE_TIMEOUT_S = 0.1

# The order is the index of PARAM_REQUEST_READ / PARAM_VALUE.param_index.
PARAMS: tuple[Param, ...] = (
    Param("CLSAC_LV", "1/s", "closed-loop reference gain Lv (paper eq. (18)); mode SAC flies Lv = 0", "lv", low=0.0),
    Param("CLSAC_SIGMA", "1/s", "sigma-modification of K_Ie (paper sec. 2)", field="sigma", low=0.0),
    Param("CLSAC_GAM_PE", "rad^-2", "adaptation weight Gamma_pe (paper sec. 2-3)", field="gamma_pe", low=0.0),
    Param("CLSAC_GAM_IE", "rad^-2/s", "adaptation weight Gamma_Ie", field="gamma_ie", low=0.0),
    Param("CLSAC_GAM_PX", "rad^-2", "adaptation weight Gamma_px", field="gamma_px", low=0.0),
    Param("CLSAC_GAM_IX", "rad^-2/s", "adaptation weight Gamma_Ix", field="gamma_ix", low=0.0),
    Param("CLSAC_GAM_PU", "rad^-2", "adaptation weight Gamma_pu", field="gamma_pu", low=0.0),
    Param("CLSAC_GAM_IU", "rad^-2/s", "adaptation weight Gamma_Iu", field="gamma_iu", low=0.0),
    Param("CLSAC_SIGMA_X", "1/s", "leakage of K_Ix (not in the paper; 0 = paper)", field="sigma_x", low=0.0),
    Param("CLSAC_SIGMA_U", "1/s", "leakage of K_Iu (not in the paper; 0 = paper)", field="sigma_u", low=0.0),
    # A_m < 0: the reference model must be stable (paper eq. (3)); the PFC's stability is ClSacConfig's check
    Param("CLSAC_AM", "1/s", "reference model A_m (paper eq. (3))", field="am", high=0.0, high_open=True),
    Param("CLSAC_BM", "1/s", "reference model B_m", field="bm"),
    # C_m > 0 with L_v >= 0 and A_m < 0 keeps A_m - L_v C_m Hurwitz (paper eq. (19)); a positive PFC with positive
    # denominator coefficients is stable: every value inside these bounds makes a valid law
    Param("CLSAC_CM", "", "reference model C_m", field="cm", low=0.0, low_open=True),
    Param(
        "CLSAC_PFC_NUM", "", "PFC D(s) = NUM / (DEN1 s + DEN0) (paper sec. 5.1: 10)", "pfc_num", low=0, low_open=True
    ),
    Param("CLSAC_PFC_DEN1", "s", "PFC denominator, s coefficient (paper: 4)", "pfc_den", low=0.0, low_open=True),
    Param("CLSAC_PFC_DEN0", "", "PFC denominator, constant (paper: 40)", "pfc_den", low=0.0, low_open=True),
    Param(
        "CLSAC_U_LIMIT", "rad", "rudder command limit", field="u_limit_rad", low=0.0, high=math.pi / 2, low_open=True
    ),
    Param("CLSAC_ANTIWINDUP", "", "conditional-integration anti-windup, 1 on / 0 off", "anti_windup", low=0, high=1),
    Param(
        "CLSAC_RATE",
        "Hz",
        "control rate (read-only while flying)",
        field="control_rate_hz",
        low=0.0,
        high=MAX_LOCKSTEP_RATE_HZ,  # a lockstep frame is identified by its millisecond
        low_open=True,
        flying_read_only=True,
    ),
    Param(
        "CLSAC_FS_ATT_TMO",
        "s",
        "failsafe after this long without attitude",
        option="attitude_timeout_s",
        low=1e-3,
        high=cli.MAX_SIM_S,
    ),
    Param(
        "CLSAC_FS_SP_TMO",
        "s",
        "wings level after this long without setpoint",
        option="setpoint_timeout_s",
        low=0.01,
        high=cli.MAX_SIM_S,
    ),
    Param(
        "CLSAC_MAX_ROLL", "rad", "roll setpoint clamp", option="max_roll_rad", low=0.0, high=math.pi / 2, low_open=True
    ),
    # PX4's name and meaning: MAV_CMD_INJECT_FAILURE is refused (MAV_RESULT_DENIED) unless it is 1
    Param(
        "SYS_FAILURE_EN",
        "",
        "failure injection from a ground station (MAV_CMD_INJECT_FAILURE), 1 on / 0 off",
        option="failure_injection",
        low=0,
        high=1,
        mav_type=mavlink.MAV_PARAM_TYPE_INT32,  # PX4's type: MAVSDK's set_param_int / get_param_int
    ),
)
# The fixed-gain baseline's gains (``autopilot.baseline.BaselineConfig``): its table is the options and these,
# under the PID's own prefix; ``CLSAC_PID_*``, their names until issue 37, are aliases.
BASELINE_PARAMS: tuple[Param, ...] = (
    Param(
        "PID_KP", "", "baseline PID K_p, rad of surface per rad of roll error", "kp", low=0.0, aliases=("CLSAC_PID_KP",)
    ),
    Param("PID_KI", "1/s", "baseline PID K_i", field="ki", low=0.0, aliases=("CLSAC_PID_KI",)),
    Param("PID_KD", "s", "baseline PID K_d", field="kd", low=0.0, aliases=("CLSAC_PID_KD",)),
)
LAW_PARAMS = {"baseline": BASELINE_PARAMS}  # a law's own parameters (autopilot.controllers.LAWS keys), not CL-SAC's
# A square MIMO design's second channel (the sideslip on the rudder; ``tools.design.mimo_report``): read by
# ``autopilot.mimo.from_values``, in no table of the one-channel laws (a SISO flight leaves them, as another law's)
MIMO_PARAMS: tuple[Param, ...] = (
    Param("CLSAC_PFC2_NUM", "", "channel 2's PFC D_2(s) = NUM / (DEN1 s + DEN0)", low=0.0, low_open=True),
    Param("CLSAC_PFC2_DEN1", "s", "channel 2's PFC denominator, s coefficient", low=0.0, low_open=True),
    Param("CLSAC_PFC2_DEN0", "", "channel 2's PFC denominator, constant", low=0.0, low_open=True),
    Param(
        "PID2_KP",
        "",
        "channel 2's baseline PID K_p, rad of surface per rad of sideslip error",
        low=0.0,
        aliases=("CLSAC_PID2_KP",),
    ),
    Param("PID2_KI", "1/s", "channel 2's baseline PID K_i", low=0.0, aliases=("CLSAC_PID2_KI",)),
    Param("PID2_KD", "s", "channel 2's baseline PID K_d", low=0.0, aliases=("CLSAC_PID2_KD",)),
)
ALIASES = {a: p.name for p in PARAMS + BASELINE_PARAMS + MIMO_PARAMS for a in p.aliases}  # old name -> name
BY_NAME = {n: p for p in PARAMS + BASELINE_PARAMS + MIMO_PARAMS for n in (p.name, *p.aliases)}  # aliases too
BINARY = ("CLSAC_ANTIWINDUP", "SYS_FAILURE_EN")  # 0 or 1, nothing between
# The options a caller of ParamTable may leave out (every other option has no default: the caller's flags give it)
OPTION_DEFAULTS = {"failure_injection": 0.0}


# The integer types of PARAM_VALUE / PARAM_SET; their value travels in the float field's four bytes (PX4's
# "bytewise" encoding, MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE, which AUTOPILOT_VERSION states).
INT_TYPES = {
    mavlink.MAV_PARAM_TYPE_UINT8: "<B3x",
    mavlink.MAV_PARAM_TYPE_INT8: "<b3x",
    mavlink.MAV_PARAM_TYPE_UINT16: "<H2x",
    mavlink.MAV_PARAM_TYPE_INT16: "<h2x",
    mavlink.MAV_PARAM_TYPE_UINT32: "<I",
    mavlink.MAV_PARAM_TYPE_INT32: "<i",
}
FLT_MIN = 1.1754943508222875e-38  # the smallest normal float32: an integer below 2^23 sent bytewise is below it


def encode(value: float, mav_type: int) -> float:
    """The PARAM_VALUE.param_value that carries ``value`` as ``mav_type``: the value itself for REAL32, else the
    integer's bytes read as a float32 (bytewise, as PX4 sends it)."""
    fmt = INT_TYPES.get(mav_type)
    if fmt is None:
        return float(value)
    return struct.unpack("<f", struct.pack(fmt, int(value)))[0]


def decode(param_value: float, mav_type: int) -> float:
    """The value a PARAM_SET carries as ``mav_type``: REAL32 (MAVProxy's and pymavlink's default) the float itself;
    an integer type bytewise (MAVSDK, PX4's ground stations), or cast (a station that sends the integer as a float:
    any finite value from the smallest normal float32 up, which no small integer sent bytewise is)."""
    fmt = INT_TYPES.get(mav_type)
    v = float(param_value)
    if fmt is None or not math.isfinite(v) or abs(v) >= FLT_MIN:
        return v
    return float(struct.unpack(fmt, struct.pack("<f", v))[0])


def arg_type(name: str, per: float = 1.0, unit: str | None = None):
    """The argparse type of a flag that sets parameter ``name`` in units of ``per`` SI units (``--u-limit-deg``:
    ``per = pi/180``, ``unit = "deg"``): the parameter's own bounds, in the flag's unit."""
    p = BY_NAME[name]
    text = p.bounds(per, unit)

    def check(value) -> float:
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise argparse.ArgumentTypeError(f"expected a number, got {value!r}") from None
        if not p.admits(v * per):
            raise argparse.ArgumentTypeError(f"must be in {text} ({name}), got {value!r}")
        return v

    check.__name__ = name.lower()
    return check


def law_params(law) -> tuple[Param, ...]:
    """The parameters of a registered law (``autopilot.controllers.Law``): the fixed-gain PID's
    (``BASELINE_PARAMS``), or a law's own table on the law interface (``autopilot.law``: its PARAMETERS rows,
    NAME, field, unit, lower, upper, description)."""
    if law.name in LAW_PARAMS:
        return LAW_PARAMS[law.name]
    aliases = law.aliases()
    return tuple(
        Param(
            name, unit, doc, field=field, low=float(lo), high=float(hi),
            aliases=tuple(a for a, to in aliases.items() if to == name),
        )
        for name, field, unit, lo, hi, doc in law.rows()
    )  # fmt: skip


def canonical(name: str) -> str:
    """The parameter's own name for ``name`` (an alias: ``CLSAC_PID_KP`` -> ``PID_KP``; a registered law's
    ``PARAMETER_ALIASES`` too); any other name as it is."""
    if name in ALIASES:
        return ALIASES[name]
    if name in BY_NAME:
        return name
    from autopilot.controllers import LAWS

    for law in LAWS.values():
        if law.generic:
            to = law.aliases().get(name)
            if to is not None:
                return to
    return name


def known(name: str) -> bool:
    """A parameter of some law (its own name or an alias): the tables here, or a registered law's own
    (``law_params``)."""
    if name in BY_NAME:
        return True
    from autopilot.controllers import LAWS

    return any(name == row[0] for law in LAWS.values() if law.generic for row in law.rows()) or canonical(name) != name


def _config_value(cfg: ClSacConfig, name: str, p: Param | None = None) -> float:
    p = p or BY_NAME[name]
    if name == "CLSAC_PFC_NUM":
        num = cfg.pfc_num
        return float(num[-1]) if len(num) == 1 else math.nan
    if name in ("CLSAC_PFC_DEN1", "CLSAC_PFC_DEN0"):
        den = cfg.pfc_den
        return float(den[0 if name.endswith("1") else 1]) if len(den) == 2 else math.nan
    return float(getattr(cfg, p.field))


class ParamTable:
    """The values of :data:`PARAMS`: ``get``, ``set`` (validated), ``config``.

    ``config``: the configured law (its ``lv`` is the configured L_v, whatever the mode flies).  ``options``:
    the non-law values, keyed by ``Param.option`` (``attitude_timeout_s``, ``setpoint_timeout_s``,
    ``max_roll_rad``; ``failure_injection``, SYS_FAILURE_EN, 0 unless given).  The law's parameters describe the
    SISO CL-SAC law with a first-order PFC; for any other law (the fixed-gain baseline) the table has the options
    only.  ``params``: the parameters, in index order.
    """

    def __init__(self, config, options: dict[str, float]):
        from autopilot.controllers import law_of

        law = law_of(config)
        clsac = law.parameters and config.is_siso and len(config.pfc_den) == 2  # autopilot.controllers
        self.params = PARAMS if clsac else tuple(p for p in PARAMS if p.option) + law_params(law)
        self._generic = law.generic  # a law on autopilot.law's interface: its Config may raise anything
        self._names = {n: p for p in self.params for n in (p.name, *p.aliases)}  # an alias acts on its parameter
        self._config = config
        self._options = {
            p.option: float(options[p.option] if p.option in options else OPTION_DEFAULTS[p.option])
            for p in PARAMS
            if p.option
        }
        self.flying = False  # set by the loop once it runs: CLSAC_RATE is then read-only

    def __len__(self) -> int:
        return len(self.params)

    def __contains__(self, name: str) -> bool:
        return name in self._names

    @property
    def config(self) -> ClSacConfig:
        return self._config

    def option(self, key: str) -> float:
        return self._options[key]

    def get(self, name: str) -> float:
        p = self._names.get(name)
        if p is None:
            raise ParamError(f"unknown parameter {name!r}")
        return self._options[p.option] if p.option else _config_value(self._config, name, p)

    def index(self, name: str) -> int:
        return self.params.index(self._names[name])

    def name_of(self, name: str) -> str:
        """The parameter's own name for ``name`` (its own name, or an alias)."""
        return self._names[name].name

    def items(self) -> list[tuple[str, float]]:
        return [(p.name, self.get(p.name)) for p in self.params]

    def set(self, name: str, value: float, *, build: bool = True) -> float:
        """Set ``name`` to ``value`` (validated); returns the value now held.  Raises :class:`ParamError`
        (value unchanged) for an unknown name, a non-finite value, a read-only parameter or an invalid law."""
        p = self._names.get(name)
        if p is None:
            raise ParamError(f"unknown parameter {name!r}")
        value = float(value)
        if not math.isfinite(value):
            raise ParamError(f"{name} must be finite, got {value!r}")
        if p.flying_read_only and self.flying and value != self.get(name):
            raise ParamError(f"{name} is read-only while flying")
        if not p.admits(value):
            raise ParamError(f"{name} must be in {p.bounds()}, got {value:g}")
        if name in BINARY and value not in (0.0, 1.0):
            raise ParamError(f"{name} must be 0 or 1, got {value:g}")
        if p.option:
            self._options[p.option] = value
            return value
        from autopilot.config import ConfigError

        cfg = self._config
        if name == "CLSAC_PFC_NUM":
            change = {"pfc_num": (value,)}
        elif name == "CLSAC_PFC_DEN1":
            change = {"pfc_den": (value, cfg.pfc_den[1])}
        elif name == "CLSAC_PFC_DEN0":
            change = {"pfc_den": (cfg.pfc_den[0], value)}
        elif name == "CLSAC_ANTIWINDUP":
            change = {"anti_windup": bool(value)}
        else:
            change = {p.field: value}
        try:
            new = dataclasses.replace(cfg, **change) if self._generic else cfg.with_(**change)
            if self._generic and build:  # a law its own constructor refuses (an unstable reference model): not flown
                from autopilot.controllers import make_law

                make_law(new)
            self._config = new
        except ConfigError as exc:
            raise ParamError(f"{name}={value:g} rejected: {exc}") from None
        except Exception as exc:  # noqa: BLE001  (a user's Config may raise anything: the set is refused)
            raise ParamError(f"{name}={value:g} rejected: {type(exc).__name__}: {exc}") from None
        return self.get(name)

    def split(self, values: dict[str, float]) -> tuple[dict[str, float], list[str]]:
        """A parameter file's values: (those for this table, the names of another law's, which it does not fly).
        A name of no law stays in the first: ``update`` refuses it.  So the file ``python -m tools.pfc design``
        writes, with every controller's values, flies each of them."""
        mine = {n: v for n, v in values.items() if n in self._names or not known(n)}
        return mine, [n for n in values if n not in mine]

    def update(self, values: dict[str, float]) -> None:
        """Set several (a loaded file) in one go; the first rejected one raises and nothing is changed."""
        saved = (self._config, dict(self._options))
        try:
            for name, value in values.items():  # a law's values are checked together (a design file's): at the end
                self.set(name, value, build=False)
            if self._generic and values:
                from autopilot.controllers import make_law

                try:
                    make_law(self._config)
                except Exception as exc:  # noqa: BLE001  (ConfigError, or anything a user's law raises)
                    raise ParamError(f"{', '.join(values)}: the law refuses them: {exc}") from None
        except ParamError:
            self._config, self._options = saved
            raise


def load_file(path) -> dict[str, float]:
    """Read a parameter file: MAVProxy's ``NAME VALUE`` (comma or blanks) or QGroundControl's
    ``SYS COMP NAME VALUE TYPE`` lines; ``#`` starts a comment.  An alias is read as its parameter's own name
    (:func:`canonical`: a file with ``CLSAC_PID_KP`` gives ``PID_KP``; a name given twice, the later line).
    Raises :class:`ParamError` naming the line."""
    out: dict[str, float] = {}
    data = Path(path).read_bytes()
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ParamError(f"{path}: not a text parameter file (byte {exc.start} is not UTF-8)") from None
    if "\0" in text:
        raise ParamError(f"{path}: not a text parameter file (it holds NUL bytes)")
    for n, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        fields = line.replace(",", " ").split()
        if len(fields) == 2:
            name, value = fields
        elif len(fields) == 5:
            name, value = fields[2], fields[3]
        else:
            raise ParamError(f"{path}:{n}: expected 'NAME VALUE' or 'SYS COMP NAME VALUE TYPE', got {line!r}")
        try:
            out[name] = float(value)
        except ValueError:
            raise ParamError(f"{path}:{n}: {name}: not a number: {value!r}") from None
    return {canonical(n): v for n, v in out.items()}


def save_file(path, items, *, qgc: bool = False, ids: tuple[int, int] = (1, 1)) -> None:
    """Write ``(name, value)`` pairs in MAVProxy's format (``param load`` reads it) or, ``qgc=True``, in
    QGroundControl's."""
    if qgc:
        lines = ["# Onboard parameters for Vehicle 1", "#", "# Vehicle-Id Component-Id Name Value Type"]
        types = {n: (BY_NAME[n].mav_type if n in BY_NAME else mavlink.MAV_PARAM_TYPE_REAL32) for n, _v in items}
        lines += [f"{ids[0]}\t{ids[1]}\t{n}\t{float(v)!r}\t{types[n]}" for n, v in items]
    else:
        lines = [f"{n:<16s} {float(v)!r}" for n, v in items]  # repr: the exact value back
    Path(path).write_text("\n".join(lines) + "\n")
