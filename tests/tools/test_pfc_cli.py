"""``python -m tools.pfc`` as a user runs it: a subprocess from the project root.

A successful run costs ~3 s (importing python-control), so the subprocesses are few (one full analysis,
--help and the bad inputs, which exit before python-control is imported), all started when this module
is collected so that they run concurrently with the rest of the suite; the tests only collect the
results.  Further variants call ``tools.pfc.main`` in-process (same code path, no 3 s start-up).
"""

from __future__ import annotations

import atexit
import json
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.e2e  # the command lines as subprocesses

ROOT = Path(__file__).parents[2]

JSON_CUSTOM = ("--json", "--pfc-num", "10", "--pfc-den", "4,40")  # the paper's D, given on the command line
HELP = ("--help",)
BAD = {
    # argv: text the one-line reason must contain (the offending value)
    ("--pfc-num", "1,a", "--pfc-den", "1,2"): "'a'",
    ("--pfc-num", "", "--pfc-den", "1,2"): "--pfc-num is empty",
    ("--pfc-num", "1,2", "--pfc-den", "1,3"): "[1.0, 2.0]/[1.0, 3.0] is not strictly proper",
    ("--pfc-num", "1", "--pfc-den=1,-2"): "pole 2 is not in the open left half plane",
    ("--pfc-num", "1", "--pfc-den", "1,NaN"): "'NaN'",
}
BAD_IN_PROCESS = {
    ("--pfc-num", "nan", "--pfc-den", "1,2"): "'nan'",
    ("--pfc-num", "1"): "without --pfc-den",
    ("--pfc", "paper", "--pfc-num", "1", "--pfc-den", "1,1"): "mutually exclusive",
    ("--pfc", "best"): "invalid choice: 'best'",
    ("--rate-hz", "-5"): "--rate-hz: must be in (0, 1000] Hz (CLSAC_RATE), got '-5'",
    ("--lv", "1e300"): "--lv: must be in [0, 10000] 1/s (CLSAC_LV), got '1e300'",  # was an overflow in the analysis
    ("--command-deg", "1e308"): "--command-deg: must be in [-180, 180] deg",
    ("--pfc-num", "0,0", "--pfc-den", "1,1"): "all zeros",
}


def _start(args: tuple[str, ...]) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "tools.pfc", *args],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


_PROCS = {args: _start(args) for args in (JSON_CUSTOM, HELP, *BAD)}


@atexit.register
def _cleanup() -> None:  # only the processes started above, if a test run was cut short
    for proc in _PROCS.values():
        if proc.poll() is None:
            proc.kill()


def result(args: tuple[str, ...]) -> tuple[int, str, str]:
    out, err = _PROCS[args].communicate(timeout=120)
    return _PROCS[args].returncode, out, err


REQUIRED_KEYS = {"minimum_phase", "relative_degree", "hf_gain", "unstable_gain_bands"}


def test_json_with_pfc_on_the_command_line():
    rc, out, err = result(JSON_CUSTOM)
    assert rc == 0, err
    d = json.loads(out)
    assert REQUIRED_KEYS <= d.keys()
    assert d["pfc"] == "paper" and d["pfc_num"] == [10.0] and d["pfc_den"] == [4.0, 40.0]
    assert d["minimum_phase"] is True and d["relative_degree"] == 1 and d["hf_gain"] == pytest.approx(2.5)
    # no single band claims the stable window [20.80, 27.29]: only the list, and a hull that says it is one
    assert "unstable_gain_band" not in d
    low, high = d["unstable_gain_bands_hull"]
    assert low == pytest.approx(0.6215458, rel=1e-6) and high == pytest.approx(1014.0569, rel=1e-6)
    edges = [x for b in d["unstable_gain_bands"] for x in (b["low"], b["high"])]
    assert edges == pytest.approx([0.6215458, 20.803930, 27.288749, 1014.0569], rel=1e-6)
    assert d["steady_state_error_deg"] == pytest.approx(0.017257, rel=1e-4)
    assert d["discrete"]["unstable_gain_bands_hull"][1] is None  # the 100 Hz loop: unstable up to infinity


def test_json_robust_in_process(capsys):
    from tools import pfc

    assert pfc.main(["--json", "--pfc", "robust"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert REQUIRED_KEYS <= d.keys()
    assert d["pfc_num"] == [10.0] and d["pfc_den"] == [1.0, 10.0] and d["pfc"] == "robust"
    assert d["minimum_phase"] is True and d["relative_degree"] == 1 and d["hf_gain"] == pytest.approx(10.0)
    assert d["unstable_gain_bands_hull"] is None and d["unstable_gain_bands"] == []


def test_help():
    rc, out, err = result(HELP)
    assert rc == 0 and "--pfc-num" in out and "unstable_gain_bands" in out


@pytest.mark.parametrize("args", list(BAD), ids=[" ".join(a) for a in BAD])
def test_bad_input_exits_nonzero_with_one_line_reason(args):
    rc, out, err = result(args)
    assert rc != 0
    assert out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert BAD[args] in lines[0]


@pytest.mark.parametrize("args", list(BAD_IN_PROCESS), ids=[" ".join(a) for a in BAD_IN_PROCESS])
def test_bad_input_in_process(args, capsys):
    from tools import pfc

    with pytest.raises(SystemExit) as exc:
        pfc.main(list(args))
    assert exc.value.code == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and BAD_IN_PROCESS[args] in lines[0], captured.err


def test_text_output_in_process(capsys):
    """The default human-readable report (same code path, in-process to save a 3 s subprocess)."""
    from tools import pfc

    assert pfc.main(["--pfc", "robust"]) == 0
    text = capsys.readouterr().out
    assert "minimum phase:       yes" in text
    assert "none (stable for every Ke > 0)" in text
    assert "PFC D(s) [robust] = (10) / (s + 10)" in text
