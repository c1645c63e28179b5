"""The controllers the product flies, in one place (docs/architecture.md, "Laws").

Two tables, plain data (no numpy: ``--help`` reads them):

* :data:`LAWS`: each control law, by name: its configuration class and law class (``module:Class``, imported on
  first use), what it has (adaptive gains, the CLSAC_* parameters of ``autopilot.params``, a PFC) and the
  ground-station modes a law of its kind may be flown in (``autopilot.vehicle.Mode`` names);
* :data:`CONTROLLERS`: each ``--controller NAME`` a user picks, by name: its law, the L_v it flies by default, the
  mode it starts in and the words that name it in headers and pictures.

The command lines' choices (``autopilot.flags``), the autopilot's start (``autopilot.__main__``: ``config``), the
control step (``autopilot.step``: :func:`make_law`), the parameter table, the ground-station modes, the launcher,
the experiments and pictures read these tables; the study (``tools.experiment.study``) names its laws by their
:data:`LAWS` key.
"""

from __future__ import annotations

import importlib
import math
from dataclasses import dataclass, field


def _load(where: str):
    module, _, name = where.partition(":")
    return getattr(importlib.import_module(module), name)


@dataclass(frozen=True)
class Law:
    """One control law."""

    name: str
    config: str  # "module:Class" of its configuration (a frozen dataclass with control_rate_hz, u_limit_rad)
    law: str  # "module:Class" of the law: law(config) steps it (autopilot.step.ControlStep)
    build: str  # "module:function": keyword options (see config()) -> its configuration
    adaptive: bool  # adaptive gains: L_v, the PFC, sigma and the gain telemetry apply
    parameters: bool  # its values are the CLSAC_* parameters of autopilot.params (else the table has options only)
    modes: tuple[str, ...]  # the autopilot.vehicle.Mode names a ground station may select while it flies
    lv: float = 0.0  # the configured L_v of its parameter table when no --lv is given (CLSAC_LV)
    # A law on the interface of autopilot.law (step(roll, roll_rate, yaw_rate, command), reset, hold, telemetry),
    # flown through autopilot.law.Flown; its parameter table is ``parameter_rows`` (its PARAMETERS), its telemetry
    # ``TELEMETRY_FIELDS``; ``mimo``: why it is refused on a square MIMO plant (None: it flies there)
    generic: bool = False
    parameter_rows: str = ""  # "module:NAME" of its PARAMETERS rows (generic laws)
    mimo: str | None = None
    design: str = ""  # the suffix of its design file beside a plant's (sitl/plants/PLANT-laws.params: "-laws")
    # Optional: its batch form (N aircraft at once: "module:Class", Class.accepts(config), Class.of(configs);
    # autopilot.batch) and its C-kernel form ("module:function", function(batch law) -> autopilot.batch.KernelForm).
    # The KH2013A study flies a controller by its law's batch form where it has one that accepts its configuration,
    # in C where it has a kernel form too; else the generic loop, one in-process flight at a time
    batch: str = ""
    kernel: str = ""
    cls: object = field(default=None, compare=False, repr=False)  # a user's law: its class, loaded (autopilot.law)

    def config_class(self):
        return self.cls.Config if self.cls is not None else _load(self.config)

    def law_class(self):
        return self.cls if self.cls is not None else _load(self.law)

    def configure(self, **options):
        """Its configuration from keyword options (see ``Controller.config``)."""
        if self.cls is not None:
            from autopilot.law import configure

            return configure(self.cls, **options)
        return _load(self.build)(**options)

    def rows(self) -> tuple:
        """Its PARAMETERS rows (NAME, field, unit, lower, upper, description); () for a law without a table."""
        if self.cls is not None:
            return tuple(getattr(self.cls, "PARAMETERS", ()))
        return tuple(_load(self.parameter_rows)) if self.parameter_rows else ()

    def aliases(self) -> dict[str, str]:
        """Its parameters' other names, alias -> its own name (a generic law's ``PARAMETER_ALIASES``; the PID's
        are in ``autopilot.params.BASELINE_PARAMS``)."""
        return dict(getattr(self.law_class(), "PARAMETER_ALIASES", None) or {}) if self.generic else {}

    def batch_class(self):
        """Its batch form's class, or None."""
        return _load(self.batch) if self.batch else None

    def kernel_form(self):
        """Its C-kernel form (a function of a batch law -> ``autopilot.batch.KernelForm``), or None."""
        return _load(self.kernel) if self.kernel else None

    def telemetry_fields(self) -> tuple[str, ...]:
        """Its own telemetry's names (generic laws)."""
        return tuple(getattr(self.law_class(), "TELEMETRY_FIELDS", ())) if self.generic else ()


@dataclass(frozen=True)
class Controller:
    """One ``--controller NAME``."""

    name: str
    law: str  # a key of LAWS
    lv: float  # the L_v it flies by default (autopilot.flags.default_lv)
    mode: str  # the autopilot.vehicle.Mode name it starts in
    label: str  # how headers name it ("fixed-gain PID")
    help: str  # its words in --controller's help
    lv_fixed: float | None = None  # the L_v it flies whatever --lv says (SAC: 0); None: the configured one
    options: tuple = ()  # (name, value) pairs its law's build takes on top of the command line's (pid-ff's)
    study_label: str = ""  # the damage study's words, where they differ from ``label`` (its tables name the PIDs)
    robustness_label: str = ""  # the KH2013A robustness study's words, where they differ from ``label``
    changes: tuple = ()  # (field, value) pairs over its law's configuration (the robustness study's VARIANTS)
    damage: int | None = None  # its place among the damage study's default controllers (None: not one of them)
    mimo: bool = False  # flies a square MIMO plant (its law's matrix form, autopilot.mimo); MIMO lists them

    @property
    def kind(self) -> Law:
        return LAWS[self.law]

    @property
    def adaptive(self) -> bool:
        return LAWS[self.law].adaptive

    def config(self, **options):
        """Its law's configuration from the command line's options (SI): ``control_rate_hz``, ``u_limit_rad``,
        ``lv`` (None: the law's default), ``pfc``, ``sigma_xu``, ``dead_zone_rad``, ``ki_max``,
        ``freeze_when_saturated``, ``gains`` (the baseline's KP,KI,KD or None); a law reads those it has."""
        return LAWS[self.law].configure(**{**options, **dict(self.options)})

    def study_config(self, pfc: str, control_rate_hz: float, u_limit_rad: float):
        """Its configuration in the KH2013A robustness study: its own L_v, the PFC drawn for the run, ``changes``."""
        cfg = self.config(control_rate_hz=control_rate_hz, u_limit_rad=u_limit_rad, lv=self.lv, pfc=pfc)
        return cfg.with_(**dict(self.changes)) if self.changes else cfg

    @property
    def robustness_words(self) -> str:
        """Its words in the robustness study's tables (``robustness_label``, else ``label``)."""
        return self.robustness_label or self.label

    def batch_form(self):
        """Its law's batch form if that flies this controller (``Law.batch``: ``accepts`` its configuration), else
        None: the study flies it through the generic loop."""
        cls = LAWS[self.law].batch_class()
        return cls if cls is not None and cls.accepts(self.config(control_rate_hz=100.0, u_limit_rad=0.5)) else None


def clsac_config(
    *,
    control_rate_hz: float,
    u_limit_rad: float,
    lv: float | None = None,
    pfc: str = "paper",
    sigma_xu: float = 0.0,
    dead_zone_rad: float = 0.0,
    ki_max: float | None = None,
    freeze_when_saturated: bool = False,
    **_ignored,
):
    """SAC and CL-SAC (``autopilot.config.ClSacConfig``)."""
    from autopilot.config import ClSacConfig

    return ClSacConfig(
        control_rate_hz=control_rate_hz,
        lv=LAWS["clsac"].lv if lv is None else lv,
        u_limit_rad=u_limit_rad,
        sigma_x=sigma_xu,
        sigma_u=sigma_xu,
        dead_zone_rad=dead_zone_rad,
        ki_max=ki_max,
        freeze_when_saturated=freeze_when_saturated,
    ).with_pfc(pfc)


def baseline_config(*, control_rate_hz: float, u_limit_rad: float, gains=None, feedforward: bool = False, **_ignored):
    """The fixed-gain PID (``autopilot.baseline.BaselineConfig``); ``gains``: (KP, KI, KD), None: its defaults.
    ``feedforward`` (pid-ff): the reference model's rate fed forward with K_FF (a fourth gain, default the
    KH2013A's ``KFF_KH2013A``) and the derivative on the measurement.  ConfigError for a K_FF without it."""
    from autopilot.baseline import KFF_KH2013A, BaselineConfig
    from autopilot.config import ConfigError

    gains = tuple(gains) if gains else ()
    kw = dict(zip(("kp", "ki", "kd"), gains[:3]))
    if feedforward:
        kw.update(kff=gains[3] if len(gains) > 3 else KFF_KH2013A, derivative="measurement")
    elif len(gains) > 3:
        raise ConfigError("a fourth gain (KFF) is pid-ff's feed-forward: the baseline takes KP,KI,KD")
    return BaselineConfig(control_rate_hz=control_rate_hz, u_limit_rad=u_limit_rad, **kw)


def _generic(where: str, **fixed):
    def build(*, control_rate_hz: float, u_limit_rad: float, **_ignored):
        return _load(where)(control_rate_hz=control_rate_hz, u_limit_rad=u_limit_rad, **fixed)

    return build


mrac_config = _generic("autopilot.mrac:MracConfig")  # the KH2013A design; a plant's from its -laws.params
crm_mrac_config = _generic("autopilot.mrac:crm_config")
l1_config = _generic("autopilot.l1:L1Config")
indi_config = _generic("autopilot.indi:IndiConfig")
_NO_MIMO = "{} has no square-MIMO form (autopilot.mimo flies clsac, sac and baseline)"


def _bench(name: str, module: str, cls: str, config: str, rows: str, mode: str, build: str) -> Law:
    """One of the adaptive-law bench's laws (issue 38): on the law interface, designed per plant."""
    return Law(
        name,
        config=f"{module}:{config}",
        law=f"{module}:{cls}",
        build=f"autopilot.controllers:{build}",
        adaptive=False,
        parameters=False,
        modes=(mode,),
        generic=True,
        parameter_rows=f"{module}:{rows}",
        mimo=_NO_MIMO.format(name),
        design="-laws",
    )


LAWS: dict[str, Law] = {
    law.name: law
    for law in (
        Law(
            "clsac",
            config="autopilot.config:ClSacConfig",
            law="autopilot.clsac:ClSac",
            build="autopilot.controllers:clsac_config",
            adaptive=True,
            parameters=True,
            modes=("SAC", "CLSAC"),
            lv=20.0,  # paper sec. 5
            batch="autopilot.batch:BatchClSac",
            kernel="autopilot.batch:clsac_kernel",
        ),
        Law(
            "baseline",
            config="autopilot.baseline:BaselineConfig",
            law="autopilot.baseline:Baseline",
            build="autopilot.controllers:baseline_config",
            adaptive=False,
            parameters=False,
            modes=("BASELINE",),
            batch="autopilot.batch:BatchBaseline",
            kernel="autopilot.batch:baseline_kernel",
        ),
        _bench("mrac", "autopilot.mrac", "Mrac", "MracConfig", "PARAMETERS", "MRAC", "mrac_config"),
        _bench("crm-mrac", "autopilot.mrac", "Mrac", "MracConfig", "CRM_PARAMETERS", "CRM_MRAC", "crm_mrac_config"),
        _bench("l1", "autopilot.l1", "L1", "L1Config", "PARAMETERS", "L1", "l1_config"),
        _bench("indi", "autopilot.indi", "Indi", "IndiConfig", "PARAMETERS", "INDI", "indi_config"),
    )
}

CONTROLLERS: dict[str, Controller] = {
    c.name: c
    for c in (
        Controller(
            "sac", "clsac", lv=0.0, mode="SAC", label="SAC", help="sac (Lv = 0)", lv_fixed=0.0, damage=1, mimo=True
        ),
        Controller(
            "clsac",
            "clsac",
            lv=20.0,
            mode="CLSAC",
            label="CL-SAC",
            help="clsac (Lv = 20, the paper's; default)",
            robustness_label="CL-SAC Lv 20 (paper)",
            damage=2,
            mimo=True,
        ),
        Controller(
            "baseline",
            "baseline",
            lv=0.0,  # no reference-model feedback
            mode="BASELINE",
            label="fixed-gain PID",
            study_label="PID (as designed)",
            help="baseline (fixed-gain PID; --lv, --pfc and the adaptation's options are refused)",
            damage=0,
            mimo=True,
        ),
        Controller(
            "pid-ff",
            "baseline",
            lv=0.0,
            mode="BASELINE",
            label="PID, feed-forward",
            study_label="PID + feed-forward, D on roll",
            help="pid-ff (the PID with the reference model's rate fed forward and the derivative on the roll)",
            options=(("feedforward", True),),
            damage=3,
        ),
        Controller("mrac", "mrac", lv=0.0, mode="MRAC", label="MRAC", help="mrac (MRAC, open-loop reference model)"),
        Controller(
            "crm-mrac", "crm-mrac", lv=0.0, mode="CRM_MRAC", label="CRM-MRAC", help="crm-mrac (closed-loop ref. model)"
        ),
        Controller("l1", "l1", lv=0.0, mode="L1", label="L1 adaptive", help="l1 (L1 adaptive control)"),
        Controller("indi", "indi", lv=0.0, mode="INDI", label="adaptive INDI", help="indi (adaptive INDI)"),
    )
}
NAMES = tuple(CONTROLLERS)  # the built-in --controller choices
DEFAULT = "clsac"
BUILT_IN = NAMES

DEAD_ZONE_RAD = 0.25 * (math.pi / 180.0)  # about the roll noise of "moderate" (tools.experiment.study)
KI_MAX = 0.2  # rad/rad: 2.6 times the largest |K_I| of the nominal 30 s CL-SAC run (0.076)


def _variant(name: str, label: str, lv: float = 20.0, **changes) -> Controller:
    return Controller(name, "clsac", lv=lv, mode="CLSAC", label=label, help="", changes=tuple(changes.items()))


# The KH2013A robustness study's variants of CL-SAC (tools.experiment.study): its configurations that the study
# compares beside the --controller choices (their names are its --controllers), not --controller choices themselves
VARIANTS: dict[str, Controller] = {
    c.name: c
    for c in (
        _variant("clsac_lv10", "CL-SAC Lv 10", lv=10.0),
        _variant("clsac_lv50", "CL-SAC Lv 50", lv=50.0),
        _variant("clsac_leak", "CL-SAC + leakage 0.1", sigma_x=0.1, sigma_u=0.1),
        _variant("clsac_deadzone", "CL-SAC + dead-zone 0.25 deg", dead_zone_rad=DEAD_ZONE_RAD),
        _variant("clsac_projection", "CL-SAC + projection |K_I| <= 0.2", ki_max=KI_MAX),
        _variant("clsac_freeze", "CL-SAC + freeze when saturated", freeze_when_saturated=True),
    )
}
# The robustness study's controllers, in its tables' order (the batched study's default --controllers)
# the controllers a square MIMO plant flies (their laws' matrix forms, autopilot.mimo), in the damage study's order
MIMO = tuple(sorted((c.name for c in CONTROLLERS.values() if c.mimo), key=lambda n: CONTROLLERS[n].damage))
ROBUSTNESS = ("sac", "clsac_lv10", "clsac", "clsac_lv50", "baseline", *tuple(VARIANTS)[2:])


def studied(name: str) -> Controller:
    """A controller of the robustness study (``ROBUSTNESS``: a --controller choice or a ``VARIANTS`` one);
    ValueError naming the known ones."""
    c = VARIANTS.get(name) or (CONTROLLERS.get(name) if name in ROBUSTNESS else None)
    if c is None:
        raise ValueError(f"unknown controller {name!r} (known: {', '.join(ROBUSTNESS)})")
    return c


def register(spec: str) -> Controller:
    """A user's law (``FILE.py:Class``, ``module:Class``, an installed entry point: ``autopilot.law.load``) added to
    the registry under ``spec``; autopilot.law.LawSpecError (one line) if it cannot be flown."""
    from autopilot.law import load

    if spec in CONTROLLERS:
        return CONTROLLERS[spec]
    cls = load(spec)
    name = str(getattr(cls, "NAME", "") or spec)
    where = f"{cls.__module__}:{cls.__qualname__}"
    config = f"{cls.Config.__module__}:{cls.Config.__qualname__}"
    mimo = f"{name} has no square-MIMO form (a law on autopilot.law's interface flies one surface)"
    LAWS[spec] = Law(spec, config, where, "", False, False, ("LAW",), generic=True, mimo=mimo, cls=cls)
    c = Controller(spec, spec, lv=0.0, mode="LAW", label=str(getattr(cls, "LABEL", "") or name), help="")
    CONTROLLERS[spec] = c
    return c


def get(name: str) -> Controller:
    """The controller called ``name`` (a user's law is loaded and registered: ``register``); ValueError naming the
    known ones, autopilot.law.LawSpecError for a user's law that cannot be flown."""
    if isinstance(name, str) and name in CONTROLLERS:
        return CONTROLLERS[name]
    if isinstance(name, str) and name:
        from autopilot import law

        if law.is_spec(name) or law.entry_point(name) is not None:
            return register(name)
    raise ValueError(f"unknown controller {name!r} (known: {', '.join(NAMES)}, FILE.py:Class, module:Class)")


def describe(name: str) -> dict:
    """What summary.json says of the law a controller flies: ``controller`` (the --controller given), ``name``,
    ``label``, ``mode``, its own ``parameters`` (names) and ``telemetry`` (its TELEMETRY_FIELDS)."""
    c = get(name)
    law = c.kind
    cls = law.cls
    return {
        "controller": c.name,
        "name": str(getattr(cls, "NAME", "") or c.name) if cls is not None else c.name,
        "label": c.label,
        "class": law.law if cls is None else f"{cls.__qualname__} ({c.name})",
        "mode": c.mode,
        "parameters": [row[0] for row in law.rows()],
        "telemetry": list(law.telemetry_fields()),
    }


def law_of(obj) -> Law:
    """The law of a configuration or a law object (by its class, without importing the others).  An MRAC
    configuration with a closed-loop reference model (``crm_l`` > 0) is CRM-MRAC's."""
    registered = getattr(obj, "registered_law", None)  # a law flying another's interface (autopilot.mimo.MimoLaw)
    if registered in LAWS:
        return LAWS[registered]
    where = f"{type(obj).__module__}:{type(obj).__qualname__}"
    if where == "autopilot.mrac:MracConfig":
        return LAWS["crm-mrac" if obj.crm_l > 0 else "mrac"]
    for law in LAWS.values():
        if where in (law.config, law.law):
            return law
    raise ValueError(f"not a registered law or configuration: {type(obj).__qualname__}")


def make_law(config):
    """The law that flies ``config`` (``autopilot.step.ControlStep``): a law on the interface of autopilot.law
    through ``autopilot.law.Flown``."""
    law = law_of(config)
    if law.generic:
        from autopilot.law import Flown

        return Flown(law.law_class()(config), law.name)
    return law.law_class()(config)


def flown_lv(name: str, configured: float) -> float:
    """The L_v a controller flies when its table holds ``configured`` (SAC: 0 whatever the table says)."""
    fixed = get(name).lv_fixed
    return configured if fixed is None else fixed
