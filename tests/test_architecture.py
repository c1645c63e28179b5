"""The dependency rule (docs/design.md, "Dependency rule"), checked on the source's imports.

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

ROOT = Path(__file__).resolve().parents[1]
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
        ("autopilot/loop_x.py", "from tools.scenario import PAPER\n"),
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
