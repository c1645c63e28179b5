"""``tools.bench.launch``'s schedule with ``--baseline``: the two codes take turns at going first and run the same way
(from their checkout, on PYTHONPATH).  With a fixed order, this checkout timed against itself gave 0.93 and 0.95:
the ratio measured the order.  The launches are stood in for here (the real ones take a minute; the command's own
test is ``tests/tools/flight/test_startup.py``): what is checked is which runs, in what order, from where."""

from __future__ import annotations

from pathlib import Path

from tools.bench import launch


def test_with_a_baseline_the_two_codes_take_turns_at_going_first_and_run_alike(monkeypatch, tmp_path, capsys):
    calls: list[tuple[str, str | None]] = []

    def flight(out: Path, extra, files, code=None):
        calls.append((out.name, code))
        wall = 2.0 if out.name.startswith("baseline") else 1.0  # the baseline twice as slow, whatever its place
        return wall, 0.5 * wall, 2 * wall, {}

    monkeypatch.setattr(launch, "_flight", flight)
    monkeypatch.setattr(launch, "_timed", lambda argv, code=None: (0.1, 0.1))
    figs = launch.main(["--runs", "4", "--baseline", str(tmp_path)])
    capsys.readouterr()
    timed = [c for c in calls if not c[0].startswith(("bare", "warm"))]
    firsts = [timed[2 * i][0].split("-")[0] for i in range(4)]
    assert firsts == ["baseline", "full", "baseline", "full"], timed
    codes = {name.split("-")[0]: code for name, code in timed}
    assert codes == {"baseline": str(tmp_path.resolve()), "full": launch.ROOT}
    assert figs["launch / baseline launch"]["value"] == 0.5
