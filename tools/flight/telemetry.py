"""A flight's telemetry wiring: one recording id, where each process writes its rows, what a live viewer gets.

* ``telemetry_argvs``: the processes' telemetry flags.  Every row goes to the recording: by default each process
  spools its rows (``--telemetry-spool``) and the launcher records the spools into ``DIR/flight.rrd`` after the flight,
  in sim-time order (``autopilot.shared.telemetry.record_spools``); ``--rrd-live`` has the processes write their parts
  with rerun as they fly.  A live viewer (``--viewer``, ``--connect``, ``--web``) has a stream of its own, thinned to
  ``live_rate`` rows per sim second of each table (``autopilot.shared.telemetry.thinning``).
* ``live_blueprint``: the layout the launcher sends that viewer: the plots over the last ``live_window`` sim seconds
  (the state lanes over the whole flight).
* ``flight_span``: the sim time ``DIR/flight.rrd``'s plots show: the flight, from its start clock to its end (or to
  where the SITL stopped, for a flight cut short).
"""

from __future__ import annotations

from pathlib import Path

from tools.flight.config import FlightConfig


def flight_span(cfg: FlightConfig, sitl_stats: dict | None = None) -> tuple[float, float]:
    """(start, end) sim s of the flight: ``start_time`` to ``start_time + duration``, or to the SITL's last sim time
    when it flew less (its stats' ``sim_time_s``, counted from the start)."""
    flown = cfg.duration
    sim = (sitl_stats or {}).get("sim_time_s")
    if isinstance(sim, (int, float)) and 0 < sim < cfg.duration:
        flown = float(sim)
    return cfg.start_time, cfg.start_time + flown


def live_blueprint(cfg: FlightConfig):
    """The flight layout for a live viewer: ``flight_span`` as asked, the plots on a trailing ``live_window``."""
    from tools.view.views import flight_blueprint

    return flight_blueprint(flight_span(cfg), trailing_s=cfg.live_window or None, rudder_limit_deg=cfg.u_limit_deg)


def telemetry_argvs(
    cfg: FlightConfig, out: Path, web_url: str | None = None
) -> tuple[dict[str, list[str]] | None, dict[str, Path], str | None]:
    """One recording id for the flight, each process's telemetry flags and where it writes its rows (joined at the
    end: ``tools.flight.files._join_telemetry``).  ``web_url``: the flight's web viewer (``--web``, already
    started), which the processes stream to."""
    if not (cfg.rrd or cfg.viewer or cfg.connect or cfg.web):
        return None, {}, None
    from autopilot.shared import telemetry as tm

    rid = tm.new_recording_id()
    url = cfg.connect or (tm.spawn_viewer() if cfg.viewer else None)  # one viewer for both processes
    if web_url is not None:
        url = web_url
    spooled = cfg.rrd and not cfg.rrd_live
    parts = (tm.spool_paths(out) if spooled else tm.part_paths(out)) if cfg.rrd else {}
    for p in parts.values():
        p.parent.mkdir(parents=True, exist_ok=True)
        p.unlink(missing_ok=True)
    if url:  # the processes send data only; the layout that joins them comes from here
        tm.send_blueprint(url, live_blueprint(cfg), rid)
    argv = {}
    for name in ("autopilot", "sitl"):
        argv[name] = ["--recording-id", rid]
        if name in parts:
            argv[name] += ["--telemetry-spool" if spooled else "--rrd", str(parts[name])]
        if url:
            argv[name] += ["--connect", url]
            if cfg.live_rate:
                argv[name] += ["--live-rate", repr(float(cfg.live_rate))]
    return argv, parts, rid
