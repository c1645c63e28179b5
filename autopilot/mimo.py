"""A square MIMO law flown by the autopilot's one-channel loop (issue 32; docs/spec.md, "Square MIMO CL-SAC").

The loop, the control step, the metrics, the envelope and the telemetry fly channel 1 (the roll on the aileron) as
they fly a SISO law; :class:`MimoLaw` quacks like one (``autopilot.clsac.ClSac``: ``command``/``advance``,
``__call__``, ``hold``, ``flew``, ``reset``, ``reconfigure`` and the ``TELEMETRY_FIELDS``, channel 1's as floats) and
flies the other channels beside it: before each step the loop sets ``y2`` (the sideslip from AOA_SSA, rad) and
``um2`` (its command, 0: coordinated flight); after it ``u2`` is the second surface's command (limited), and
``e2``, ``ym2``, ``ym_ol2``, ``saturated2`` and the gain matrices ``Ke``, ``Kx``, ``Ku`` (m x m) what it used.

Two laws: CL-SAC (or SAC) as ``autopilot.clsac.ClSac``'s matrix step with a PFC per channel, or the baseline, one
``autopilot.baseline.Baseline`` PID per channel.  ``from_values`` builds either from a design's parameter file
(``CLSAC_PFC_*``/``CLSAC_PFC2_*``, ``CLSAC_GAM_*``, ``PID_*``/``PID2_*``: ``tools.design.mimo_report``; a file's
``CLSAC_PID_*``/``CLSAC_PID2_*``, their aliases, as ``autopilot.params.load_file`` reads them).
"""

from __future__ import annotations

import math

import numpy as np

from autopilot.config import ConfigError
from autopilot.shared.cli import SIDESLIP_ENVELOPE_DEG  # |beta| a coordinated flight stays within, setpoints too

MIMO_FIELDS = ("beta", "um2", "u2", "e2", "ym2", "ym_ol2", "sat2", "ke11", "ke12", "ke21", "ke22")


class MimoLaw:
    """m = 2 channels behind the SISO law's interface (module docstring)."""

    def __init__(self, kind: str, config, laws=None):
        self.kind = kind  # "clsac" (ClSac's matrix step) or "baseline" (a PID per channel)
        self.registered_law = kind  # its law in autopilot.controllers.LAWS (modes, parameters)
        self.config = config  # channel 1's view: dt, u_limit_rad (the aileron's); ClSacConfig of both for clsac
        if kind == "clsac":
            from autopilot.clsac import ClSac

            self.law = ClSac(config, fast=False)
            self.laws = None
        else:
            self.law = None
            self.laws = list(laws)
        self.y2 = 0.0
        self.um2 = 0.0
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        if self.law is not None:
            self.law.reset()
        else:
            for law in self.laws:
                law.reset()
        self.steps = 0
        self.frozen = False
        self.u2 = self.e2 = self.ym2 = self.ym_ol2 = 0.0
        self.sat2 = False
        self._copy()

    def _copy(self) -> None:
        """Channel 1's internals as floats (the SISO attributes), channel 2's and the gain matrices beside them."""
        if self.law is not None:
            c = self.law
            for name in ("um", "y", "ym", "ym_ol", "ya", "y_pfc", "e", "u_raw", "u"):
                setattr(self, name, float(np.ravel(getattr(c, name))[0]))
            for name in ("kpe", "kie", "ke", "kpx", "kix", "kx", "kpu", "kiu", "ku"):
                setattr(self, name, float(np.asarray(getattr(c, name))[0, 0]))
            self.Ke, self.Kx, self.Ku = (np.array(getattr(c, n), dtype=float) for n in ("ke", "kx", "ku"))
            u = np.ravel(c.u)
            raw = np.ravel(c.u_raw)
            self.saturated = bool(u[0] != raw[0])
            self.sat2 = bool(u[1] != raw[1])
            self.u2, self.e2 = float(u[1]), float(np.ravel(c.e)[1])
            self.ym2, self.ym_ol2 = float(np.ravel(c.ym)[1]), float(np.ravel(c.ym_ol)[1])
        else:
            a, b = self.laws
            for name in ("um", "y", "ym", "ym_ol", "ya", "y_pfc", "e", "u_raw", "u", "saturated"):
                setattr(self, name, getattr(a, name))
            for name in ("kpe", "kie", "ke", "kpx", "kix", "kx", "kpu", "kiu", "ku"):
                setattr(self, name, getattr(a, name))
            self.Ke = np.diag([a.ke, b.ke])
            self.Kx = np.diag([a.kx, b.kx])
            self.Ku = np.diag([a.ku, b.ku])
            self.u2, self.e2, self.ym2, self.ym_ol2, self.sat2 = b.u, b.e, b.ym, b.ym_ol, bool(b.saturated)

    def telemetry(self) -> tuple:
        from autopilot.clsac import telemetry_of

        return telemetry_of(self)

    def mimo_row(self) -> tuple:
        """``MIMO_FIELDS`` of the last step: the second channel and K_e."""
        k = self.Ke
        return (
            float(self.y2), float(self.um2), self.u2, self.e2, self.ym2, self.ym_ol2, self.sat2,
            float(k[0, 0]), float(k[0, 1]), float(k[1, 0]), float(k[1, 1]),
        )  # fmt: skip

    # ------------------------------------------------------------------ step
    def __call__(self, y, um):
        return self.step(y, um)

    def step(self, y, um) -> float:
        if self.law is not None:
            self.law.step(np.array([float(y), float(self.y2)]), np.array([float(um), float(self.um2)]))
        else:
            a, b = self.laws
            a(y, um)
            b(self.y2, self.um2)
        self.steps += 1
        self.frozen = False
        self._copy()
        return self.u

    def command(self, y, um) -> float:
        return self.step(y, um)

    def advance(self) -> None:
        """Nothing: ``command`` stepped both channels whole."""

    def hold(self, u_applied=0.0) -> None:
        """Someone else flies channel 1 (``u_applied``); the second surface goes neutral; adaptation frozen."""
        if self.law is not None:
            self.law.hold(np.array([float(u_applied), 0.0]))
        else:
            self.laws[0].hold(u_applied)
            self.laws[1].hold(0.0)
        self.frozen = True
        self._copy()

    def flew(self, u_applied) -> None:
        if self.law is not None:
            self.law.flew(np.array([float(u_applied), self.u2]))
        elif hasattr(self.laws[0], "flew"):
            self.laws[0].flew(u_applied)

    def reconfigure(self, config) -> None:
        """A parameter change (``param_table``) or a SAC <-> CL-SAC switch (L_v = 0): the whole MIMO configuration
        for CL-SAC, channel 1's for the baseline (channel 2's PID is set by the table itself)."""
        if self.law is not None:
            lv = np.atleast_2d(np.asarray(config.lv, dtype=float))
            lv = float(lv[0, 0]) * np.eye(2) if lv.shape == (1, 1) else lv
            cfg = config.with_(lv=tuple(map(tuple, lv)))
            self.law.reconfigure(cfg)
            self.config = cfg
        else:
            self.laws[0].reconfigure(config)
            self.config = config


def from_values(kind: str, values: dict, *, control_rate_hz: float, limits, lv: float | None = None):
    """The MIMO law ``kind`` ("clsac", "sac" or "baseline") from a design's parameter values (``load_file``), the
    surfaces' ``limits`` (rad); ConfigError naming what the file lacks."""
    from autopilot.params import canonical

    values = {canonical(n): v for n, v in values.items()}  # CLSAC_PID_KP -> PID_KP (autopilot.params, "Aliases")
    need = (
        ("CLSAC_PFC_NUM", "CLSAC_PFC_DEN1", "CLSAC_PFC_DEN0", "CLSAC_PFC2_NUM", "CLSAC_PFC2_DEN1", "CLSAC_PFC2_DEN0")
        if kind != "baseline"
        else ("PID_KP", "PID_KI", "PID_KD", "PID2_KP", "PID2_KI", "PID2_KD")
    )
    missing = [n for n in need if n not in values]
    if missing:
        raise ConfigError(
            f"a square MIMO plant flies a MIMO design: the parameter file has no {', '.join(missing)} "
            "(python -m tools.pfc design jsbsim:MODEL:surface=aileron+rudder writes them)"
        )
    if kind == "baseline":
        from autopilot.baseline import Baseline, BaselineConfig

        _check_limits(limits)
        cfgs = [
            BaselineConfig(
                control_rate_hz=control_rate_hz,
                u_limit_rad=float(limits[i]),
                **{k.lower(): values[f"PID{tag}_{k}"] for k in ("KP", "KI", "KD")},
            )
            for i, tag in enumerate(("", "2"))
        ]
        return MimoLaw("baseline", cfgs[0], [Baseline(c) for c in cfgs])
    _check_limits(limits)
    lv = 0.0 if kind == "sac" else (values.get("CLSAC_LV", 20.0) if lv is None else lv)
    return MimoLaw("clsac", _clsac_config(values, control_rate_hz=control_rate_hz, limits=limits, lv=lv))


def _clsac_config(values: dict, *, control_rate_hz: float, limits, lv: float):
    from autopilot.config import ClSacConfig

    eye = np.eye(2)
    gam = {f"gamma_{n}": values.get(f"CLSAC_GAM_{n.upper()}", 10.0) for n in ("pe", "ie", "px", "ix", "pu", "iu")}
    pfcs = tuple(
        ((values[f"CLSAC_PFC{t}_NUM"],), (values[f"CLSAC_PFC{t}_DEN1"], values[f"CLSAC_PFC{t}_DEN0"]))
        for t in ("", "2")
    )
    return ClSacConfig(
        control_rate_hz=control_rate_hz,
        am=tuple(map(tuple, values.get("CLSAC_AM", -5.0) * eye)),
        bm=tuple(map(tuple, values.get("CLSAC_BM", 5.0) * eye)),
        cm=tuple(map(tuple, values.get("CLSAC_CM", 1.0) * eye)),
        lv=tuple(map(tuple, lv * eye)),
        sigma=values.get("CLSAC_SIGMA", 5.0),
        **gam,
        pfc_channels=pfcs,
        u_limit_rad=float(limits[0]),
        u_limits_rad=tuple(float(v) for v in limits),
    )


def _check_limits(limits) -> None:
    if len(limits) != 2 or not all(math.isfinite(v) and v > 0 for v in limits):
        raise ConfigError(f"a MIMO law needs two positive surface limits, got {limits!r}")


class ChannelMetrics:
    """A step hook (``autopilot.loop`` hooks) of a MIMO flight: per channel, from the steps the law flew
    (``Failsafe.NONE``), the run metrics of ``autopilot.metrics`` (ise_ref = sum (y - y_m,ol)^2 T, energy = sum u^2 T,
    tv = sum |u[k] - u[k-1]|, max |u|), the saturation per surface, and the max |sideslip| against
    ``SIDESLIP_ENVELOPE_DEG``.  ``result()``: the "sideslip" block of summary.json."""

    def __init__(self, dt: float, limits, envelope_deg: float = SIDESLIP_ENVELOPE_DEG):
        self.dt = dt
        self.limits = tuple(float(v) for v in limits)
        self.envelope_deg = envelope_deg
        self.n = 0
        self.ise = [0.0, 0.0]
        self.energy = [0.0, 0.0]
        self.tv = [0.0, 0.0]
        self.max_u = [0.0, 0.0]
        self.max_y = [0.0, 0.0]
        self.sat = [0, 0]
        self._last = None

    def __call__(self, rec) -> None:
        from autopilot.step import Failsafe

        r, c = rec.result, rec.ctrl
        if r.failsafe is not Failsafe.NONE or c.frozen:
            return
        ys = (r.phi, float(c.y2))
        refs = (c.ym_ol, c.ym_ol2)
        us = (r.u, c.u2)
        sats = (c.saturated, c.sat2)
        for i in range(2):
            d = ys[i] - refs[i]
            self.ise[i] += d * d
            self.energy[i] += us[i] * us[i]
            self.max_u[i] = max(self.max_u[i], abs(us[i]))
            self.max_y[i] = max(self.max_y[i], abs(ys[i]))
            self.sat[i] += bool(sats[i])
            if self._last is not None:
                self.tv[i] += abs(us[i] - self._last[i])
        self._last = us
        self.n += 1

    def result(self) -> dict:
        n, dt = self.n, self.dt
        channels = []
        for i, (name, surface) in enumerate((("roll", "aileron"), ("sideslip", "rudder"))):
            channels.append(
                {
                    "channel": name,
                    "surface": surface,
                    "metrics": {
                        "ise_ref": self.ise[i] * dt,
                        "energy": self.energy[i] * dt,
                        "tv": self.tv[i],
                        "max_abs_u": self.max_u[i],
                    },
                    "max_abs_deg": math.degrees(self.max_y[i]),
                    "saturated_fraction": self.sat[i] / n if n else 0.0,
                    "limit_deg": math.degrees(self.limits[i]),
                }
            )
        beta = math.degrees(self.max_y[1])
        return {
            "max_abs_sideslip_deg": beta,
            "envelope_deg": self.envelope_deg,
            "within_envelope": beta <= self.envelope_deg,
            "saturated_fraction": {
                "aileron": channels[0]["saturated_fraction"],
                "rudder": channels[1]["saturated_fraction"],
            },
            "channels": channels,
            "steps": n,
        }


def with_sideslip(controlled: dict, side: dict) -> dict:
    """The envelope verdict (``autopilot.envelope``'s ``controlled`` block) of a MIMO flight with its second channel
    in it: out of the envelope also when |sideslip| went past ``side["envelope_deg"]`` or the rudder saturated in as
    large a share of the steps as the aileron may (``limits["max_saturated_share"]``, strict as for the aileron);
    the reason says the sideslip's numbers either way.  A flight with no verdict (not checked) is left as it is."""
    if not controlled or not controlled.get("checked", True):
        return controlled
    beta, env = side["max_abs_sideslip_deg"], side["envelope_deg"]
    rudder = side["saturated_fraction"]["rudder"]
    share = controlled.get("limits", {}).get("max_saturated_share", 0.2)
    out = []
    if not beta <= env:  # a NaN is out
        out.append(f"|sideslip| reached {beta:.1f} deg (limit {env:g})")
    if not rudder < share:
        out.append(f"rudder saturated {100 * rudder:.1f} % of the flight (limit {100 * share:g} %)")
    said = (
        f"sideslip: max |sideslip| {beta:.1f} deg, rudder saturated {100 * rudder:.1f} % of the flight "
        f"(limits {env:g} deg, {100 * share:g} %)"
    )
    result = dict(controlled, sideslip_ok=not out)
    if out and controlled["ok"]:
        result.update(ok=False, reason="; ".join(out))
    elif out:
        result["reason"] = f"{controlled['reason']}; " + "; ".join(out)
    else:
        result["reason"] = f"{controlled['reason']}; {said}"
    return result


def param_table(law: MimoLaw, options: dict):
    """The parameter table of a MIMO flight (``autopilot.params.ParamTable``'s interface): each channel's values
    under the names a ground station shows (channel 1 the SISO names, channel 2 with a 2: ``CLSAC_PFC2_NUM``,
    ``PID2_KP``, alias ``CLSAC_PID2_KP``; the adaptation weights, sigma and L_v one for both), then the options."""
    from autopilot.params import ParamTable

    class MimoParamTable(ParamTable):
        def __init__(self):
            from autopilot.params import BASELINE_PARAMS, BY_NAME, MIMO_PARAMS, OPTION_DEFAULTS, PARAMS

            self.law = law
            if law.kind == "clsac":
                names = ("CLSAC_LV", "CLSAC_SIGMA", *(f"CLSAC_GAM_{n}" for n in ("PE", "IE", "PX", "IX", "PU", "IU")))
                names += ("CLSAC_PFC_NUM", "CLSAC_PFC_DEN1", "CLSAC_PFC_DEN0")
                own = tuple(BY_NAME[n] for n in names) + MIMO_PARAMS[:3]
            else:
                own = BASELINE_PARAMS + MIMO_PARAMS[3:]
            self.params = own + tuple(p for p in PARAMS if p.option)
            self._names = {n: p for p in self.params for n in (p.name, *p.aliases)}  # aliases: CLSAC_PID2_KP
            self._config = law.config
            self._options = {
                p.option: float(options[p.option] if p.option in options else OPTION_DEFAULTS[p.option])
                for p in PARAMS
                if p.option
            }
            self.flying = False

        def get(self, name: str) -> float:
            from autopilot.params import ParamError

            p = self._names.get(name)
            if p is None:
                raise ParamError(f"unknown parameter {name!r}")
            name = p.name
            if p.option:
                return self._options[p.option]
            if law.kind != "clsac":
                cfg = self._config if "PID2" not in name else law.laws[1].config
                return float(getattr(cfg, name.rsplit("_", 1)[1].lower()))
            cfg = self._config
            if name.startswith("CLSAC_PFC"):
                num, den = cfg.pfc_channels[1 if "PFC2" in name else 0]
                return float(num[-1] if name.endswith("NUM") else den[0 if name.endswith("DEN1") else 1])
            return float(np.atleast_2d(np.asarray(getattr(cfg, p.field), dtype=float))[0, 0])

        def set(self, name: str, value: float) -> float:
            from autopilot.params import ParamError

            p = self._names.get(name)
            if p is None:
                raise ParamError(f"unknown parameter {name!r}")
            name, value = p.name, float(value)
            if not math.isfinite(value) or not p.admits(value):
                raise ParamError(f"{name} must be in {p.bounds()}, got {value:g}")
            if p.option:
                self._options[p.option] = value
                return value
            try:
                if law.kind != "clsac":
                    gain = name.rsplit("_", 1)[1].lower()
                    if "PID2" in name:  # channel 2 flies it at once (the loop reconfigures channel 1's)
                        law.laws[1].reconfigure(law.laws[1].config.with_(**{gain: value}))
                    else:
                        self._config = self._config.with_(**{gain: value})
                    return self.get(name)
                cfg = self._config
                if name.startswith("CLSAC_PFC"):
                    ch = 1 if "PFC2" in name else 0
                    pfcs = [list(map(list, c)) for c in cfg.pfc_channels]
                    if name.endswith("NUM"):
                        pfcs[ch][0] = [value]
                    else:
                        pfcs[ch][1][0 if name.endswith("DEN1") else 1] = value
                    change = {"pfc_channels": tuple((tuple(n), tuple(d)) for n, d in pfcs)}
                elif p.field == "sigma":
                    change = {"sigma": value}
                else:  # L_v and the weights: value * I
                    change = {p.field: tuple(map(tuple, value * np.eye(2)))}
                self._config = cfg.with_(**change)
            except ConfigError as exc:
                raise ParamError(f"{name}={value:g} rejected: {exc}") from None
            return self.get(name)

    return MimoParamTable()
