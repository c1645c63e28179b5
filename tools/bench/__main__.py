"""``python -m tools.bench [AREA ...] [--json PATH] [--strict] [--quick] [-- AREA_ARGS]``: run benchmark areas.

Areas are discovered by module name (see ``tools/bench/__init__.py``): with no AREA (or ``all``) every
area present runs; an area whose module cannot be imported is skipped with its reason.
"""

from __future__ import annotations

import platform
import sys
import time
from pathlib import Path

from autopilot.shared.cli import OneLineArgumentParser
from autopilot.shared.process import standard_json
from tools import bench


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    forwarded: list[str] = []
    if "--" in argv:
        i = argv.index("--")
        argv, forwarded = argv[:i], argv[i + 1 :]
    available = bench.areas()
    p = OneLineArgumentParser(
        prog="python -m tools.bench",
        description="Run benchmarks and compare them with their targets. Areas: "
        + ", ".join(available)
        + ". Arguments after -- go to every area's main().",
    )
    p.add_argument("area", nargs="*", help="areas to run (default: all)")
    p.add_argument("--json", metavar="PATH", help="write every figure to this JSON file")
    p.add_argument("--strict", action="store_true", help="exit 1 when a figure misses its target")
    p.add_argument("--quick", action="store_true", help="fewer repetitions (smoke test; figures are noisier)")
    if "-h" in argv or "--help" in argv:  # `AREA --help`: this help, then each named area's own flags
        p.print_help()
        for area in dict.fromkeys(a for a in argv if a in available):
            print(f"\n{area}: its own flags (below) go after --: python -m tools.bench {area} -- FLAGS\n")
            try:
                bench.load(area).main(["--help"])
            except SystemExit:
                pass
        return 0
    args = p.parse_args(argv)

    explicit = [a for a in args.area if a != "all"]
    for a in explicit:
        if a not in available:
            print(
                f"python -m tools.bench: error: unknown benchmark area {a!r} (available: {', '.join(available)})",
                file=sys.stderr,
            )
            return 2
    selected = list(dict.fromkeys(explicit)) or available
    if args.json:
        out = Path(args.json)
        if out.is_dir() or not out.parent.is_dir():
            print(
                f"python -m tools.bench: error: cannot write --json {args.json!r}: not a file in an existing folder",
                file=sys.stderr,
            )
            return 2

    results: dict[str, dict] = {}
    skipped: dict[str, str] = {}
    errors: dict[str, str] = {}
    t_all = time.perf_counter()
    for area in selected:
        try:
            module = bench.load(area)
        except Exception as exc:  # noqa: BLE001  (an area's optional dependency may be missing)
            reason = f"{type(exc).__name__}: {exc}"
            if explicit:
                print(f"python -m tools.bench: error: area {area!r} cannot be imported: {reason}", file=sys.stderr)
                return 2
            skipped[area] = reason
            print(f"[{area}] skipped: {reason}")
            continue
        area_argv = (list(getattr(module, "QUICK_ARGV", [])) if args.quick else []) + forwarded
        t0 = time.perf_counter()
        try:
            figures = module.main(area_argv)
        except SystemExit as exc:  # the area rejected its arguments (it printed why) or gave up
            if exc.code not in (0, None):
                errors[area] = f"exited with status {exc.code}"
                print(f"[{area}] error: exited with status {exc.code}", file=sys.stderr)
                continue
            figures = {}
        except Exception as exc:  # noqa: BLE001  (one broken area must not hide the others' figures)
            errors[area] = f"{type(exc).__name__}: {exc}"
            print(f"[{area}] error: {errors[area]}", file=sys.stderr)
            continue
        results[area] = figures if isinstance(figures, dict) else {}
        print(f"[{area}] done in {time.perf_counter() - t0:.1f} s\n")

    failed = bench.failures(results)
    total = time.perf_counter() - t_all
    print(
        f"benchmarks: {len(results)} area(s) in {total:.1f} s; "
        + (f"{len(failed)} target(s) missed: {', '.join(failed)}" if failed else "all targets met")
        + (f"; area(s) in error: {', '.join(errors)}" if errors else "")
    )
    if args.json:
        doc = {
            "areas": results,
            "skipped": skipped,
            "errors": errors,
            "failed": failed,
            "host": {
                "python": platform.python_version(),
                "machine": platform.machine(),
                "platform": platform.platform(),
                **bench.machine_load(),
            },
            "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        }
        Path(args.json).write_text(standard_json(doc, indent=2) + "\n", encoding="utf-8")
        print(f"wrote {Path(args.json).resolve()}")
    if errors:
        return 1
    return 1 if (args.strict and failed) else 0


if __name__ == "__main__":
    sys.exit(main())
