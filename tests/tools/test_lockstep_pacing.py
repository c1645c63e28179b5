"""What paces a lockstep flight besides the two processes' frames (docs/spec.md, "Lockstep"): the GCS script's nap
between two passes, which follows the sim rate it sees and keeps its schedule ahead."""

from __future__ import annotations

import pytest

from tools.flight.profiles import Profile
from tools.gcs import LOCKSTEP_NAP_MAX_S, LOCKSTEP_NAP_MIN_S, Gcs, GcsOptions


@pytest.fixture
def gcs():
    g = Gcs(GcsOptions(listen=("127.0.0.1", 0), lockstep=True, quiet=True), Profile.square())
    yield g
    g.link.close()


def _naps(g: Gcs, passes) -> list[float]:
    """The nap after each pass (wall s, sim ms seen by then)."""
    out = []
    for now, sim_ms in passes:
        g.sim_ms = sim_ms
        out.append(g._lockstep_nap(now))
    return out


def test_nap_is_half_the_lookahead_at_the_sim_rate_seen(gcs):
    la = gcs.opts.lookahead
    assert la == 5.0  # the default: the autopilot takes setpoints up to 10 s ahead
    # 100x real time: half of 5 s of sim time is 25 ms of wall time, more than the longest nap
    assert _naps(gcs, [(10.0, 1000), (10.01, 2000)]) == [LOCKSTEP_NAP_MIN_S, LOCKSTEP_NAP_MAX_S]
    # 250x: 2.5 s of sim time is 10 ms
    assert _naps(gcs, [(10.02, 4500)]) == [pytest.approx(0.5 * la / 250.0)]
    # 2000x: 1.25 ms, below the shortest nap (the fixed 4 ms this script took before): the shortest
    assert _naps(gcs, [(10.03, 24500)]) == [LOCKSTEP_NAP_MIN_S]
    assert LOCKSTEP_NAP_MIN_S == 0.004


def test_nap_is_the_shortest_while_sim_time_stands_still_or_is_unknown(gcs):
    # no sim time yet; then the first one; then it stands still (the vehicle may wait for this schedule); then
    # it goes back (a restarted clock)
    naps = _naps(gcs, [(1.0, None), (1.1, 500), (1.2, 500), (1.3, 400), (1.31, 1400)])
    assert naps[:4] == [LOCKSTEP_NAP_MIN_S] * 4
    assert naps[4] == LOCKSTEP_NAP_MAX_S  # 1 s of sim time in 10 ms: 100x, half the lookahead is 25 ms
