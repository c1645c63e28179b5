"""``python -m tools.experiment.damage.docs``: re-fly the damage study's published tables and write them into
docs/damage.md.

Each block of tables on the page sits between ``<!-- damage-tables: ARGS -->`` and ``<!-- /damage-tables -->``,
ARGS the flags of ``python -m tools.experiment damage`` that made it; this flies each block's command (or reads a
``summary.json`` given with ``--summary N=PATH`` for block N) and replaces the block with
``tools.experiment.damage.aggregate.markdown_tables`` of the result.  ``tests/project/test_docs_damage.py`` flies a
row of each block again and compares every printed digit with the page.
"""

from __future__ import annotations

import argparse
import json
import re
import shlex
import subprocess
import sys
import tempfile
from pathlib import Path

BLOCK = re.compile(r"(<!-- damage-tables: ([^\n]*?) -->\n)(.*?)(<!-- /damage-tables -->)", re.S)
PAGE = Path(__file__).resolve().parents[3] / "docs" / "damage.md"


def fly(args: list[str], out: Path) -> dict:
    """The ``summary.json`` document of the damage study run with ``args`` into ``out``."""
    cmd = [sys.executable, "-m", "tools.experiment", "damage", *args, "--quiet", "--no-plot", "--out", str(out)]
    subprocess.run(cmd, check=True)
    return json.loads((out / "summary.json").read_text(encoding="utf-8"))


def merge(docs: list[dict]) -> dict:
    """One document of several runs of the same command, one plant each (``--plant`` split to fly them apart)."""
    out = dict(docs[0])
    for d in docs[1:]:
        out["plants"] = out["plants"] + [p for p in d["plants"] if p not in out["plants"]]
        out["controllers"] = list(dict.fromkeys(out["controllers"] + d["controllers"]))
        out["cells"] = out["cells"] + d["cells"]
        out["not_flown"] = {**out.get("not_flown", {}), **d.get("not_flown", {})}
    return out


def rewrite(text: str, docs: dict[int, dict]) -> str:
    """``text`` with block i's tables replaced by those of ``docs[i]`` (blocks not in ``docs`` are kept)."""
    from tools.experiment.damage.aggregate import markdown_tables

    count = iter(range(10**6))

    def one(m: re.Match) -> str:
        i = next(count)
        if i not in docs:
            return m.group(0)
        return m.group(1) + "\n" + markdown_tables(docs[i]).strip() + "\n\n" + m.group(4)

    return BLOCK.sub(one, text)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m tools.experiment.damage.docs", description=__doc__.splitlines()[0])
    p.add_argument("--page", type=Path, default=PAGE, help="the page to rewrite (default docs/damage.md)")
    p.add_argument("--blocks", default=None, metavar="I,J", help="only these blocks (0 = the first; default all)")
    p.add_argument(
        "--summary",
        action="append",
        default=[],
        metavar="N=PATH",
        help="block N from this summary.json (repeat N for one plant per file)",
    )
    args = p.parse_args(argv)
    text = args.page.read_text(encoding="utf-8")
    blocks = [shlex.split(m.group(2)) for m in BLOCK.finditer(text)]
    given: dict[int, list[Path]] = {}
    for k, _, v in (s.partition("=") for s in args.summary):
        given.setdefault(int(k), []).append(Path(v))
    wanted = range(len(blocks)) if args.blocks is None else [int(i) for i in args.blocks.split(",")]
    docs = {}
    with tempfile.TemporaryDirectory() as tmp:
        for i in wanted:
            if i in given:
                docs[i] = merge([json.loads(f.read_text(encoding="utf-8")) for f in given[i]])
            else:
                print(f"block {i}: python -m tools.experiment damage {shlex.join(blocks[i])}", flush=True)
                docs[i] = fly(blocks[i], Path(tmp) / f"block{i}")
    args.page.write_text(rewrite(text, docs), encoding="utf-8")
    print(f"rewrote {len(docs)} block(s) of {args.page}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
