"""``python -m tools.rrd summary|verify|merge|record`` (tools.view.rrd_files)."""

import sys

from tools.view.rrd_files import main

if __name__ == "__main__":
    sys.exit(main())
