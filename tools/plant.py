"""``python -m tools.plant linearise jsbsim:MODEL --airspeed KT --out plant.toml`` (tools.design.linearise)."""

import sys

from tools.design.linearise import main

if __name__ == "__main__":
    sys.exit(main())
