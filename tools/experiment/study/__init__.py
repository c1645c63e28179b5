"""The Monte Carlo robustness study of every plant (issues 13, 28): on the KH2013A many aircraft and controllers
stepped at once as numpy arrays (or in C); on a JSBSim aircraft or a plant file, one in-process flight at a time.

    python -m tools.experiment robustness [--plant kh2013a|FILE.toml|jsbsim:MODEL[,...]] [--seed S] [--out DIR]
                                          [--controllers a,b] [--workers N | --scheduler tcp://HOST:PORT]
        kh2013a:                          [--runs N] [--conditions nominal,moderate,severe] [--sweep-runs M]
                                          [--long-runs L] [--chunk C]
        a JSBSim aircraft or plant file:  [--airspeeds KT,...] [--turbulence none,light,...] [--seeds N]
    python -m tools.experiment replay --controller NAME --condition NAME --seed S --run I

The KH2013A's study follows; the scalar plants' is ``flights``' doc, the list of plants ``robustness``'.
Per controller (``CONTROLLERS``: SAC, CL-SAC at L_v 10/20/50, the fixed-gain baseline, CL-SAC with each robustness
modification) and condition (``CONDITIONS``: nominal, moderate, severe, plus one-factor sweeps of link loss, sensor
delay and turbulence from nominal), N runs of the paper's 30 s square wave; a separate 600 s long-flight scenario
(``--long-runs``) measures the drift of the integral gains.  Writes ``DIR/summary.json`` (per controller and
condition: share of bounded runs, p50/p95 of every metric, the worst run and the commands that replay it),
``DIR/robustness.png`` (metric distributions per controller), ``DIR/worst.rrd`` (the worst runs side by side) and
prints the table.

**Randomness.**  Run i draws everything from ``numpy.random.default_rng([seed, i])``: first the static draws (plant
scale factors, PFC, gust, crosswind, bias, turbulence initial state) as standard uniforms/normals, then, in blocks,
7 standard normals per control step (4 for the Dryden filter, 1 roll noise, 2 link-loss draws).  A condition only
maps these standard draws to values, so run i sees the same underlying draws under every controller and condition
(common random numbers), and a run's result depends on (seed, i, controller, condition) only: never on the chunk
it was computed in or the worker that computed it.  Every per-step operation is elementwise (the law:
``autopilot.batch``; the plant: explicit sums in a fixed order, not BLAS), so element i of a batch is the same
whatever N.

**Models.**  Plant: the 6-state KH2013A + servo (``sitl.model``) scaled by ``sitl.uncertainty.PlantScales``,
advanced one control period T with the command and the disturbance held (exact ZOH of [B_p, E],
``sitl.atmosphere.disturbance_matrix``).  Turbulence: ``sitl.atmosphere.DrydenFilter`` built at T (the disturbance
is sampled and held at the control rate, 100 Hz, rather than the SITL's 1 kHz physics rate), intensity as a
multiple of MIL-HDBK-1797 "severe"; 1-cosine side gust (``sitl.atmosphere.Gust``); steady crosswind.  Sensor:
roll delayed by D samples, plus bias and white noise (``sitl.sensors`` semantics).  Link: each ATTITUDE is lost
with probability p (the law steps on the last roll received, as the real-time autopilot does before its 100 ms
failsafe), each SERVO_OUTPUT_RAW with probability p (the servo keeps the last command).

**Bounded**: the flight stayed inside the default envelope of ``autopilot.envelope`` (the one definition of a
controlled flight the autopilot and the launcher use too): max |roll| (truth) < 60 deg and the command saturated
(``autopilot.envelope.saturated``: at the limit) in < 20 % of the steps.

**Never hangs.**  The batches stream (``execution.stream``: in task order, a few in flight, the tasks generated as
they go), into a ``Tally`` whose memory follows the cells, not the runs (``accumulate``); the study prints its
estimate of time and memory first, and SIGINT stops it within 0.1 s, keeping what is done (a summary marked
``partial``).  A Dask scheduler is probed before use, every wait bounded (``scheduler``).

Layout: ``sampling`` (controllers, conditions, tasks), ``simulation`` (one batch; its steps in numpy, or in C:
``kernel.c``, built and loaded by ``native``, the same numbers bit for bit), ``execution`` (many batches, here or
on Dask), ``scheduler`` (Dask, bounded), ``accumulate`` (the runs folded as they come; Wilson intervals),
``aggregation`` (summary.json), ``report`` (tables, figure, worst runs), ``runner``
(``run_study``: the KH2013A's), ``flights`` (a JSBSim aircraft's or a plant file's), ``robustness`` (a list of
plants, one summary.json) and ``cli`` (the command lines); every name is importable from ``tools.experiment.study``
as before.
"""

from __future__ import annotations

from tools.experiment.study.accumulate import wilson
from tools.experiment.study.aggregation import (
    LONG_CONDITIONS,
    LONG_CONTROLLERS,
    LONG_DURATION_S,
    aggregate,
    breaks,
    long_flight_summary,
    mavlink_command,
    replay_command,
)
from tools.experiment.study.cli import (
    add_run_arguments,
    build_parser,
    build_replay_parser,
    main,
    main_replay,
    main_run,
    options_from_args,
    replay_main,
)
from tools.experiment.study.execution import Progress, execute, interruptible, merge, stream
from tools.experiment.study.inputs import CANONICAL_BITS, DRYDEN_COLUMN_SIGNS, canonical
from tools.experiment.study.report import format_breaks, format_long, format_table, save_figure, save_worst_rrd
from tools.experiment.study.runner import run_study
from tools.experiment.study.sampling import (
    BLOCK,
    BOUND_ROLL_RAD,
    BOUND_SAT_FRACTION,
    CHANNELS,
    CONDITIONS,
    DEG,
    ENVELOPE,
    METRICS,
    STATIC,
    SWEEPS,
    WINDOW_S,
    Condition,
    StudyError,
    StudyOptions,
    Task,
    get_condition,
    get_controller,
    make_tasks,
    sweep_conditions,
)
from tools.experiment.study.simulation import replay, simulate

__all__ = [
    "BLOCK",
    "BOUND_ROLL_RAD",
    "BOUND_SAT_FRACTION",
    "CANONICAL_BITS",
    "CHANNELS",
    "CONDITIONS",
    "Condition",
    "DEG",
    "DRYDEN_COLUMN_SIGNS",
    "ENVELOPE",
    "LONG_CONDITIONS",
    "LONG_CONTROLLERS",
    "LONG_DURATION_S",
    "METRICS",
    "Progress",
    "STATIC",
    "SWEEPS",
    "StudyError",
    "StudyOptions",
    "Task",
    "WINDOW_S",
    "add_run_arguments",
    "aggregate",
    "breaks",
    "build_parser",
    "build_replay_parser",
    "interruptible",
    "canonical",
    "execute",
    "format_breaks",
    "format_long",
    "format_table",
    "get_condition",
    "get_controller",
    "long_flight_summary",
    "main",
    "main_replay",
    "main_run",
    "make_tasks",
    "mavlink_command",
    "merge",
    "options_from_args",
    "replay_main",
    "replay",
    "replay_command",
    "run_study",
    "save_figure",
    "save_worst_rrd",
    "simulate",
    "stream",
    "sweep_conditions",
    "wilson",
]
