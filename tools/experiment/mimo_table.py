"""``python -m tools.experiment.mimo_table [--out DIR]``: the MIMO results table of docs/jsbsim.md (issue 32).

Roll tracking and coordination of the c172x in the +-10 deg, 10 s square wave (30 s, lockstep, over MAVLink: each
row is one ``python -m tools.launch`` flight) for three controllers:

- MIMO CL-SAC: ``jsbsim:c172x:surface=aileron+rudder`` with its design (``--controller clsac``);
- aileron-only CL-SAC: ``jsbsim:c172x`` with its design, the rudder held at trim;
- MIMO baseline: the MIMO plant, one PID per channel (``--controller baseline``);

on design (90 kt), off design (63 and 117 kt, the 90 kt designs flown there) and with the aileron at 0.3 effectiveness
(``--fault effectiveness=0.3@0``).  Roll: ise_ref (rad^2 s) and the envelope's verdict; coordination: max |sideslip|
(deg).  The MIMO flights' sideslip is the summary's (AOA_SSA, JSBSim's aero/beta-rad); the aileron-only flight has no
sideslip channel, so its sideslip is computed from the SITL's truth series: beta = asin(v / V), v the body side
velocity, V the true airspeed of the trim (JSBSim's velocities/vt-fps; the safety pilot holds the airspeed).
"""

from __future__ import annotations

import argparse
import json
import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np

from autopilot.shared.process import standard_json

MIMO = "jsbsim:c172x:surface=aileron+rudder"
SISO = "jsbsim:c172x"
CASES = (
    ("on design, 90 kt", {}, None),
    ("63 kt", {"airspeed_kt": "63"}, None),
    ("117 kt", {"airspeed_kt": "117"}, None),
)
CASES += (("aileron at 0.3", {}, "effectiveness=0.3@0"),)
CONTROLLERS = (
    ("MIMO CL-SAC", MIMO, "clsac"),
    ("aileron-only CL-SAC", SISO, "clsac"),
    ("MIMO baseline", MIMO, "baseline"),
)


def _plant(base: str, keys: dict) -> str:
    if not keys:
        return base
    extra = ",".join(f"{k}={v}" for k, v in keys.items())
    return base + ("," if base.count(":") == 2 else ":") + extra


def _true_airspeed(plant: str) -> float:
    from sitl.jsbsim_models import quiet_stdio
    from sitl.jsbsim_plant import FT, parse_spec, trimmed_fdm

    with quiet_stdio():
        return float(trimmed_fdm(parse_spec(plant), 0.001)["velocities/vt-fps"]) * FT


def fly(plant: str, controller: str, fault: str | None, out: Path) -> dict:
    """One flight; its row: ise_ref, the envelope verdict, max |sideslip| (deg), saturation per surface."""
    from tools.design.linearise import designed_params

    params = designed_params(plant)
    argv = [sys.executable, "-m", "tools.launch", "--lockstep", "--quiet", "--duration", "30", "--plant", plant]
    argv += ["--controller", controller, "--params", str(params), "--out", str(out)]
    argv += ["--fault", fault] if fault else []
    r = subprocess.run(argv, capture_output=True, text=True, timeout=600)
    found = re.search(r"files: (\S+)/flight\.tlog", r.stdout)
    if found is None:
        return {"exit": r.returncode, "error": (r.stderr or r.stdout).strip().splitlines()[-1:]}
    run = Path(found.group(1))
    s = json.loads((run / "summary.json").read_text())
    env = s.get("controlled") or {}
    row = {"exit": r.returncode, "controlled": env.get("ok"), "max_roll_deg": env.get("max_abs_roll_deg")}
    row["ise_ref"] = s["runs"][0]["metrics"]["ise_ref"] if s["runs"] else math.nan
    side = s.get("sideslip")
    if side is not None:
        row["beta_deg"] = side["max_abs_sideslip_deg"]
        row["sat"] = side["saturated_fraction"]
    else:
        v = np.load(run / "sitl_series.npz")["v"]
        row["beta_deg"] = math.degrees(float(np.max(np.abs(np.arcsin(np.clip(v / _true_airspeed(plant), -1, 1))))))
        row["sat"] = {"aileron": None, "rudder": 0.0}
    return row


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m tools.experiment.mimo_table", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default="runs/mimo-table", help="the folder of the flights (default runs/mimo-table)")
    p.add_argument(
        "--damage",
        action="store_true",
        help="instead: the damage sweep, the aileron's effectiveness 1, 0.5, 0.3, 0.2 for the whole flight, in-process "
        "(tools.experiment.mimo_inprocess: bit for bit the lockstep flights)",
    )
    args = p.parse_args(argv)
    if args.damage:
        from tools.experiment.mimo_inprocess import sweep

        print(
            "| aileron effectiveness | controller | roll ise_ref (rad^2 s) | max \\|roll\\| (deg) "
            "| max \\|sideslip\\| (deg) | aileron saturated |"
        )
        print("|---|---|---|---|---|---|")
        for r in sweep():
            print(
                f"| {r['effectiveness']:g} | {r['controller']} | {r['ise_ref']:.4g} | {r['max_abs_roll_deg']:.1f} | "
                f"{r['max_abs_sideslip_deg']:.2f} | {100 * r['aileron_saturated']:.1f} % |"
            )
        return 0
    out = Path(args.out)
    rows = []
    for case, keys, fault in CASES:
        for name, base, controller in CONTROLLERS:
            plant = _plant(base, keys)
            tag = re.sub(r"[^a-z0-9]+", "-", f"{case}-{name}".lower())
            row = fly(plant, controller, fault, out / tag)
            rows.append((case, name, row))
            print(standard_json({"case": case, "controller": name, **row}), flush=True)
    print()
    print(
        "| case | controller | roll ise_ref (rad^2 s) | max \\|roll\\| (deg) | controlled | max \\|sideslip\\| (deg) |"
    )
    print("|---|---|---|---|---|---|")
    for case, name, r in rows:
        ise = f"{r['ise_ref']:.4g}" if "ise_ref" in r else "-"
        beta = f"{r['beta_deg']:.2f}" if "beta_deg" in r else "-"
        roll = f"{r['max_roll_deg']:.1f}" if r.get("max_roll_deg") is not None else "-"
        ok = {True: "yes", False: "no"}.get(r.get("controlled"), f"exit {r['exit']}")
        print(f"| {case} | {name} | {ise} | {roll} | {ok} | {beta} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
