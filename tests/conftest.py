"""Shared fixtures.  Slow tests that start real processes carry the ``e2e`` marker:
``python -m pytest -m "not e2e"`` runs the fast ones in seconds."""

from __future__ import annotations

import pytest

from tools.scenario import PAPER, PAPER_RUNS, run_inprocess


@pytest.fixture(scope="session")
def paper_runs() -> dict:
    """The reference scenario's five runs in-process (no wire model), by run name: ``RunResult`` objects."""
    return {run.name: run_inprocess(PAPER, run) for run in PAPER_RUNS}
