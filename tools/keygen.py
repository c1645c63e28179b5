"""``python -m tools.keygen FILE``: create a MAVLink 2 signing key file (32 random bytes as 64 hex digits, mode 0600).

Give the same file to every process of a flight with ``--signing-key FILE`` (the launcher makes one per flight by
itself).  The file must not exist yet; the key is never printed.
"""

from __future__ import annotations

import sys

from autopilot.shared.cli import OneLineArgumentParser
from autopilot.shared.process import EXIT_FAILED
from autopilot.shared.signing import KeyFileError, write_key


def main(argv=None) -> int:
    p = OneLineArgumentParser(prog="python -m tools.keygen", description=__doc__.split("\n\n")[0])
    p.add_argument("file", metavar="FILE", help="the key file to create (must not exist)")
    args = p.parse_args(argv)
    try:
        write_key(args.file)
    except FileExistsError:
        p.error(f"{args.file} exists: remove it first or choose another name")
    except (OSError, KeyFileError) as exc:
        print(f"python -m tools.keygen: error: {args.file}: {getattr(exc, 'strerror', None) or exc}", file=sys.stderr)
        return EXIT_FAILED
    print(f"signing key written to {args.file} (mode 0600)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
