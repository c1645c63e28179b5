"""``python -m tools.experiment.study``."""

import sys

from tools.experiment.study.cli import main

sys.exit(main())
