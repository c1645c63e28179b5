"""``Flight``: one flight of the three processes, started, watched and ended (child supervision, the web
server's lifetime), and ``FlightResult``, what it returns; ``fly_run_over_mavlink``, the ``mavlink`` transport
of experiments."""

from __future__ import annotations

import math
import os
import sys
import threading
import time
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

from autopilot.metrics import METRIC_NAMES
from autopilot.shared.process import (
    EXIT_ADDRESS_IN_USE,
    EXIT_FAILED,
    EXIT_INTERRUPTED,
    EXIT_OK,
    reserve_for,
    write_json_atomic,
)
from tools.flight.children import Child, cpu_times, free_udp_ports, machine_load, new_run_dir, stop_children
from tools.flight.command_lines import _flight_key, child_argvs
from tools.flight.config import (
    LIVE_RATE_HZ,
    LIVE_WINDOW_S,
    PROCESSES,
    PROFILES,
    FlightConfig,
    FlightConfigError,
)
from tools.flight.files import (
    STALE_FILES,
    SUMMARY_RESERVE_BYTES,
    _join_telemetry,
    _load,
    build_summary,
    flight_recovery,
    load_series,
    png_request,
    provisional_summary,
    remove_leftovers,
    start_recorder_import,
    write_flight_png,
    write_refusal,
    write_summary,
    write_unstarted,
)
from tools.flight.outcome import (
    _ended_normally,
    diverged_verdict,
    envelope_verdict,
    flown_report,
    outcome_of,
    verdict,
)
from tools.flight.telemetry import flight_span, telemetry_argvs
from tools.view.flight_picture import PngHelper


def _run_metrics(ap_stats: dict | None) -> dict:
    """The five METRIC_NAMES of what flew: summary.json's run (``build_summary`` takes it from the autopilot's
    stats when it flew a step), None each when nothing flew."""
    ap = ap_stats or {}
    m = ap.get("metrics") if ap.get("metric_samples") else None
    return {k: m.get(k) for k in METRIC_NAMES} if m is not None else dict.fromkeys(METRIC_NAMES)


class OutputError(OSError):
    """The flight's folder cannot be written (a full disk before the start): nothing was flown."""


@dataclass(frozen=True)
class FlightResult:
    """How a flight ended and what it left; ``series`` is read from the run folder on first use.

    Two facts: ``completed`` (flown to the end, every process clean) and ``controlled`` (it stayed inside the
    envelope, ``autopilot.envelope``; None when the autopilot left no verdict).  ``ok`` is both."""

    ok: bool
    exit_code: int  # 0 ok, 1 a process failed, 3 out of the envelope, 130 interrupted or stopped by the caller
    reason: str | None  # None when ok, else one line: what failed, or why the flight was not controlled
    metrics: dict  # the five METRIC_NAMES of what flew (None if nothing flew)
    out: Path
    summary: dict  # what summary.json holds
    completed: bool = False
    controlled: bool | None = None

    @property
    def outcome(self) -> str:
        """ "OK", "OUT OF ENVELOPE" or "FAILED" (``summary["outcome"]``)."""
        return outcome_of(self.exit_code)

    @cached_property
    def series(self) -> dict:
        """The per-step series (``load_series``): arrays keyed like ``tools.experiment.scenario.SERIES``; {} if not
        recorded."""
        return load_series(self.out)


def serve_web(web) -> str:
    """Start the flight's web viewer (a ``tools.flight.web.WebServer``, bound to loopback unless ``web_host`` says
    otherwise)
    and print where to open it; the URL the processes stream to.  It ends with the flight (``Flight._stop_web``)."""
    url = web.start()
    for line in web.notice():
        print(line, flush=True)
    return url


def _web_server(cfg: FlightConfig, out: Path):
    """The flight's ``tools.flight.web.WebServer`` (not started), its output in DIR/web.log."""
    from tools.flight.web import WebServer

    return WebServer(cfg.web_host, cfg.web_port, cfg.web_grpc_port, log_path=out / "web.log")


def run_tag(cfg: FlightConfig) -> str:
    """The plant in a run folder's name: its short name (``sitl.plant.name_of``) in characters a file name keeps."""
    import re

    return re.sub(r"[^A-Za-z0-9._-]+", "_", cfg.plant_name)[:40]


def run_folder_tag(cfg: FlightConfig) -> str:
    """What follows the time stamp in a new run folder's name: ``-rt-clsac-KH2013A`` (``-lockstep-...`` in lockstep,
    then the controller and ``run_tag``), as in ``runs/20250101-120000-rt-clsac-KH2013A``."""
    return f"-{'lockstep' if cfg.lockstep else 'rt'}-{cfg.controller}-{run_tag(cfg)}"


# ---------------------------------------------------------------------------------------- the flight
class Flight:
    """One flight: ``run()`` blocks and returns its ``FlightResult``; as a context manager, entering starts the
    processes and leaving stops whatever still runs, after which ``result`` holds the ``FlightResult``.

    ``start()``, ``wait(timeout)``, ``stop()`` and ``running`` are the pieces; ``interrupt()`` (safe from a signal
    handler or another thread) ends the flight as interrupted at the next poll of ``wait``.
    """

    def __init__(
        self,
        *,
        lockstep: bool = False,
        duration: float | None = None,
        controller: str = "clsac",
        lv: float | None = None,
        pfc: str | None = None,
        sigma_xu: float = 0.0,
        dead_zone_deg: float = 0.0,
        ki_max: float | None = None,
        freeze_when_saturated: bool = False,
        rate: float = 100.0,
        physics_rate: float | None = None,
        sensor_rate: float = 200.0,
        telemetry_rate: float | None = None,
        out: str | os.PathLike | None = None,
        base_port: int | None = None,
        start_time: float = 0.0,
        profile: str = "square",
        csv: str | None = None,
        amplitude: float = 10.0,
        period: float = 10.0,
        u_limit_deg: float = 30.0,
        envelope_roll: float = 60.0,
        envelope_saturated: float = 20.0,
        envelope: bool = True,
        timeout: float | None = None,
        rt_priority: int = 0,
        pin: bool = False,
        busy_wait: bool = False,
        lockstep_spin_us: float | None = None,
        lockstep_idle_exit: float = 5.0,
        vehicle_timeout: float = 5.0,
        quiet: bool = False,
        viewer: bool = False,
        connect: str | None = None,
        rrd: bool = True,
        rrd_live: bool = False,
        live_rate: float = LIVE_RATE_HZ,
        live_window: float = LIVE_WINDOW_S,
        rrd_merge_max_mb: float = 64.0,
        series: bool = True,
        png: bool = True,
        web: bool = False,
        web_host: str = "127.0.0.1",
        web_port: int = 9090,
        web_grpc_port: int = 9877,
        gcs_peer: tuple = (),
        failure_injection: bool = False,
        name: str | None = None,
        signing: bool = True,
        signing_key: str | os.PathLike | None = None,
        sysid: int = 1,
        turbulence: str | None = None,
        turbulence_sigma: str | tuple | None = None,
        turbulence_length: str | tuple | None = None,
        altitude: float | None = None,
        gust: str | tuple | None = None,
        crosswind: float | None = None,
        roll_noise: float | None = None,
        roll_bias: float | None = None,
        rate_noise: float | None = None,
        rate_bias: float | None = None,
        sensor_delay: int | None = None,
        loss: float | None = None,
        delay: float | None = None,
        duplicate: float | None = None,
        reorder: float | None = None,
        scale: str | tuple | None = None,
        seed: int | None = None,
        fault: str | tuple | list | None = None,
        plant: str = "kh2013a",
        params: str | os.PathLike | None = None,
        baseline_gains: str | tuple | None = None,
    ):
        """The keywords are ``FlightConfig``'s, the long flags of ``python -m tools.launch`` (docs/python-api.md):
        how it flies (``lockstep``, ``duration``, ``rate``, ...), the controller (``controller``, ``lv``, ``pfc``,
        ``params``, ``baseline_gains``, ...), the profile, the plant (``plant``), disturbances and faults, the
        envelope, the outputs (``out``, ``rrd``, ``series``, ``png``, ``viewer``, ``web``, ...) and the links
        (``signing``, ``sysid``, ...).  ``quiet``: the children's output is not echoed to this process's stdout
        (it is still in DIR/<process>.log); the launcher's ``--quiet``.  A bad value raises ``FlightConfigError``
        naming the keyword, before anything starts."""
        self.config = FlightConfig(
            lockstep=lockstep,
            duration=duration,
            controller=controller,
            lv=lv,
            pfc=pfc,
            sigma_xu=sigma_xu,
            dead_zone_deg=dead_zone_deg,
            ki_max=ki_max,
            freeze_when_saturated=freeze_when_saturated,
            rate=rate,
            physics_rate=physics_rate,
            sensor_rate=sensor_rate,
            telemetry_rate=telemetry_rate,
            out=out,
            base_port=base_port,
            start_time=start_time,
            profile=profile,
            csv=csv,
            amplitude=amplitude,
            period=period,
            u_limit_deg=u_limit_deg,
            envelope_roll=envelope_roll,
            envelope_saturated=envelope_saturated,
            envelope=envelope,
            timeout=timeout,
            rt_priority=rt_priority,
            pin=pin,
            busy_wait=busy_wait,
            lockstep_spin_us=lockstep_spin_us,
            lockstep_idle_exit=lockstep_idle_exit,
            vehicle_timeout=vehicle_timeout,
            quiet=quiet,
            viewer=viewer,
            connect=connect,
            rrd=rrd,
            rrd_live=rrd_live,
            live_rate=live_rate,
            live_window=live_window,
            rrd_merge_max_mb=rrd_merge_max_mb,
            series=series,
            png=png,
            web=web,
            web_host=web_host,
            web_port=web_port,
            web_grpc_port=web_grpc_port,
            gcs_peer=gcs_peer,
            failure_injection=failure_injection,
            name=name,
            signing=signing,
            signing_key=signing_key,
            sysid=sysid,
            turbulence=turbulence,
            turbulence_sigma=turbulence_sigma,
            turbulence_length=turbulence_length,
            altitude=altitude,
            gust=gust,
            crosswind=crosswind,
            roll_noise=roll_noise,
            roll_bias=roll_bias,
            rate_noise=rate_noise,
            rate_bias=rate_bias,
            sensor_delay=sensor_delay,
            loss=loss,
            delay=delay,
            duplicate=duplicate,
            reorder=reorder,
            scale=scale,
            seed=seed,
            fault=fault,
            plant=plant,
            params=params,
            baseline_gains=baseline_gains,
        )
        self.out: Path | None = None  # the run folder, once started
        self.result: FlightResult | None = None
        self._children: dict[str, Child] = {}
        self._parts: dict[str, Path] = {}
        self._recording_id: str | None = None
        self._web = None  # the --web server (tools.flight.web.WebServer), stopped when the flight ends
        self._png = None  # the flight.png helper process (tools.view.flight_picture.PngHelper), from start() to _end()
        self._early_png = None  # one started before this Flight existed (adopt_png_helper), used or closed by start()
        self._recorder = None  # the thread importing rerun while the children start (start_recorder_import)
        self._t0: float | None = None
        self._cpu0 = None  # the machine's CPU times when the flight started (children.cpu_times)
        self._interrupt = threading.Event()
        self._reserve = None  # disk space held for summary.json (autopilot.shared.process.SpaceReserve)

    @classmethod
    def for_scenario(cls, scenario, run, out, **options) -> Flight:
        """The lockstep flight of one ``tools.experiment.scenario`` RunSpec of a Scenario: quiet, with series, no
        flight.rrd
        (an experiment logs its runs side by side from the series)."""
        profile = scenario.profile
        if profile.kind not in PROFILES or (profile.kind == "step" and profile.step_time != 1.0):
            raise FlightConfigError(
                "profile",
                f"profile: {profile!r} has no launcher flags (square, step at 1 s, "
                "sine): fly it from a CSV file with csv=FILE",
            )
        return cls(
            lockstep=True,
            duration=scenario.duration_s,
            controller=run.controller or ("sac" if run.lv == 0 else "clsac"),
            lv=run.lv,
            pfc=run.pfc,
            sigma_xu=run.sigma_xu or 0.0,
            name=run.name,
            rate=scenario.control_rate_hz,
            physics_rate=scenario.physics_rate_hz,
            profile=profile.kind,
            amplitude=math.degrees(profile.amplitude),
            period=profile.period,
            u_limit_deg=math.degrees(scenario.u_limit_rad),
            plant=scenario.plant,
            params=scenario.params,
            baseline_gains=scenario.baseline_gains,
            **dict(scenario.disturbances),
            out=out,
            quiet=True,
            series=True,
            rrd=False,
            png=False,
            **options,
        )

    @property
    def running(self) -> bool:
        """Started and not yet ended."""
        return self._t0 is not None and self.result is None

    @property
    def pids(self) -> dict[str, int]:
        """Process id of each child started (the last attempt's, if ports had to be tried again)."""
        return {name: c.proc.pid for name, c in self._children.items()}

    def __enter__(self) -> Flight:
        return self.start()

    def __exit__(self, exc_type, exc, tb) -> bool:
        try:
            if self.result is None:
                if exc_type is KeyboardInterrupt:
                    self._end(EXIT_INTERRUPTED, None, "interrupted (Ctrl-C)")
                else:
                    self.stop()
        finally:
            if self.result is None:  # ending it failed (an internal error): no process of it outlives the flight
                stop_children(self._children.values())
            self._stop_web()  # whatever happened above
            self._stop_png()
        return False

    def _start_web(self) -> str:
        """Start the --web server before anything else; a port taken (or rerun failing) refuses the flight: one
        line, DIR/summary.json says so, nothing started (``tools.flight.web.WebServerError`` is raised to the
        caller)."""
        from tools.flight.web import WebServerError

        self._web = _web_server(self.config, self.out)
        try:
            return serve_web(self._web)
        except WebServerError as exc:
            write_refusal(self.out, "web", str(exc))
            if self._reserve is not None:  # nothing flies: no space is held
                self._reserve.release()
            raise

    def _stop_web(self) -> None:
        if self._web is not None:
            self._web.stop()

    def _stop_png(self) -> None:
        for helper in (self._png, self._early_png):
            if helper is not None:
                helper.close()
        self._png = self._early_png = None

    def adopt_png_helper(self, helper) -> None:
        """A picture helper (``tools.view.flight_picture.PngHelper``) started before this flight: ``python -m
        tools.launch`` starts one before its own imports, so that the helper's imports run on the core the launcher's
        leave idle.  ``start`` uses it if this flight draws its picture with a helper, else closes it at once."""
        if self._t0 is not None:
            raise RuntimeError("adopt_png_helper: the flight has started already")
        self._early_png = helper

    def run(self) -> FlightResult:
        """Fly to the end (or until interrupted) and return the result."""
        with self:
            return self.wait()

    def interrupt(self) -> None:
        """Ask the flight to end as interrupted (exit code 130) at the next poll of ``wait``."""
        self._interrupt.set()

    def start(self) -> Flight:
        """Start the SITL, the GCS script and the autopilot on free ports (or ``base_port``) and wait until the
        first two listen; a process failing at start-up ends the flight (see ``result``)."""
        if self._t0 is not None:
            raise RuntimeError("this flight was already started; a Flight flies once")
        cfg = self.config
        self._t0 = time.monotonic()
        self._cpu0 = cpu_times()  # how busy the machine is while it flies (a real-time flight's late steps)
        self.out = Path(cfg.out) if cfg.out else new_run_dir("runs", run_folder_tag(cfg))
        self.out.mkdir(parents=True, exist_ok=True)
        for f in (*STALE_FILES, "summary.json"):
            (self.out / f).unlink(missing_ok=True)
        remove_leftovers(self.out)
        # Until the flight ends the verdict is "not OK": a launcher killed outright (SIGKILL) leaves this, never
        # an earlier flight's "ok: true" in a reused folder.
        try:
            write_json_atomic(self.out / "summary.json", provisional_summary(os.getpid()))
        except OSError as exc:  # a full disk before anything flew: one line, exit 1 (tools.launch)
            self._stop_png()
            raise OutputError(f"could not write {self.out / 'summary.json'}: {exc.strerror or exc}") from None
        self._reserve = reserve_for(self.out / "summary.json", SUMMARY_RESERVE_BYTES)  # the verdict fits a full disk
        web_url = self._start_web() if cfg.web else None
        try:
            early, self._early_png = self._early_png, None
            if cfg.png and cfg.series and cfg.lockstep and not cfg.pin:
                # First: it imports numpy and Pillow while the flight starts and flies (tools.view.flight_picture).
                # Lockstep
                # only: a real-time loop (or a pinned CPU) is not to share its CPU with it; those draw at the end.
                try:
                    self._png = early if early is not None else PngHelper()
                except OSError:  # a picture never fails a flight: drawn here at the end instead
                    self._png = None
            elif early is not None:
                early.close()  # not wanted (the request never comes): killed before it takes more CPU
            telemetry, self._parts, self._recording_id = telemetry_argvs(cfg, self.out, web_url)
            key_file = _flight_key(cfg, self.out)
            for attempt in range(3):
                ports = range(cfg.base_port, cfg.base_port + 4) if cfg.base_port is not None else free_udp_ports(4)
                sitl_port, gcs_port, *ap_ports = ports
                self._spawn(child_argvs(cfg, self.out, sitl_port, gcs_port, telemetry, key_file, tuple(ap_ports)))
                if self._recorder is None and cfg.lockstep and not cfg.pin:
                    self._recorder = start_recorder_import(self._parts, flight_span(cfg), cfg.u_limit_deg)
                failed = self._await_listening()
                if failed is None:
                    break
                if failed.code == EXIT_ADDRESS_IN_USE and cfg.base_port is None and attempt < 2:
                    stop_children(self._children.values())  # a free port was taken in between: try others
                    continue
                self._end(
                    EXIT_FAILED,
                    failed.name,
                    f"{failed.name} failed at start-up (exit code {failed.code}): {failed.reason()}",
                )
                break
        except BaseException as exc:
            interrupted = isinstance(exc, KeyboardInterrupt)
            if not self._children:  # nothing started (e.g. the key did not fit on a full disk): no verdict to make
                self._stop_png()
                self._stop_web()
                why = "interrupted (Ctrl-C)" if interrupted else f"start-up failed: {type(exc).__name__}: {exc}"
                write_unstarted(self.out, EXIT_INTERRUPTED if interrupted else EXIT_FAILED, why, self._reserve)
                if isinstance(exc, OSError):
                    raise OutputError(f"could not write in {self.out}: {exc.strerror or exc}") from None
                raise
            self._end(
                EXIT_INTERRUPTED if interrupted else EXIT_FAILED,
                None if interrupted else "launch",
                "interrupted (Ctrl-C)" if interrupted else f"start-up failed: {type(exc).__name__}: {exc}",
            )
            raise
        return self

    def _spawn(self, argvs: dict[str, list[str]]) -> None:
        # All three start together (the autopilot announces itself until the SITL and the GCS answer).
        echo = not self.config.quiet
        self._children = {
            "sitl": Child("sitl", argvs["sitl"], self.out / "sitl.log", echo, "listening on"),
            "gcs": Child("gcs", argvs["gcs"], self.out / "gcs.log", echo, "listening on"),
            "autopilot": Child("autopilot", argvs["autopilot"], self.out / "autopilot.log", echo),
        }

    def _await_listening(self) -> Child | None:
        """Wait (up to 60 s each, or until interrupted) for the SITL and the GCS to listen; the one that exited
        instead, if any.  One that said it listens and has exited since is not one of them: a short lockstep flight
        can be flown to its end before this thread looks (a loaded machine; the verdict reads how it ended)."""
        for c in (self._children["sitl"], self._children["gcs"]):
            while not c.ready.wait(0.05) and not self._interrupt.is_set() and time.monotonic() - c.started <= 60:
                pass
            if c.code is not None and not c.marker_seen:
                return c
        return None

    def wait(self, timeout: float | None = None) -> FlightResult | None:
        """Watch the flight until it ends (its result) or ``timeout`` wall seconds pass (None)."""
        if self._t0 is None:
            raise RuntimeError("the flight was not started: call start() or run()")
        deadline = None if timeout is None else time.monotonic() + timeout
        while self.result is None:
            if self._interrupt.is_set():
                self._end(EXIT_INTERRUPTED, None, "interrupted (Ctrl-C)")
            elif not self._poll() and deadline is not None and time.monotonic() >= deadline:
                return None
        return self.result

    def stop(self) -> FlightResult:
        """End the flight now if it still runs (SIGINT to each process, killed after 5 s) and return its result:
        not ok, exit code 130, reason "stopped by the caller after X s of Y s"."""
        if self._t0 is None:
            raise RuntimeError("the flight was not started: call start() or run()")
        if self.result is None and not self._poll():  # it may have just ended by itself
            self._end(EXIT_INTERRUPTED, None, None, stopped=True)
        return self.result

    def _poll(self) -> bool:
        """One look at the processes (at most 50 ms); True if that ended the flight."""
        ap = self._children["autopilot"]
        code = ap.wait(0.05)
        if code is not None:
            if code != 0:
                self._end(EXIT_FAILED, "autopilot", f"autopilot failed (exit code {code}): {ap.reason()}")
            else:
                self._land()
            return True
        for c in (self._children["sitl"], self._children["gcs"]):
            if c.code not in (None, 0):
                self._end(EXIT_FAILED, c.name, f"{c.name} failed (exit code {c.code}): {c.reason()}")
                return True
        limit = self.config.wall_timeout
        if time.monotonic() - self._t0 > limit:
            why = "--timeout" if self.config.timeout else "the default limit; --timeout S sets it"
            self._end(EXIT_FAILED, "launch", f"flight did not finish within {limit:g} s of wall clock ({why})")
            return True
        return False

    def _land(self) -> None:
        """The autopilot ended the flight: the GCS sees it power off; the SITL ends by itself in lockstep, unless
        the autopilot ended before the end of the run (then nobody answers the SITL's frames: it is stopped now)."""
        failed = error = None
        interrupted = set()
        if not self.config.lockstep or not _ended_normally(_load(self.out / "autopilot.json")):
            self._children["sitl"].interrupt()
            interrupted.add("sitl")
        for name in ("gcs", "sitl"):
            c = self._children[name]
            code = c.wait(5.0)
            if code is None and name not in interrupted:  # (one that ignores SIGINT is killed by _end)
                c.interrupt()
                code = c.wait(5.0)
            if code not in (None, 0):
                failed, error = name, f"{name} failed (exit code {code}): {c.reason()}"
        self._end(EXIT_FAILED if failed else EXIT_OK, failed, error)

    def _end(self, exit_code: int, failed: str | None, error: str | None, stopped: bool = False) -> None:
        """Stop what still runs, merge the telemetry, write summary.json and set ``result``."""
        cfg = self.config
        t_end = time.monotonic()  # exits seen after this are those of stopping the flight
        try:
            stop_children(self._children.values())
        finally:
            self._stop_web()  # nothing streams any more: the server ends with the flight
        stats = {n: _load(self.out / f"{n}.json") for n in PROCESSES}
        metrics = _run_metrics(stats["autopilot"])
        # flight.png (the helper draws it from the series and the metrics) while the recording is joined here
        drawing = self._request_png(metrics)
        rrd_path, rrd_indexed, rrd_error = _join_telemetry(
            self._parts,
            self.out,
            self._recording_id,
            cfg.rrd_merge_max_mb,
            flight_span(cfg, stats["sitl"]),
            cfg.u_limit_deg,
            self._recorder,
        )
        if rrd_error and exit_code == EXIT_OK:
            exit_code, failed, error = EXIT_FAILED, "telemetry", rrd_error
        # a log the disk could not take (the children's output was still read: none blocked on it)
        log_errors = [
            f"{c.log_error} (what was written before is kept)" for c in self._children.values() if c.log_error
        ]
        if log_errors and exit_code == EXIT_OK:
            exit_code, failed, error = EXIT_FAILED, "launch", f"launch: could not write {log_errors[0]}"
        flown = flown_report(cfg, stats)
        machine = machine_load(self._cpu0)  # how busy every CPU of the machine was while it flew
        if stopped:
            error = f"stopped by the caller after {flown['sim_time_s']:g} s of {cfg.duration:g} s (sim time)"
        elif exit_code != EXIT_INTERRUPTED and (div := diverged_verdict(self._children, stats, flown, t_end)):
            exit_code, failed, error = div  # the plant diverged: the SITL stopped the flight, out of the envelope
        elif exit_code != EXIT_INTERRUPTED:
            exit_code, failed, error = verdict(self._children, stats, flown, exit_code, failed, error, t_end, machine)
            exit_code, failed, error = envelope_verdict(
                exit_code, failed, error, (stats["autopilot"] or {}).get("controlled")
            )
        summary = build_summary(
            cfg,
            self.out,
            stats,
            {n: c.code for n, c in self._children.items()},
            failed,
            error,
            exit_code,
            time.monotonic() - self._t0,
            rrd_path,
            rrd_indexed,
        )
        summary["flown"] = flown
        summary["recovery"] = flight_recovery(self.out, summary.get("faults"))  # per fault: back to tracking?
        summary["machine"] = machine
        if rrd_error or log_errors:  # also when the flight failed otherwise (a full disk: DIR/.parts keeps the spools)
            summary["output_errors"] = [*filter(None, [rrd_error]), *log_errors]
        png = self._png_result(drawing, metrics)
        summary["files"]["png"] = str(png) if png else None
        summary = write_summary(self.out, summary, self._reserve)  # the most complete that fits (a full disk)
        exit_code, error = summary["exit_code"], summary["error"]
        if self._reserve is not None:
            self._reserve.release()
        remove_leftovers(self.out)
        controlled = (summary["controlled"] or {}).get("ok")
        self.result = FlightResult(
            exit_code == EXIT_OK, exit_code, error, metrics, self.out, summary, summary["completed"], controlled
        )

    def _request_png(self, metrics: dict) -> bool:
        """Ask the helper for flight.png (the processes have exited: the series are complete); False if there is
        no helper to ask (then ``_png_result`` draws it here)."""
        cfg = self.config
        if not (cfg.png and cfg.series) or self._png is None:
            return False
        request = png_request(cfg, self.out, cfg.name or cfg.controller, metrics)
        return self._png.request(request)

    def _png_result(self, drawing: bool, metrics: dict):
        """DIR/flight.png: the helper's answer, or drawn here when there was none to ask or it did not answer; a
        picture never fails a flight (the reason it is missing is printed)."""
        cfg = self.config
        if not (cfg.png and cfg.series):
            return None
        png = error = None
        answered = False
        if drawing:
            answered, png, error = self._png.result()
        self._stop_png()
        if not answered:
            try:
                png = write_flight_png(cfg, self.out, cfg.name or cfg.controller, metrics)
            except (OSError, ValueError, KeyError) as exc:
                error = f"{type(exc).__name__}: {exc}"
        if error:
            print(f"launch: flight.png not written: {error}", file=sys.stderr, flush=True)
        return png


def fly_run_over_mavlink(scenario, run, workdir):
    """Fly one RunSpec of a Scenario in lockstep over real processes and UDP; metrics from what flew.

    The ``mavlink`` transport of ``tools.experiment``: files go to ``workdir``; returns a
    ``tools.experiment.scenario.RunResult`` whose series have the keys of ``tools.experiment.scenario.SERIES``,
    recorded by the
    autopilot (controller side, ``u`` = the command that flew, after PWM) and the SITL (``v``, ``delta_r``)."""
    from tools.experiment.scenario import RunResult

    res = Flight.for_scenario(scenario, run, Path(workdir)).run()
    if not res.completed or not res.summary["runs"]:  # out of the envelope is a result (SAC's), not a failure
        raise RuntimeError(f"mavlink run {run.name} failed: {res.reason} (see {res.out})")
    return RunResult(run.name, run.lv, res.metrics, res.series)
