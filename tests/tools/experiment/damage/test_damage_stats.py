"""The damage study's statistics (``tools.experiment.damage.stats``) and the cells, tables and paired comparisons
built on them (``tools.experiment.damage.aggregate``), each against a count done by hand on a small grid."""

from __future__ import annotations

import math

import pytest

from tools.experiment.damage import grid, stats
from tools.experiment.damage.aggregate import (
    cell_of,
    first_period,
    long_of,
    markdown_paired_table,
    markdown_table,
    paired_table,
    period_table,
    summarise,
    table,
    wilson,
)


def test_the_sign_test_interval_is_the_binomial_table_s():
    # n = 10: P(Bin(10, 1/2) <= 1) = 11/1024, so [d_(2), d_(9)] covers the median with 1 - 22/1024 = 97.85 %;
    # [d_(3), d_(8)] would cover it with 1 - 2 * 56/1024 = 89 % only
    lo, hi, conf = stats.sign_interval([9, 1, 8, 2, 7, 3, 6, 4, 5, 10])
    assert (lo, hi) == (2, 9) and conf == pytest.approx(1 - 22 / 1024)
    # n = 6, the least that reaches 95 %: the range, 1 - 2/64
    assert stats.sign_interval([3, 1, 2, 6, 5, 4]) == (1, 6, pytest.approx(1 - 2 / 64))
    # n = 4: no interval reaches 95 %; the range with its own 1 - 2/16
    assert stats.sign_interval([0.4, 0.1, 0.3, 0.2]) == (0.1, 0.4, pytest.approx(0.875))
    assert stats.sign_interval([math.nan, None]) is None


def test_a_paired_difference_takes_the_common_seeds_and_shows_only_at_95_percent():
    a = {1: 1.0, 2: 2.0, 3: 3.0, 4: 4.0, 5: 5.0, 6: 6.0, 7: 100.0}
    b = {6: 6.5, 5: 5.4, 4: 4.3, 3: 3.2, 2: 2.1, 1: 1.6, 8: -50.0}  # seeds 7 and 8 flew one law only
    d = stats.paired(a, b, "ise_ref_after")
    assert d["n"] == 6 and d["median_diff"] == pytest.approx((0.4 + 0.3) / 2)
    assert d["interval"] == pytest.approx([0.1, 0.6]) and d["shown"] and d["verdict"] == "b higher"
    four = stats.paired({s: a[s] for s in (1, 2, 3, 4)}, b, "x")  # the same signs, 4 seeds: 87.5 % only
    assert not four["shown"] and four["verdict"].startswith("no difference shown")
    across = stats.paired(a, {s: v + (0.5 if s % 2 else -0.5) for s, v in a.items()}, "x")  # 0 inside
    assert not across["shown"] and across["interval"][0] < 0 < across["interval"][1]


def test_paired_shares_are_the_exact_mcnemar_test():
    # 6 seeds only b keeps, none only a: p = 2 (1/2)^6 = 0.03125; 5: 0.0625
    a = {s: False for s in range(8)}
    six = stats.paired_share(a, {s: s < 6 for s in range(8)})
    assert (six["b_only"], six["a_only"]) == (6, 0) and six["p_value"] == pytest.approx(0.03125) and six["shown"]
    five = stats.paired_share(a, {s: s < 5 for s in range(8)})
    assert five["p_value"] == pytest.approx(0.0625) and not five["shown"]
    both = stats.paired_share({s: True for s in range(8)}, {s: True for s in range(8)})
    assert both["p_value"] == 1.0 and not both["shown"]


def test_a_median_prints_the_digits_its_interval_supports():
    assert stats.digits(3.15, (2.0, 10.0)) == 1  # half width 4: 3.15 is "3"
    assert stats.digits(0.0451, (0.040, 0.050)) == 2  # half width 0.005: 0.045
    assert stats.digits(0.102, (0.1015, 0.1025)) == 3  # 4 supported, 3 at most
    assert stats.digits(0.5, (0.5, 0.5)) == 3 and stats.digits(None, None) == 3


def test_the_bootstrap_mean_is_the_mean_and_repeats():
    vals = [0.1, 0.2, 0.3, 0.4, 1.0]
    m, lo, hi = stats.bootstrap_mean(vals)
    assert m == pytest.approx(0.4) and lo < m < hi and lo >= 0.1 and hi <= 1.0
    assert stats.bootstrap_mean(vals) == (m, lo, hi)  # a fixed generator: the same interval on every run
    assert stats.bootstrap_mean([0.3] * 7) == pytest.approx((0.3, 0.3, 0.3))
    assert stats.bootstrap_mean([math.nan]) == (None, None, None)  # no NaN for summary.json


def test_wilson_interval_of_three_in_ten():
    # (p + z^2/2n -+ z sqrt(p(1-p)/n + z^2/4n^2)) / (1 + z^2/n), p = 0.3, n = 10, z = 1.96: 0.1078, 0.6032
    assert wilson(3, 10) == pytest.approx((0.1078, 0.6032), abs=1e-4)
    # at 0/n and n/n the bound is the share exactly: (1 + z^2/n - z^2/n) / (1 + z^2/n) rounds to 2.8e-17 at 0/6
    for n in range(1, 13):
        assert wilson(0, n)[0] == 0.0 and wilson(n, n)[1] == 1.0


def test_damage_png_draws_cells_kept_and_lost_by_every_seed(tmp_path):
    from tools.view.damage_png import draw

    cells = _cells()
    for c in cells:  # every flight of CL-SAC's lost, every one of the PID's kept: the Wilson bounds at 0 and 1
        c["controlled"] = c["flights"] if c["controller"] == "baseline" else 0
        c["share_controlled"] = c["controlled"] / c["flights"]
        c["wilson95"] = list(wilson(c["controlled"], c["flights"]))
    path = draw(cells, ["kh2013a"], ["rate"], ["clsac", "baseline"], {}, tmp_path / "damage.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def _rec(seed=1, controlled=True, after=0.1, recovered=True, recovery_s=2.0, periods=(0.1, 0.2, 0.3), energy=1.0):
    return {
        "seed": seed,
        "controlled": controlled,
        "oscillating": False,
        "ise_ref_after": after,
        "energy_after": energy,
        "ise_ref": after,
        "energy": energy,
        "max_abs_roll_deg": 10.0,
        "recovered": recovered,
        "recovery_s": recovery_s,
        "ise_ref_periods": list(periods),
    }


def test_the_recovered_share_and_time_are_over_the_right_flights():
    # five flights: two recovered (2 s, 4 s), one measured and not (its time 9 s must not count), two not measured
    recs = [
        _rec(1, recovered=True, recovery_s=2.0),
        _rec(2, recovered=True, recovery_s=4.0),
        _rec(3, recovered=False, recovery_s=9.0),
        _rec(4, recovered=None, recovery_s=7.0),
        _rec(5, recovered=None, recovery_s=None),
    ]
    cell = cell_of(recs)
    assert cell["recovered_share"] == pytest.approx(2 / 3)  # of the 3 measured, not of the 5 flown
    assert cell["recovery_s_p50"] == 3.0  # the median of the 2 that recovered
    assert cell_of([_rec(recovered=None)])["recovered_share"] is None


def test_the_first_period_after_an_onset_is_the_next_whole_one():
    assert first_period(10.0) == 1 and first_period(10.0 + 1e-12) == 1  # 10-20 s
    assert first_period(15.0) == 2 and first_period(0.5) == 1  # inside a period: the next one, not floored
    recs = [_rec(s, periods=[0.0, 1.0, 2.0, 3.0, 4.0] + [10.0 + s] * 20) for s in (1, 2)]
    lg = long_of(recs, 15.0, window=100.0)
    assert lg["first_period"]["start_s"] == 20.0 and lg["first_period"]["mean"] == 2.0
    # the last 100 s: periods 15-24 of each seed, 11 and 12
    assert lg["last_window"]["from_s"] == 150.0 and lg["last_window"]["to_s"] == 250.0
    assert lg["last_window"]["units"] == 20 and lg["last_window"]["mean"] == pytest.approx(11.5)


def _cells(onsets=(10.0, 20.0)):
    """Two controllers, 6 seeds, a fault at two onsets: the first onset's numbers differ from the last's."""
    flights, results = [], []
    for ctrl, base in (("clsac", 1.0), ("baseline", 2.0)):
        for seed in range(1, 7):
            flights.append(grid.DamageFlight("kh2013a", ctrl, grid.NONE, None, onsets[0], seed))
            results.append(_rec(seed, after=base * 0.01 + seed * 1e-4, energy=base))
            for t in onsets:
                flights.append(grid.DamageFlight("kh2013a", ctrl, "rate", 5.0, t, seed))
                err = base * (0.3 if t == onsets[0] else 7.0) + seed * 1e-3
                results.append(_rec(seed, controlled=ctrl == "baseline" or seed > 4, after=err, energy=2 * base))
    return summarise(flights, results)


def test_tables_take_the_first_onset_by_default_not_the_last():
    cells = _cells()
    row = next(r for r in table(cells, "kh2013a", ["clsac", "baseline"]).splitlines() if r.startswith("rate=5"))
    assert "0.3" in row and "0.6" in row and "7." not in row and "14" not in row, row
    md = markdown_table(cells, "kh2013a", ["clsac", "baseline"]).splitlines()
    assert md[3].startswith("| `rate=5` | 33 % / 0.30") and "100 % / 0.60" in md[3], md[3]
    assert "onset 10 s" in paired_table(cells, "kh2013a", ["clsac", "baseline"])


def test_cells_pair_each_law_with_cl_sac_on_common_seeds():
    cells = _cells()
    rate = next(c for c in cells if c["controller"] == "baseline" and c["kind"] == "rate" and c["onset_s"] == 10.0)
    d = rate["vs"]["ise_ref_after"]
    assert rate["reference"] == "clsac" and rate["vs"]["law"] == "clsac"
    # per seed: (2 * 0.3 + s/1000) - (0.3 + s/1000) = 0.3 exactly, on all 6 seeds: shown at 96.9 %
    assert d["n"] == 6 and d["median_diff"] == pytest.approx(0.3) and d["interval"] == pytest.approx([0.3, 0.3])
    assert d["shown"] and d["confidence"] == pytest.approx(1 - 2 / 64)
    assert rate["energy_ratio"]["median"] == pytest.approx(2.0)
    # controlled: the baseline keeps all 6, CL-SAC seeds 5 and 6: 4 discordant pairs, p = 2/16
    assert (rate["vs"]["controlled"]["b_only"], rate["vs"]["controlled"]["p_value"]) == (4, pytest.approx(0.125))
    ref = next(c for c in cells if c["controller"] == "clsac" and c["kind"] == "rate" and c["onset_s"] == 10.0)
    assert "vs" not in ref
    md = markdown_paired_table(cells, "kh2013a", ["clsac", "baseline"]).splitlines()
    assert md[0] == "| fault | PID (as designed) - CL-SAC |" and "no difference shown" not in md[3]


def test_the_long_flight_table_ranks_the_means_over_the_last_window():
    flights, results = [], []
    for ctrl, last in (("clsac", 0.05), ("baseline", 0.02)):
        for seed in (1, 2):
            flights.append(grid.DamageFlight("kh2013a", ctrl, "rate", 5.0, 10.0, seed, 300.0))
            first = 0.01 if ctrl == "clsac" else 0.03
            results.append(_rec(seed, periods=[0.0, first] + [1.0] * 18 + [last + seed * 1e-3] * 10))
    cells = summarise(flights, results)
    row = next(r for r in period_table(cells, "kh2013a", ["clsac", "baseline"]).splitlines() if "rate=5" in r)
    assert "0.01(1)/0.052 [0.051, 0.052](2)" in row and "0.03(2)/0.022 [0.021, 0.022](1)" in row, row
    base = next(c for c in cells if c["controller"] == "baseline")
    lw = base["vs"]["last_window"]
    assert lw["units"] == 20 and lw["mean_diff"] == pytest.approx(-0.03) and lw["shown"]
