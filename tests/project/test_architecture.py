"""The dependency rule (docs/architecture.md, "Dependency rule"), checked on the source's imports.

* ``autopilot.shared`` (the MAVLink wire contract, process plumbing, telemetry writer primitives) imports
  nothing of the project outside itself;
* nothing under ``autopilot/`` imports ``sitl`` or ``tools``;
* ``sitl/`` imports from ``autopilot`` only ``autopilot.shared`` (never the control law, the loop, the step
  or the autopilot's telemetry) and never ``tools``.

Every import statement counts, at module level or inside a function.
"""

from __future__ import annotations

import ast
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PROJECT = ("autopilot", "sitl", "tools")


def _imports(path: Path, root: Path) -> list[tuple[int, str]]:
    """(line, module) for every import in a file; ``from a import b`` yields ``a.b`` (b may be a module)."""
    tree = ast.parse(path.read_text(), str(path))
    package = ".".join(path.relative_to(root).parts[:-1])
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative: resolve against the file's package
                parts = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(p for p in (*parts, base) if p)
            out += [(node.lineno, f"{base}.{a.name}" if base else a.name) for a in node.names]
    return out


def _allowed(importer: str, module: str) -> bool:
    top = module.split(".")[0]
    if top not in PROJECT:
        return True  # standard library and third-party packages
    if importer.startswith("autopilot.shared"):
        return module.startswith("autopilot.shared")
    if importer.startswith("autopilot"):
        return top == "autopilot"
    if importer.startswith("sitl"):
        return top == "sitl" or module.startswith("autopilot.shared")
    return True  # tools may import anything


def violations(root: Path = ROOT) -> list[str]:
    bad = []
    for package in ("autopilot", "sitl"):
        for path in sorted((root / package).rglob("*.py")):
            importer = ".".join(path.relative_to(root).with_suffix("").parts)
            for line, module in _imports(path, root):
                if not _allowed(importer, module):
                    bad.append(f"{path.relative_to(root)}:{line}: {importer} imports {module}")
    return bad


def test_the_dependency_rule_holds():
    assert violations() == []


@pytest.mark.parametrize(
    ("where", "source"),
    [
        ("autopilot/loop_x.py", "from sitl.aircraft import Aircraft\n"),
        ("autopilot/loop_x.py", "def f():\n    import sitl.model\n"),
        ("autopilot/loop_x.py", "from tools.experiment.scenario import PAPER\n"),
        ("autopilot/shared/x.py", "from autopilot.clsac import ClSac\n"),
        ("autopilot/shared/x.py", "from autopilot import ClSac\n"),
        ("autopilot/shared/x.py", "from ..step import ControlStep\n"),
        ("sitl/x.py", "from autopilot.clsac import ClSac\n"),
        ("sitl/x.py", "from autopilot import telemetry\n"),
        ("sitl/x.py", "import autopilot.loop\n"),
        ("sitl/x.py", "from autopilot.step import ControlStep\n"),
    ],
)
def test_a_broken_rule_is_reported(tmp_path, where, source):
    """The check is not vacuous: each kind of forbidden import, planted in a copy-like tree, is found."""
    for pkg in ("autopilot", "autopilot/shared", "sitl"):
        (tmp_path / pkg).mkdir(parents=True, exist_ok=True)
        (tmp_path / pkg / "__init__.py").write_text("")
    (tmp_path / where).write_text(source)
    found = violations(tmp_path)
    assert len(found) == 1 and where in found[0], found


@pytest.mark.parametrize(
    "source",
    [
        "from autopilot.shared.link import UdpLink\n",
        "from autopilot.shared import mavlink\n",
        "from . import model\n",
    ],
)
def test_allowed_sitl_imports_pass(tmp_path, source):
    for pkg in ("autopilot", "autopilot/shared", "sitl"):
        (tmp_path / pkg).mkdir(parents=True, exist_ok=True)
        (tmp_path / pkg / "__init__.py").write_text("")
    (tmp_path / "sitl" / "x.py").write_text(source)
    assert violations(tmp_path) == []


def test_the_simulator_process_does_not_load_the_control_law():
    """At run time too: importing the SITL's modules leaves the law, the loop and the step unloaded."""
    code = textwrap.dedent("""
        import sys
        import sitl, sitl.aircraft, sitl.endpoint, sitl.__main__
        loaded = sorted(m for m in sys.modules
                        if m.split('.')[0] == 'autopilot' and not m.startswith('autopilot.shared')
                        and m != 'autopilot')
        print(loaded)
    """)
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout + out.stderr


def _module_names(root: Path) -> dict[str, Path]:
    """Every module of the project: ``a.b`` for ``a/b.py``, ``a`` for ``a/__init__.py``."""
    out = {}
    for package in PROJECT:
        for path in sorted((root / package).rglob("*.py")):
            parts = path.relative_to(root).with_suffix("").parts
            out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def import_cycles(root: Path = ROOT) -> list[list[str]]:
    """The import circles among the project's modules (every import counts, lazy ones too): the strongly
    connected components of more than one module of the import graph (Tarjan's algorithm, iterative)."""
    modules = _module_names(root)

    def resolve(name: str) -> str | None:  # ``a.b.C`` (a name in module a.b) -> ``a.b``
        while name and name not in modules:
            name = name.rpartition(".")[0]
        return name or None

    graph = {m: sorted({r for _, i in _imports(p, root) if (r := resolve(i)) and r != m}) for m, p in modules.items()}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles = []
    for start in graph:
        if start in index:
            continue
        work = [(start, iter(graph[start]))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            v, children = work[-1]
            w = next(children, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(graph[w])))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                component = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    component.append(w)
                    if w == v:
                        break
                if len(component) > 1:
                    cycles.append(sorted(component))
    return cycles


def test_no_import_circle():
    assert import_cycles() == []


def test_an_import_circle_is_reported(tmp_path):
    """The check is not vacuous: a circle of three modules, one of its imports lazy, is found whole."""
    for pkg in PROJECT:
        (tmp_path / pkg).mkdir()
        (tmp_path / pkg / "__init__.py").write_text("")
    (tmp_path / "tools" / "a.py").write_text("from tools.b import f\n")
    (tmp_path / "tools" / "b.py").write_text("def f():\n    from tools import c\n")
    (tmp_path / "tools" / "c.py").write_text("import tools.a\nfrom sitl import x\n")
    (tmp_path / "sitl" / "x.py").write_text("")
    assert import_cycles(tmp_path) == [["tools.a", "tools.b", "tools.c"]]


# ------------------------------------------------------------------------------- the layout (docs/architecture.md)
MAX_MODULE_LINES = 700
MAX_TOOLS_ENTRIES = 10  # tools/ grouped by job: the commands and the rooms (docs/architecture.md, "The rooms")
MANUAL_PAGES = ("tests.md", "benchmarks.md")  # manuals, not lab notebooks: history is in git
MAX_MANUAL_LINES = 150


def tools_entries(root: Path = ROOT) -> list[str]:
    """The entries at the top of tools/ (its package files and caches left out)."""
    skip = {"__init__.py", "__main__.py", "__pycache__"}
    return sorted(p.name for p in (root / "tools").iterdir() if p.name not in skip and not p.name.startswith("."))


def long_modules(root: Path = ROOT, limit: int = MAX_MODULE_LINES) -> list[str]:
    return [
        f"{p.relative_to(root)}: {n} lines"
        for package in PROJECT
        for p in sorted((root / package).rglob("*.py"))
        if (n := len(p.read_text().splitlines())) > limit
    ]


def test_no_module_is_longer_than_700_lines():
    assert long_modules() == []


def test_a_long_module_is_reported(tmp_path):
    for pkg in PROJECT:
        (tmp_path / pkg).mkdir()
    (tmp_path / "sitl" / "big.py").write_text("x = 1\n" * 701)
    (tmp_path / "tools" / "ok.py").write_text("x = 1\n" * 700)
    assert long_modules(tmp_path) == ["sitl/big.py: 701 lines"]


def test_tools_has_at_most_ten_entries_grouped_by_job():
    entries = tools_entries()
    assert len(entries) <= MAX_TOOLS_ENTRIES, entries
    assert {"bench", "design", "experiment", "flight", "view"} <= set(entries), entries
    # one Monte Carlo for every plant: python -m tools.experiment robustness --plant (tools/experiment/study/)
    assert not (ROOT / "tools" / "jsbsim_study.py").exists()
    assert not (ROOT / "tools" / "experiment" / "jsbsim_study.py").exists()
    # every top entry that is a file is a command: its module answers python -m (a __main__ guard)
    for name in entries:
        if name.endswith(".py"):
            assert 'if __name__ == "__main__":' in (ROOT / "tools" / name).read_text(), name


def test_no_file_name_repeats_a_plant_or_design_module():
    """``plant.py``/``design.py`` once each in the tree, so a name says which room it is (sitl/plant.py is the plant
    interface, tools/plant.py the linearisation command)."""
    for name in ("plant.py", "design.py"):
        found = sorted(str(p.relative_to(ROOT)) for pkg in PROJECT for p in (ROOT / pkg).rglob(name))
        assert len(found) <= 2 and not any(f.startswith("tools/") and f.count("/") > 1 for f in found), found


@pytest.mark.parametrize("page", MANUAL_PAGES)
def test_the_manual_pages_are_short(page):
    lines = (ROOT / "docs" / page).read_text().splitlines()
    assert len(lines) <= MAX_MANUAL_LINES, f"docs/{page}: {len(lines)} lines"


MAX_ARCHITECTURE_LINES = 250  # the map a newcomer reads first (docs/architecture.md)


def test_the_architecture_page_is_short():
    lines = (ROOT / "docs" / "architecture.md").read_text().splitlines()
    assert len(lines) <= MAX_ARCHITECTURE_LINES, f"docs/architecture.md: {len(lines)} lines"


def _readme_commands() -> list[tuple[str, ...]]:
    """Each ``python -m MODULE [SUBCOMMAND]`` the README shows (in its shell blocks and inline), once."""
    import re
    import shlex

    text = (ROOT / "README.md").read_text()
    snippets = re.findall(r"```(?:sh|bash|)\n(.*?)```", text, re.S) + re.findall(r"`(python -m [^`]+)`", text)
    found = set()
    for snippet in snippets:
        for part in re.split(r"&&|\|\||[|;&\n]", snippet):
            try:
                words = shlex.split(part, comments=True)
            except ValueError:
                continue
            if len(words) >= 3 and words[:2] == ["python", "-m"]:
                module, rest = words[2], words[3:]
                ours = module.split(".")[0] in PROJECT
                found.add((module, rest[0]) if ours and rest and re.fullmatch(r"[a-z]+", rest[0]) else (module,))
    return sorted(found)


def test_every_readme_command_answers_help():
    """``python -m X [SUB] --help`` exits 0 for every command of the README (the moved modules included)."""
    from concurrent.futures import ThreadPoolExecutor

    commands = _readme_commands()
    assert {("tools.launch",), ("tools.experiment", "paper"), ("tools.experiment", "robustness")} <= set(commands)

    def run(argv):
        r = subprocess.run(
            [sys.executable, "-m", *argv, "--help"], cwd=ROOT, capture_output=True, text=True, timeout=120
        )
        return argv, r.returncode, r.stderr.strip().splitlines()[-1:] if r.returncode else []

    with ThreadPoolExecutor(4) as pool:
        bad = [(a, code, err) for a, code, err in pool.map(run, commands) if code != 0]
    assert bad == [], bad
