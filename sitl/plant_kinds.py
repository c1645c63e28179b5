"""The plant kinds, one record each (``KINDS``), as ArduPilot's SITL builds each aircraft from one table
(``model_constructors[]``): the interface every plant has (:class:`Plant`), what a kind is (:class:`PlantKind`: how
its spec is recognised and parsed, how it is built, what it flies), and a ``--plant`` value parsed once into a
:class:`PlantSpec` that every consumer reads.  No I/O but the plant file.

Every test of a plant's kind happens here; elsewhere the code reads a spec's fields (``mimo``, ``surfaces``,
``own_atmosphere``, ...) or its kind's.  Adding a kind is one record in ``KINDS`` (docs/plants.md).
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np


class PlantError(ValueError):
    """A --plant value is unusable (a bad file, a bad JSBSim spec or model, a disturbance it cannot fly)."""


@runtime_checkable
class Plant(Protocol):
    """What the SITL flies (``sitl.plant.build``'s result), like ArduPilot's SIM_Aircraft.

    ``advance(delta_command, n, d=None)`` flies n physics steps with the servo command held and the disturbance d
    (one row per step), if any, and returns ``truth``; ``truth`` is [v, p, r, phi, delta, delta_dot]
    (``sitl.model.STATE_NAMES``); ``attitude()`` is (roll, pitch, yaw or None, p, q, r); ``steps`` the physics steps
    flown, ``time`` the sim time (s), ``config.dt`` the physics step (s); ``set_effect`` takes the active faults'
    ``sitl.damage.Effect``."""

    config: Any
    steps: int

    @property
    def time(self) -> float: ...

    @property
    def truth(self) -> np.ndarray: ...

    def advance(self, delta_command: float, n: int, d=None) -> np.ndarray: ...

    def attitude(self) -> tuple: ...

    def set_effect(self, effect) -> None: ...


SCALE = "--scale names KH2013A coefficients"


@dataclass(frozen=True, eq=False, repr=False)
class PlantKind:
    """One kind of plant: its ``name``; ``matches(text)``: whether a --plant value is of this kind (the table is tried
    in order, the last kind takes anything); ``parse(text)``: the kind's own parsed form (None, a
    ``sitl.linear_plant.LinearPlant``, a ``sitl.jsbsim_plant.JsbsimSpec``), raising PlantError; ``check(text,
    physics_rate_hz)``: PlantError unless it can fly (a plant file's physics step at that rate unless None, a JSBSim
    model found with its surfaces and safety pilot); ``construct(spec,
    physics_rate_hz, params, dist, damaged)``: the :class:`Plant`; what the parsed form says (``surfaces``,
    ``surface``: the one the command drives, ``aileron+rudder`` on a MIMO JSBSim plant,
    ``travel``: each surface's stop in rad or None, ``label``: the short name, ``mimo``); the disturbance flags it
    cannot fly, with why (``unsupported``); ``design(text, model)``: where the design of it is found
    (``tools.pfc design``; None: the paper's values are its design, ``paper``); ``linear(text, model)``: the linear
    model it is designed on, (A_p, B_p, C_p) with the servo last and the index of its roll-rate state, None if none;
    ``disturbances(text, model, atmosphere_flags, given)``: PlantError for an atmosphere it cannot carry (beyond
    ``unsupported``); ``atmosphere(model, dist)``: the disturbances ``sitl.disturbances.Injector`` applies on it;
    ``refusals(model)``: the fault kinds it refuses of its own, with why; ``value_refusal(model, fault)``: why it
    cannot fly a fault's value (beyond a surface's travel, checked for every kind); ``keyed``: its spec takes
    comma-separated KEY=VALUE pairs; ``own_atmosphere``: it flies its own (JSBSim);
    ``batched``: the batched robustness study (numpy and C) flies it; ``euler``: its attitude has pitch and yaw;
    ``faults``: the ``sitl.fault_kinds.FaultKind.group`` s it flies (``servo``, ``airframe``, ``mass``);
    ``words``: what it is, in --plant's help (:func:`help_text`)."""

    name: str
    syntax: str
    matches: Callable[[str], bool]
    parse: Callable[[str], Any]
    check: Callable[[str, float | None], None]
    construct: Callable[..., Plant]
    surfaces: Callable[[Any], tuple[str, ...]]
    surface: Callable[[Any], str]
    travel: Callable[[Any], tuple[float | None, ...]]
    label: Callable[[str, Any], str]
    design: Callable[[str, Any], Path | None] = lambda _text, _m: None
    linear: Callable[[str, Any], tuple | None] = lambda _text, _m: None
    mimo: Callable[[Any], bool] = lambda _m: False
    disturbances: Callable[[str, Any, list, dict], None] = lambda _text, _m, _air, _given: None
    atmosphere: Callable[[Any, Any], Any] = lambda _m, dist: dist
    refusals: Callable[[Any], dict] = lambda _m: {}
    value_refusal: Callable[[Any, Any], str | None] = lambda _m, _fault: None
    paper: bool = False
    keyed: bool = False
    unsupported: dict = field(default_factory=dict)
    own_atmosphere: bool = False
    batched: bool = False
    euler: bool = False
    faults: frozenset = frozenset({"servo", "airframe"})
    words: str = ""

    def __repr__(self) -> str:
        return f"PlantKind({self.name!r})"


@dataclass(frozen=True)
class PlantSpec:
    """A --plant value parsed once: ``text`` as given, its :class:`PlantKind`, and ``model``, the kind's parsed form."""

    text: str
    kind: PlantKind
    model: Any = field(compare=False, repr=False)

    @property
    def name(self) -> str:
        """The plant's short name (headers, titles, run folders): ``KH2013A``, the JSBSim model (``c172x``, with
        ``-rudder`` on its rudder), a plant file's ``name`` (else its file name)."""
        return self.kind.label(self.text, self.model)

    @property
    def surfaces(self) -> tuple[str, ...]:
        """The surfaces, one per input, in the plant's order (``("rudder",)`` on the KH2013A)."""
        return self.kind.surfaces(self.model)

    @property
    def surface(self) -> str:
        """The surface the plant's command drives: ``rudder`` (the KH2013A), a plant file's ``[input] surface``, a
        JSBSim spec's ``surface`` (aileron by default; ``aileron+rudder`` on a MIMO plant)."""
        return self.kind.surface(self.model)

    @property
    def travel(self) -> tuple[float | None, ...]:
        """Each surface's stop from neutral (rad), None where the plant has none."""
        return self.kind.travel(self.model)

    @property
    def mimo(self) -> bool:
        """A square plant of more than one input (``jsbsim:MODEL:surface=aileron+rudder``, a plant file of m > 1)."""
        return self.kind.mimo(self.model)

    @property
    def paper(self) -> bool:
        """The paper's own aircraft (the KH2013A): its design is the paper's values."""
        return self.kind.paper

    @property
    def design_file(self) -> Path | None:
        """Where its design is looked for (docs/plants.md, "Where a design is found"), None for the paper's."""
        return self.kind.design(self.text, self.model)

    @property
    def linear_model(self) -> tuple | None:
        """(A_p, B_p, C_p, roll-rate state index or None) it is designed on, None if there is none."""
        return self.kind.linear(self.text, self.model)

    @property
    def own_atmosphere(self) -> bool:
        return self.kind.own_atmosphere

    @property
    def batched(self) -> bool:
        return self.kind.batched

    @property
    def euler(self) -> bool:
        return self.kind.euler

    @property
    def jsbsim(self):
        """The ``sitl.jsbsim_plant.JsbsimSpec`` of a JSBSim aircraft, else None."""
        return self.model if self.kind.own_atmosphere else None

    @property
    def linear(self):
        """The ``sitl.linear_plant.LinearPlant`` of a plant file, else None."""
        from sitl.linear_plant import LinearPlant

        return self.model if isinstance(self.model, LinearPlant) else None


# ---------------------------------------------------------------------------------------------- the KH2013A
KH2013A = "kh2013a"


def _kh_build(spec: PlantSpec, physics_rate_hz: float, params=None, dist=None, damaged=False) -> Plant:  # noqa: ARG001
    from sitl.aircraft import Aircraft, AircraftConfig

    return Aircraft(AircraftConfig(physics_rate_hz=physics_rate_hz), params=params)


def _kh_linear(_text: str, _m) -> tuple:
    from sitl import model

    return model.A_P, model.B_P, model.C_P, model.P


# ---------------------------------------------------------------------------------------------- a plant file
def _linear_of(lp) -> tuple:
    from sitl.damage import roll_rate_index

    return lp.a_p, lp.b_p, lp.c_p, roll_rate_index(lp.truth)


def _file_parse(text: str, physics_rate_hz: float | None = None):
    from sitl.linear_plant import PlantFileError, load

    try:
        return load(text, physics_rate_hz)
    except PlantFileError as exc:
        raise PlantError(str(exc)) from None


def _file_disturbances(text: str, lp, air: list, given: dict) -> None:
    """A plant file carries the atmosphere only on the airframe states [v, p, r, phi], scaled to its
    ``[atmosphere]`` (a crosswind needs no scale), the turbulence at an altitude of the low-altitude Dryden model."""
    if not air:
        return
    if lp.truth is not None:
        # the gusts enter through the aerodynamic columns of v, p, r (sitl.atmosphere.disturbance_matrix)
        raise PlantError(
            f"--{air[0].replace('_', '-')} cannot fly on --plant {text}: the atmosphere needs the airframe states "
            "[v, p, r, phi], in that order"
        )
    scaled = [d for d in air if d != "crosswind"]  # a steady crosswind is a side velocity: no scale to it
    if scaled and lp.airspeed_m_s is None:
        raise PlantError(
            f"--{scaled[0].replace('_', '-')} cannot fly on --plant {text}: the Dryden turbulence and the gusts are "
            "scaled to the aircraft, and the file does not say which: give [atmosphere] airspeed = M/S and span = M "
            "(and altitude = M) in it"
        )
    alt = lp.altitude_m if scaled else None
    if alt is not None and given.get("turbulence") is not None and not 3.048 <= alt <= 304.8:
        raise PlantError(
            f"--turbulence cannot fly on --plant {text}: its [atmosphere] altitude {alt:g} m is outside the "
            "low-altitude Dryden model (3.05..304.8 m, 10..1000 ft)"
        )


def scaled_atmosphere(lp, atm):
    """``atm`` (``sitl.atmosphere.AtmosphereConfig``) for the aircraft of plant file ``lp``: the Dryden filters and
    the gusts at its airspeed and span; a --turbulence intensity at its altitude too, unless --altitude, the sigmas
    or the scale lengths were given.  Unchanged without ``[atmosphere]`` (only a crosswind is then allowed)."""
    if lp.airspeed_m_s is None:
        return atm
    from sitl.atmosphere import ALTITUDE, DrydenConfig

    turb = atm.turbulence
    if turb is not None:
        name = next((n for n in ("light", "moderate", "severe") if DrydenConfig.intensity(n, ALTITUDE) == turb), None)
        if name is not None and lp.altitude_m is not None:
            turb = DrydenConfig.intensity(name, lp.altitude_m)
        turb = replace(turb, airspeed=lp.airspeed_m_s, span=lp.span_m)
    gusts = tuple(replace(g, airspeed=lp.airspeed_m_s) for g in atm.gusts)
    return replace(atm, turbulence=turb, gusts=gusts)


def _file_refusals(lp) -> dict:
    from sitl.damage import roll_rate_index

    if roll_rate_index(lp.truth) is None:
        return {"damping": "the plant file's roll rate is not one of its states (a transfer function)"}
    return {}


def _file_build(spec: PlantSpec, physics_rate_hz: float, params=None, dist=None, damaged=False) -> Plant:  # noqa: ARG001
    from sitl.aircraft import Aircraft, AircraftConfig

    lp = _file_parse(spec.text, physics_rate_hz)  # its physics step checked at the rate it flies
    if lp.is_mimo:
        raise PlantError(
            f"{spec.text}: a plant file of {lp.m} inputs is designed (python -m tools.pfc design) but not flown by the "
            "SITL: fly the JSBSim aircraft it was linearised from (jsbsim:MODEL:surface=aileron+rudder)"
        )
    cfg = AircraftConfig(
        physics_rate_hz=physics_rate_hz, rudder_limit_rad=lp.limit_rad, rudder_rate_limit_rad_s=lp.rate_limit_rad_s
    )
    return Aircraft(cfg, params=lp.aircraft_params())


# ---------------------------------------------------------------------------------------------- a JSBSim aircraft
JSBSIM = "jsbsim:"


def _jsbsim_parse(text: str):
    from sitl.jsbsim_plant import JsbsimPlantError, parse_spec

    try:
        return parse_spec(text)
    except JsbsimPlantError as exc:
        raise PlantError(str(exc)) from None


def _jsbsim_check(text: str, _physics_rate_hz: float | None) -> None:
    """The spec parsed, its model found, its surfaces mapped and its safety pilot's gains there."""
    from sitl.jsbsim_models import pilot_gains
    from sitl.jsbsim_plant import JsbsimPlantError, available_models

    spec = _jsbsim_parse(text)
    try:
        if spec.model not in available_models():
            raise JsbsimPlantError(f"jsbsim plant: no model {spec.model!r}; available: {', '.join(available_models())}")
        _ = spec.surface_maps  # the model's own command -> deflection, or why it has none in rad
        pilot_gains(spec.model)  # the safety pilot holds it, or says why not
    except JsbsimPlantError as exc:
        raise PlantError(str(exc)) from None


def _turbulence_name(dist) -> str | None:
    """The --turbulence intensity behind ``dist`` (JSBSim plants take only the intensity, see ``unsupported``)."""
    from sitl.atmosphere import ALTITUDE, DrydenConfig

    turb = None if dist is None else dist.atmosphere.turbulence
    if turb is None:
        return None
    for name in ("light", "moderate", "severe"):
        if DrydenConfig.intensity(name, ALTITUDE) == turb:
            return name
    raise PlantError("JSBSim's MIL-F-8785C turbulence takes an intensity only (--turbulence)")


def _jsbsim_atmosphere(_m, dist):
    """Everything but the atmosphere: JSBSim flies its own, at the aircraft's airspeed and altitude."""
    from sitl.atmosphere import AtmosphereConfig

    return replace(dist, atmosphere=AtmosphereConfig())


def _jsbsim_xml(m) -> Path:
    from sitl.jsbsim_plant import _root

    return _root() / "aircraft" / m.model / f"{m.model}.xml"


def _jsbsim_refusals(m) -> dict:
    from sitl.jsbsim_damage import refusals

    return refusals(_jsbsim_xml(m), m.surfaces[0])


def _jsbsim_value_refusal(m, fault) -> str | None:
    """A JSBSim airspeed outside the aircraft's trim range (it does not trim there at its altitude), a cg shift
    beyond half the half span."""
    if fault.kind == "airspeed":
        kt = fault.value / (1852.0 / 3600.0)
        if not _trims(m.model, round(kt, 9), m.altitude_m):
            return f"{m.model} does not trim in level flight at {kt:.6g} kt, {m.altitude_m:g} m (its trim range)"
        return None
    if fault.kind != "cg":
        return None
    from sitl.jsbsim_damage import anatomy

    span = anatomy(_jsbsim_xml(m), m.surfaces[0]).span_ft
    most = 0.25 * span * 0.3048 if span else None  # half the half span: a tip ballast as heavy as the aircraft
    if most and abs(fault.value) > most:
        return f"beyond {most:.2f} m (half the half span) the wing-tip ballast would weigh more than the aircraft"
    return None


@functools.lru_cache(maxsize=64)
def _trims(model: str, kt: float, altitude_m: float) -> bool:
    """Whether JSBSim's ``model`` trims in level flight at ``kt`` knots and ``altitude_m`` (one trim)."""
    from sitl.jsbsim_models import quiet_stdio
    from sitl.jsbsim_plant import JsbsimPlantError, JsbsimSpec, trimmed_fdm

    with quiet_stdio():  # JSBSim's chatter ("Sorry, udot doesn't appear to be trimmable")
        try:
            trimmed_fdm(JsbsimSpec(model, airspeed_kt=kt, altitude_m=altitude_m), 0.01, suggest=False)
        except JsbsimPlantError:
            return False
    return True


def _jsbsim_build(spec: PlantSpec, physics_rate_hz: float, params=None, dist=None, damaged=False) -> Plant:  # noqa: ARG001
    from sitl.jsbsim_plant import JsbsimPlant, JsbsimPlantError

    try:
        return JsbsimPlant(
            spec.model,
            physics_rate_hz,
            turbulence=_turbulence_name(dist),
            seed=0 if dist is None else dist.seed,
            crosswind=0.0 if dist is None else dist.atmosphere.crosswind,
            damaged=damaged,
        )
    except JsbsimPlantError as exc:
        raise PlantError(str(exc)) from None


def _jsbsim_design(_text: str, m) -> Path:
    suffix = "" if m.surface == "aileron" else f"-{m.surface}"
    return shipped(f"jsbsim-{m.model}{suffix}.params")


def _jsbsim_linear(text: str, m) -> tuple | None:
    """Its linearised file shipped beside its designed parameter file (``sitl/plants/jsbsim-MODEL.toml``, at its
    design point, whatever the airspeed flown), None if none."""
    path = _jsbsim_design(text, m).with_suffix(".toml")
    if not _jsbsim_design(text, m).is_file() or not path.is_file():
        return None
    return _linear_of(_file_parse(str(path)))


# ---------------------------------------------------------------------------------------------- the table
KINDS: dict[str, PlantKind] = {
    k.name: k
    for k in (
        PlantKind(
            name=KH2013A,
            syntax=KH2013A,
            matches=lambda text: text == KH2013A,
            parse=lambda _text: None,
            check=lambda _text, _rate: None,
            construct=_kh_build,
            surfaces=lambda _m: ("rudder",),
            surface=lambda _m: "rudder",
            travel=lambda _m: (None,),
            label=lambda _text, _m: "KH2013A",
            linear=_kh_linear,
            paper=True,
            batched=True,
            words="the paper's model",
        ),
        PlantKind(
            name="jsbsim",
            syntax="jsbsim:MODEL[:KEY=VALUE,...]",
            matches=lambda text: text.startswith(JSBSIM),
            parse=_jsbsim_parse,
            check=_jsbsim_check,
            construct=_jsbsim_build,
            surfaces=lambda m: m.surfaces,
            surface=lambda m: m.surface,
            travel=lambda m: m.surface_limits_rad,
            label=lambda _text, m: m.model + ("" if m.surface == "aileron" else f"-{m.surface}"),
            design=_jsbsim_design,
            linear=_jsbsim_linear,
            mimo=lambda m: m.is_mimo,
            atmosphere=_jsbsim_atmosphere,
            refusals=_jsbsim_refusals,
            value_refusal=_jsbsim_value_refusal,
            keyed=True,
            unsupported={
                "scale": SCALE,
                "gust": "--gust is a KH2013A side-gust model (JSBSim flies its own atmosphere: use --turbulence)",
                "turbulence_sigma": "JSBSim's MIL-F-8785C turbulence takes an intensity only (--turbulence)",
                "turbulence_length": "JSBSim's MIL-F-8785C turbulence takes an intensity only (--turbulence)",
                "altitude": "the JSBSim altitude is the plant's own: jsbsim:MODEL:altitude_m=M",
            },
            own_atmosphere=True,
            euler=True,
            faults=frozenset({"servo", "airframe", "mass"}),
            words="a JSBSim aircraft, e.g. jsbsim:c172x",
        ),
        PlantKind(  # last: any other value is a plant file's path
            name="file",
            syntax="FILE.toml",
            matches=lambda _text: True,
            parse=_file_parse,
            check=lambda text, rate: _file_parse(text, rate) and None,
            construct=_file_build,
            surfaces=lambda lp: lp.surfaces or (lp.surface,),
            surface=lambda lp: lp.surface,
            travel=lambda lp: lp.limits_rad or (lp.limit_rad,),
            label=lambda text, lp: lp.name or Path(text).stem,
            design=lambda text, _lp: Path(text).with_suffix(".params"),
            linear=lambda _text, lp: _linear_of(lp),
            mimo=lambda lp: lp.is_mimo,
            disturbances=_file_disturbances,
            atmosphere=lambda lp, dist: replace(dist, atmosphere=scaled_atmosphere(lp, dist.atmosphere)),
            refusals=_file_refusals,
            unsupported={"scale": SCALE},
            words="a linear plant file of your own",
        ),
    )
}


def help_text(default: str | None = KH2013A, note: Callable[[PlantKind], str] | None = None) -> str:
    """What --plant takes, from the records (``KINDS``, in its order): each kind's syntax and words, ``default``
    marked, and ``note(kind)`` (a command's own words about a kind) after its words where it gives some."""
    parts = []
    for k in KINDS.values():
        said = [
            k.words,
            *([note(k)] if note is not None and note(k) else []),
            *(["default"] if k.syntax == default else []),
        ]
        parts.append(f"{k.syntax} ({'; '.join(s for s in said if s)})")
    return ", ".join(parts[:-1]) + " or " + parts[-1]


def kind_of(text: str) -> PlantKind:
    """The kind of a --plant value (never raises: an unknown value is a plant file's path)."""
    return next(k for k in KINDS.values() if k.matches(text))


def _stamp(text: str) -> tuple:
    """What makes a cached parse stale: which file a plant file's path names from here, its size and modification
    time (nothing for the others)."""
    try:
        st = os.stat(text)
    except (OSError, ValueError):
        return ()
    return (os.path.abspath(text), st.st_mtime_ns, st.st_size)


@functools.lru_cache(maxsize=128)
def _parsed(text: str, stamp: tuple) -> PlantSpec:  # noqa: ARG001 (the stamp is the cache key)
    k = kind_of(text)
    return PlantSpec(text, k, k.parse(text))


def spec(text) -> PlantSpec:
    """The --plant value ``text`` parsed once (cached; a plant file again when it changed on disk); PlantError with
    a one-line reason.  A PlantSpec is returned as it is."""
    if isinstance(text, PlantSpec):
        return text
    text = str(text)
    return _parsed(text, _stamp(text))


def shipped(name: str) -> Path:
    """A plant file shipped with the package (``sitl/plants/NAME``)."""
    return Path(str(resources.files("sitl") / "plants" / name))


__all__ = [
    "JSBSIM", "KH2013A", "KINDS", "Plant", "PlantError", "PlantKind", "PlantSpec", "help_text", "kind_of", "shipped",
    "spec",
]  # fmt: skip
