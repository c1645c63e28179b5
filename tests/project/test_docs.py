"""The front page and the manual stay true: the README is one screen with the two set-up commands, every link
between pages (and every #anchor) resolves, and every ``python -m`` command shown uses only flags that command's
own ``--help`` lists (each command's ``--help`` is run for real, once)."""

from __future__ import annotations

import re
import shlex
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
OUR_MODULES = ("autopilot", "sitl", "tools.")
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
FENCE = re.compile(r"```([^\n]*)\n(.*?)```", re.S)  # (language, body)
INLINE = re.compile(r"`(python -m [^`]+)`")


def _slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, markup and punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[`*_]", "", heading.strip().lower())
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def _anchors(page: Path) -> set[str]:
    text = FENCE.sub("", page.read_text(encoding="utf-8"))
    return {_slug(m.group(1)) for m in re.finditer(r"^#{1,6} (.+)$", text, re.M)}


def test_front_page_is_one_screen_with_the_two_setup_commands():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(text.splitlines()) < 150
    first_block = FENCE.search(text).group(2).strip().splitlines()
    assert first_block == ['python -m pip install -e ".[dev]" && python -m tools.launch', "python -m pytest"]


def test_front_page_links_every_manual_page():
    text = (ROOT / "README.md").read_text(encoding="utf-8") + (ROOT / "docs" / "README.md").read_text(encoding="utf-8")
    for page in PAGES[1:]:
        assert page.name in text, f"no link to docs/{page.name} from the front page or the manual's index"


def _links():
    for page in PAGES:
        for m in LINK.finditer(FENCE.sub("", page.read_text(encoding="utf-8"))):
            target = m.group(1)
            if not re.match(r"[a-z]+:", target):
                yield page, target


@pytest.mark.parametrize("page, target", list(_links()), ids=lambda v: v.name if isinstance(v, Path) else v)
def test_link_resolves(page, target):
    path, _, anchor = target.partition("#")
    dest = (page.parent / path).resolve() if path else page
    assert dest.exists(), f"{page.name}: link to {target}: no such file"
    if anchor:
        assert anchor in _anchors(dest), f"{page.name}: link to {target}: no heading with that anchor in {dest.name}"


def _commands() -> list[tuple[str, list[str]]]:
    """Every ``python -m`` command of this project shown in a shell block or inline, as argv after ``-m``."""
    found = []
    for page in PAGES:
        text = page.read_text(encoding="utf-8")
        blocks = [body.replace("\\\n", " ") for lang, body in FENCE.findall(text) if lang in ("", "sh", "bash")]
        snippets = blocks + INLINE.findall(FENCE.sub("", text))
        for snippet in snippets:
            for line in snippet.splitlines():
                for part in re.split(r"&&|\|\||[|;&]", line):
                    try:
                        words = shlex.split(part, comments=True)
                    except ValueError:
                        continue
                    if len(words) >= 3 and words[:2] == ["python", "-m"] and words[2].startswith(OUR_MODULES):
                        found.append((page.name, words[2:]))
    return found


@cache
def _help(argv: tuple[str, ...]) -> str | None:
    proc = subprocess.run(
        [sys.executable, "-m", *argv, "--help"], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    return proc.stdout if proc.returncode == 0 else None


def _split(argv: list[str]) -> tuple[tuple[str, ...], list[str]]:
    """(the command: module and subcommand if it has one, its long flags before any ``--``)."""
    module, rest = argv[0], argv[1:]
    if "--" in rest:
        rest = rest[: rest.index("--")]
    command = (module,)
    if rest and re.fullmatch(r"[a-z][a-z_-]*", rest[0]):
        sub = _help((module, rest[0]))
        if sub is not None and sub != _help((module,)):
            command = (module, rest[0])
    flags = [w.split("=", 1)[0] for w in rest if w.startswith("--") and len(w) > 2]
    return command, flags


COMMANDS = _commands()


def test_the_pages_show_commands():
    modules = {argv[0] for _, argv in COMMANDS}
    assert {"tools.launch", "autopilot", "sitl", "tools.experiment", "tools.rrd"} <= modules


def test_every_flag_shown_is_one_the_command_takes():
    """Run each command's --help once (in parallel) and look up every long flag the pages give it."""
    split = [(page, *_split(argv)) for page, argv in COMMANDS]
    commands = sorted({c for _, c, _ in split})
    with ThreadPoolExecutor(4) as pool:
        helps = dict(zip(commands, pool.map(_help, commands)))
    bad = []
    for page, command, flags in split:
        text = helps[command]
        if text is None:
            bad.append(f"{page}: python -m {' '.join(command)} --help fails")
            continue
        bad += [
            f"{page}: python -m {' '.join(command)} has no {f}"
            for f in flags
            if not re.search(rf"(?<![\w-]){f}(?![\w-])", text)
        ]
    assert not bad, "\n".join(sorted(set(bad)))
