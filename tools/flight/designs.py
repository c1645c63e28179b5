"""A flight's design: the parameter file each controller flies on a plant (``FlightConfig.params_file``), and the
refusals of ``FlightConfig`` when there is none, or when a flag asks for what the file overrides
(docs/plants.md, "Where a design is found")."""

from __future__ import annotations

import math

from autopilot import controllers, flags


def refusal(cfg) -> tuple[str, str] | None:
    """A plant other than the KH2013A flies its own design (``tools.pfc design``: found where
    ``tools.design.linearise.design_path`` says) or a parameter file given; without either it is refused, naming
    the command that designs it, unless the controller's values are given (``pfc``, ``baseline_gains``).  A flag
    the file would override (it wins over the flags) is refused, and so is a command limit beyond the plant's
    stop.  ``cfg``: a ``FlightConfig``; returns (its keyword, the one-line reason) or None."""
    from autopilot.params import load_file
    from sitl import plant as plants
    from tools.design.linearise import PFC_PARAMS, PID_PARAMS, design_advice, design_path, shown_path

    c = controllers.get(cfg.controller)
    path = cfg.params_file
    if c.kind.generic:  # a law on autopilot.law's interface flies its design for the plant (a user's: its defaults)
        if c.kind.design and path is None and not plants.spec(cfg.plant).paper:
            from tools.design.linearise import design_path

            base = design_path(cfg.plant)
            law_file = None if base is None else base.with_name(base.stem + c.kind.design + ".params")
            where = "its laws' design" if law_file is None else shown_path(law_file)
            return (
                "plant",
                f"plant: {cfg.plant} has no design of {c.name} (no {where}): python -m tools.design.laws "
                f"{cfg.plant} --out {where}, or fly a parameter file of your own (--params FILE)",
            )
        return None
    if path is None:
        explicit = cfg.pfc is not None if c.adaptive else cfg.baseline_gains is not None
        if not plants.spec(cfg.plant).paper and not explicit:
            return (
                "plant",
                f"plant: {cfg.plant} has no design (no {shown_path(design_path(cfg.plant))}): "
                f"{design_advice(cfg.plant)}, or fly a parameter file of your own (--params FILE)",
            )
        return None
    values = load_file(path)
    whose = "the parameter file" if cfg.params is not None else f"{cfg.plant}'s design"
    for key, names, given in (
        ("pfc", PFC_PARAMS, c.adaptive and cfg.pfc is not None),
        ("lv", ("CLSAC_LV",), c.adaptive and cfg.lv is not None),
        ("baseline_gains", PID_PARAMS, not c.adaptive and cfg.baseline_gains is not None),
    ):
        if given and any(n in values for n in names):
            return (
                key,
                f"{key}{flags.value_text(getattr(cfg, key))}: {whose} {path} sets "
                f"{', '.join(n for n in names if n in values)}, which wins over the flags: give one or the other",
            )
    limit = values.get("CLSAC_U_LIMIT") if c.adaptive else None
    stop = cfg.surface_limit_deg
    if limit is not None and stop is not None and math.degrees(limit) > stop * (1 + 1e-12):
        return (
            "params",
            f"params: {path} sets CLSAC_U_LIMIT {math.degrees(limit):.4g} deg, beyond {cfg.plant}'s surface stop "
            f"{stop:.4g} deg: the command cannot go past the stop",
        )
    return None


def law_refusal(controller: str) -> str | None:
    """A user's law (``autopilot.law``) built once, at its defaults: the one line of what its Config or its
    constructor raised, None if it builds (checked before any process starts)."""
    c = controllers.get(controller)
    if c.kind.cls is None:
        return None
    try:
        controllers.make_law(c.config(control_rate_hz=100.0, u_limit_rad=math.radians(30.0)))
    except Exception as exc:  # noqa: BLE001  (a user's code may raise anything)
        return f"controller {controller}: {type(exc).__name__}: {' '.join(str(exc).split())}"
    return None


def is_mimo(cfg) -> bool:
    """``cfg.mimo``, False for a plant that does not parse (refused later with its own reason)."""
    try:
        return cfg.mimo
    except Exception:  # noqa: BLE001
        return False


def check_params(values: dict[str, float], controller: str) -> None:
    """A parameter file's values against the one table of bounds and ``controller``'s law
    (``autopilot.params.ParamTable``, as the autopilot loads it: another law's values are not its to fly):
    ``ParamError`` naming the first one refused, before anything starts."""
    from autopilot.loop import AutopilotOptions
    from autopilot.params import ParamTable

    defaults = AutopilotOptions()  # the options the autopilot starts from (the file's values replace them)
    options = {k: getattr(defaults, k) for k in ("attitude_timeout_s", "setpoint_timeout_s", "max_roll_rad")}
    cfg = controllers.get(controller).config(control_rate_hz=100.0, u_limit_rad=math.radians(30.0))
    table = ParamTable(cfg, options)
    table.update(table.split(values)[0])
