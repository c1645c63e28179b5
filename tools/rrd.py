"""``python -m tools.rrd summary|verify|merge|record``: inspect, verify and merge .rrd files (the work:
``tools.view.rrd_files``, whose doc lists the subcommands)."""

from __future__ import annotations

import sys

from autopilot.shared.cli import OneLineArgumentParser, output_file_problem
from tools.view.rrd_files import _first_error, checked, merge, record, summary, verify


def main(argv: list[str] | None = None) -> int:
    ap = OneLineArgumentParser(prog="python -m tools.rrd", description="Inspect, verify and merge .rrd files.")
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("summary", help="entities, rows and time span of each recording")
    p.add_argument("files", nargs="+")
    p = sub.add_parser(
        "verify",
        help="the file whole: its framing to the last byte (footers required unless --no-footer-check), its content "
        "against FILE.sha256 when there is one (written beside every recording the product makes), then rerun rrd "
        "verify (every message decoded)",
    )
    p.add_argument("files", nargs="+")
    p.add_argument(
        "--no-footer-check", action="store_true", help="accept files without footer (the per-process parts of a flight)"
    )
    p = sub.add_parser("merge", help="merge the part files of one flight into one recording")
    p.add_argument("out")
    p.add_argument("parts", nargs="+")
    p.add_argument(
        "--concatenate",
        action="store_true",
        help="copy the parts into one stream in constant memory, without rerun's footer (for long flights)",
    )
    p.add_argument(
        "--no-blueprint",
        action="store_true",
        help="never add the flight blueprint (by default it is added if no part has one)",
    )
    p = sub.add_parser("record", help="record the telemetry spools of one flight into one recording")
    p.add_argument("out")
    p.add_argument("spools", nargs="+")
    p.add_argument("--no-blueprint", action="store_true", help="do not add the flight blueprint")
    args = ap.parse_args(argv)
    if args.cmd in ("merge", "record"):
        # before anything is read: a target that is not a regular file (/dev/null) is never replaced by one
        problem = output_file_problem(args.out)
        if problem:
            ap.error(problem)
    try:
        if args.cmd == "summary":
            for f in args.files:
                print(summary(f))
            return 0
        if args.cmd == "verify":
            bad = 0
            for f in args.files:
                ok, msg = verify(f, check_footers=not args.no_footer_check)
                print(f"{f}: {'ok' + checked(msg) if ok else 'FAILED: ' + _first_error(msg)}")
                bad += not ok
            return 1 if bad else 0
        if args.cmd == "record":
            print(record(args.out, args.spools, blueprint=not args.no_blueprint))
            return 0
        print(merge(args.out, args.parts, blueprint=not args.no_blueprint, concatenate=args.concatenate))
        return 0
    except (OSError, ValueError, RuntimeError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
