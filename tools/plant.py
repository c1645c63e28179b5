"""``python -m tools.plant linearise jsbsim:MODEL --airspeed KT --out plant.toml``: a JSBSim aircraft's roll channel
at its trim point, written as a linear plant file (the work: ``tools.design.linearise``).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

from autopilot.shared.cli import OneLineArgumentParser
from tools.design.linearise import (
    LinearisationError,
    _linearise_child,
    add_timeout_argument,
    linearise_bounded,
    to_toml,
)


def build_parser() -> OneLineArgumentParser:
    p = OneLineArgumentParser(prog="python -m tools.plant", description=__doc__.split("\n\n")[0].replace("``", ""))
    sub = p.add_subparsers(dest="command", required=True)
    lin = sub.add_parser("linearise", help="a JSBSim aircraft's roll channel at its trim point, as a plant file")
    lin.add_argument("plant", help="jsbsim:MODEL[:KEY=VALUE,...], e.g. jsbsim:c172x")
    lin.add_argument("--airspeed", type=float, default=None, metavar="KT", help="trim airspeed (default: the spec's)")
    lin.add_argument("--out", required=True, metavar="FILE.toml", help="the plant file to write")
    add_timeout_argument(lin)
    return p


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["_linearise"]:  # the child of linearise_bounded
        return _linearise_child(argv[1:])
    parser = build_parser()
    args = parser.parse_args(argv)
    from dataclasses import replace

    from sitl.jsbsim_plant import JsbsimPlantError, parse_spec
    from sitl.plant import PlantError, check

    try:
        check(args.plant)
        spec = parse_spec(args.plant)
        if args.airspeed is not None:
            if not (math.isfinite(args.airspeed) and args.airspeed > 0):
                parser.error(f"--airspeed must be positive and finite, got {args.airspeed!r}")
            spec = replace(spec, airspeed_kt=args.airspeed)
        lin = linearise_bounded(spec, args.timeout)
    except (PlantError, JsbsimPlantError, LinearisationError) as exc:
        parser.error(str(exc))
    except KeyboardInterrupt:
        print(f"{parser.prog}: interrupted", file=sys.stderr)
        return 130
    try:
        Path(args.out).write_text(to_toml(spec, lin))
    except OSError as exc:
        parser.error(f"--out {args.out}: {exc.strerror or exc}")
    poles = np.linalg.eigvals(lin["A"])
    what = f"{len(spec.surfaces)}x{len(spec.surfaces)} lateral channels" if spec.is_mimo else "roll channel"
    print(f"wrote {args.out}: {spec.text()} {what}, poles " + ", ".join(f"{z:.4g}" for z in poles))
    return 0


if __name__ == "__main__":
    sys.exit(main())
