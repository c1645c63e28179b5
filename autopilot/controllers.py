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
from dataclasses import dataclass


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

    def config_class(self):
        return _load(self.config)

    def law_class(self):
        return _load(self.law)

    def configure(self, **options):
        """Its configuration from keyword options (see ``Controller.config``)."""
        return _load(self.build)(**options)


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
        ),
        Law(
            "baseline",
            config="autopilot.baseline:BaselineConfig",
            law="autopilot.baseline:Baseline",
            build="autopilot.controllers:baseline_config",
            adaptive=False,
            parameters=False,
            modes=("BASELINE",),
        ),
    )
}

CONTROLLERS: dict[str, Controller] = {
    c.name: c
    for c in (
        Controller("sac", "clsac", lv=0.0, mode="SAC", label="SAC", help="sac (Lv = 0)", lv_fixed=0.0),
        Controller(
            "clsac", "clsac", lv=20.0, mode="CLSAC", label="CL-SAC", help="clsac (Lv = 20, the paper's; default)"
        ),
        Controller(
            "baseline",
            "baseline",
            lv=0.0,  # no reference-model feedback
            mode="BASELINE",
            label="fixed-gain PID",
            help="baseline (fixed-gain PID; --lv, --pfc and the adaptation's options are refused)",
        ),
        Controller(
            "pid-ff",
            "baseline",
            lv=0.0,
            mode="BASELINE",
            label="PID, feed-forward",
            help="pid-ff (the PID with the reference model's rate fed forward and the derivative on the roll)",
            options=(("feedforward", True),),
        ),
    )
}
NAMES = tuple(CONTROLLERS)  # the --controller choices
DEFAULT = "clsac"


def get(name: str) -> Controller:
    """The controller called ``name``; ValueError naming the known ones."""
    try:
        return CONTROLLERS[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown controller {name!r} (known: {', '.join(NAMES)})") from None


def law_of(obj) -> Law:
    """The law of a configuration or a law object (by its class, without importing the others)."""
    registered = getattr(obj, "registered_law", None)  # a law flying another's interface (autopilot.mimo.MimoLaw)
    if registered in LAWS:
        return LAWS[registered]
    where = f"{type(obj).__module__}:{type(obj).__qualname__}"
    for law in LAWS.values():
        if where in (law.config, law.law):
            return law
    raise ValueError(f"not a registered law or configuration: {type(obj).__qualname__}")


def make_law(config):
    """The law that flies ``config`` (``autopilot.step.ControlStep``)."""
    return law_of(config).law_class()(config)


def flown_lv(name: str, configured: float) -> float:
    """The L_v a controller flies when its table holds ``configured`` (SAC: 0 whatever the table says)."""
    fixed = get(name).lv_fixed
    return configured if fixed is None else fixed
