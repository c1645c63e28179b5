"""The flags the experiment commands share (``python -m tools.experiment damage``, ``delay-margin``,
``robustness``): the output folder, the local workers, and the plants' list as given to ``--plant``."""

from __future__ import annotations

import argparse

from autopilot.shared import cli


def add_out(p: argparse.ArgumentParser, name: str) -> None:
    """``--out DIR``, by default a new ``runs/NAME-<timestamp>/``."""
    p.add_argument("--out", metavar="DIR", help=f"output folder (default: a new runs/{name}-<timestamp>/)")


def add_workers(p: argparse.ArgumentParser, default: int | None = None, *, scheduler: bool = True) -> None:
    """``--workers N`` local processes (1 to 1024; ``default`` None: the machine's cores), ``scheduler``: the
    command also takes ``--scheduler`` (then the workers are its)."""
    when = " when no --scheduler" if scheduler else ""
    what = "default: the machine's cores" if default is None else f"default {default}"
    p.add_argument(
        "--workers",
        type=cli.count(1, 1024, name="workers"),
        default=default,
        help=f"local processes{when} ({what}; results do not change)",
    )


def plant_list(text: str) -> list[str]:
    """The plants of ``--plant P1,P2``, each once, each checked (``tools.experiment.damage.grid.DamageError`` for a
    malformed list, ``sitl.plant.PlantError`` for a plant that is not one: one line)."""
    from sitl import plant as plants
    from tools.experiment.damage import grid

    out = list(dict.fromkeys(grid.parse_list(text, "plants")))  # a value given twice is flown once
    for p in out:
        plants.check(p)
    return out


__all__ = ["add_out", "add_workers", "plant_list"]
