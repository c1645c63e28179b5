"""``python -m tools.experiment``."""

import sys

from tools.experiment.runs import main

sys.exit(main())
