"""``python -m tools.launch``: fly SITL + autopilot + GCS script together as real processes over UDP.

Real time by default, ``--lockstep`` for as fast as the machine allows (deterministic).  Writes
``DIR/flight.tlog`` (every packet the autopilot sent and received, standard tlog), ``DIR/summary.json``
(DESIGN.md schema, one run, metrics from what flew, plus counters, timing and file names) and each
child's output in ``DIR/<name>.log``; prints a summary table.  Ctrl-C or a failing child stops
everything cleanly, leaves valid files and exits non-zero naming the process that failed.

``run_lockstep(scenario, run, workdir)`` is the entry point of ``tools.experiment --transport mavlink``.
"""

from __future__ import annotations

import json
import math
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from autopilot.shared.process import EXIT_ADDRESS_IN_USE

PROCESSES = ("sitl", "gcs", "autopilot")


@dataclass
class LaunchConfig:
    lockstep: bool = False
    duration: float = 30.0
    controller: str = "clsac"
    lv: float | None = None
    pfc: str = "paper"  # autopilot.config.PFC_PRESETS key
    sigma_xu: float = 0.0  # sigma-modification of K_Ix, K_Iu (0 = the paper)
    name: str | None = None
    rate: float = 100.0
    physics_rate: float = 1000.0
    sensor_rate: float = 200.0
    telemetry_rate: float | None = None  # GCS stream rate; default 50 Hz real time, 10 Hz of sim time in lockstep
    out: str | None = None
    base_port: int | None = None
    start_time: float = 0.0
    profile: str = "square"
    amplitude: float = 10.0
    period: float = 10.0
    csv: str | None = None
    u_limit_deg: float = 30.0
    rudder_max_deg: float = 30.0
    echo: bool = True  # show the children's output on the console
    rt_priority: int = 0  # real time: SCHED_FIFO priority for the autopilot (and SITL one below), 0 = normal
    pin: bool = False  # the autopilot alone on CPU 1; the SITL and the GCS script on CPU 0
    busy_wait: bool = False  # real time: the autopilot never sleeps between steps (one CPU at 100 %)
    series: bool = False  # autopilot and SITL record per-step series (DIR/autopilot_series.npz, DIR/sitl_series.npz)
    timeout: float | None = None  # wall-clock limit for the whole flight (default from the duration)
    rrd: bool = True  # Rerun telemetry from the autopilot and the SITL, merged into DIR/flight.rrd
    viewer: bool = False  # spawn a Rerun viewer (or reuse the one on port 9876) and stream to it live
    connect: str | None = None  # stream live to a running Rerun viewer at this URL
    extra: dict = field(default_factory=dict)  # extra argv per process name


@dataclass
class LaunchResult:
    ok: bool
    exit_code: int
    error: str | None
    out_dir: Path
    summary: dict


class Child:
    """A child process whose output goes to DIR/<name>.log (and, if echo, to the console with a prefix)."""

    def __init__(self, name: str, argv: list[str], log_path: Path, echo: bool, ready_marker: str | None = None):
        self.name = name
        self.argv = argv
        self.log_path = log_path
        self.echo = echo
        self.ready = threading.Event()
        self.ready_marker = ready_marker
        self.tail: list[str] = []
        self._log = open(log_path, "w", buffering=1)
        self._log.write("$ " + " ".join(argv) + "\n")
        env = dict(os.environ, PYTHONUNBUFFERED="1", MAVLINK20="1")
        self.proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     env=env, start_new_session=True, text=True,
                                     bufsize=1)
        self.started = time.monotonic()
        self._reader = threading.Thread(target=self._read, name=f"read-{name}", daemon=True)
        self._reader.start()

    def _read(self):
        for line in self.proc.stdout:
            self._log.write(line)
            line = line.rstrip("\n")
            self.tail.append(line)
            if len(self.tail) > 40:
                del self.tail[:20]
            if self.ready_marker and self.ready_marker in line:
                self.ready.set()
            if self.echo:
                sys.stdout.write(f"[{self.name}] {line}\n")
                sys.stdout.flush()
        self.ready.set()  # EOF: whoever waits for readiness must look at the exit code

    @property
    def code(self):
        return self.proc.poll()

    def interrupt(self):
        if self.proc.poll() is None:
            try:
                self.proc.send_signal(signal.SIGINT)
            except ProcessLookupError:
                pass

    def wait(self, timeout: float) -> int | None:
        try:
            return self.proc.wait(timeout=max(0.0, timeout))
        except subprocess.TimeoutExpired:
            return None

    def kill(self):
        if self.proc.poll() is None:
            try:
                self.proc.kill()
            except ProcessLookupError:
                pass
            self.proc.wait()

    def finish(self):
        self._reader.join(timeout=5)
        self._log.close()

    def reason(self) -> str:
        """The child's last error line, for the launcher's message."""
        for line in reversed(self.tail):
            if "error" in line.lower():
                return line.strip()
        return self.tail[-1].strip() if self.tail else "(no output)"


def free_udp_ports(n: int) -> list[int]:
    socks = []
    try:
        for _ in range(n):
            s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            s.bind(("127.0.0.1", 0))
            socks.append(s)
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


def new_run_dir(base: str = "runs", tag: str = "") -> Path:
    stamp = time.strftime("%Y%m%d-%H%M%S")
    root = Path(base)
    root.mkdir(parents=True, exist_ok=True)
    for i in range(1000):
        d = root / (f"{stamp}{tag}" + (f"-{i + 1}" if i else ""))
        try:
            d.mkdir()
            return d
        except FileExistsError:
            continue
    raise RuntimeError(f"cannot create a new run folder under {root}")


def _scenario_name(cfg: LaunchConfig) -> str:
    paper = (cfg.profile == "square" and not cfg.csv and cfg.amplitude == 10.0 and cfg.period == 10.0
             and cfg.duration == 30.0 and cfg.rate == 100.0 and cfg.physics_rate == 1000.0 and cfg.u_limit_deg == 30.0)
    return "paper" if paper else "custom"


def _lv(cfg: LaunchConfig) -> float:
    return cfg.lv if cfg.lv is not None else (0.0 if cfg.controller == "sac" else 20.0)


def _telemetry_rate(cfg: LaunchConfig) -> float:
    """In lockstep the GCS stream only serves the ground station (the tlog has every frame's ATTITUDE and
    SERVO_OUTPUT_RAW anyway) and 10 Hz of sim time is still hundreds of messages per wall second."""
    if cfg.telemetry_rate is not None:
        return cfg.telemetry_rate
    return 10.0 if cfg.lockstep else 50.0


def _argvs(cfg: LaunchConfig, out: Path, sitl_port: int, gcs_port: int,
           telemetry: dict[str, list[str]] | None = None) -> dict[str, list[str]]:
    py = [sys.executable, "-u", "-m"]
    pwm = ["--rudder-max-deg", repr(max(cfg.rudder_max_deg, cfg.u_limit_deg))]
    sitl = py + ["sitl", "--listen", f"127.0.0.1:{sitl_port}", "--rate", repr(cfg.rate),
                 "--physics-rate", repr(cfg.physics_rate), "--start-time", repr(cfg.start_time),
                 "--stats-json", str(out / "sitl.json")] + pwm
    ap = py + ["autopilot", "--sitl", f"127.0.0.1:{sitl_port}", "--gcs", f"127.0.0.1:{gcs_port}",
               "--rate", repr(cfg.rate), "--controller", cfg.controller, "--lv", repr(_lv(cfg)),
               "--pfc", cfg.pfc, "--sigma-xu", repr(cfg.sigma_xu), "--name", cfg.name or cfg.controller, "--u-limit-deg", repr(cfg.u_limit_deg),
               "--duration", repr(cfg.duration), "--telemetry-rate", repr(_telemetry_rate(cfg)),
               "--tlog", str(out / "flight.tlog"), "--stats-json", str(out / "autopilot.json")] + pwm
    # Lockstep: the GCS schedules the profile up to the end; real time: it flies until the autopilot powers off.
    gcs = py + ["tools.gcs", "--listen", f"127.0.0.1:{gcs_port}", "--duration", repr(cfg.duration if cfg.lockstep else 0),
                "--amplitude", repr(cfg.amplitude), "--period", repr(cfg.period), "--stats-json", str(out / "gcs.json"),
                "--start-time", repr(cfg.start_time)]
    gcs += ["--csv", cfg.csv] if cfg.csv else [cfg.profile]
    if cfg.series:
        ap += ["--series", str(out / "autopilot_series.npz")]
        sitl += ["--series", str(out / "sitl_series.npz")]
    if cfg.lockstep:
        sitl += ["--lockstep", "--duration", repr(cfg.duration)]
        ap += ["--lockstep", "--lockstep-idle-exit", "5"]
        gcs += ["--lockstep"]
    else:
        sitl += ["--sensor-rate", repr(cfg.sensor_rate)]
        if cfg.rt_priority:
            ap += ["--rt-priority", str(cfg.rt_priority)]
            sitl += ["--rt-priority", str(max(1, cfg.rt_priority - 1))]
        if cfg.busy_wait:
            ap += ["--busy-wait"]
    if cfg.pin and (os.cpu_count() or 1) >= 2:
        # The autopilot gets CPU 1 to itself; the SITL and the GCS share CPU 0 (a GCS woken on the autopilot's
        # CPU preempts it mid-frame: attitude-to-servo latency p99 0.13-0.65 ms -> 0.08-0.12 ms here).
        sitl += ["--cpu", "0"]
        gcs += ["--cpu", "0"]
        ap += ["--cpu", "1"]
    if telemetry:
        for name, argv in (("sitl", sitl), ("autopilot", ap)):
            argv += telemetry[name]
    for name, argv in (("sitl", sitl), ("autopilot", ap), ("gcs", gcs)):
        argv += list(cfg.extra.get(name, []))
    return {"sitl": sitl, "autopilot": ap, "gcs": gcs}


def launch(cfg: LaunchConfig, stop_event: threading.Event | None = None) -> LaunchResult:
    """Run one flight; never raises for a failing child (the result says what failed)."""
    out = Path(cfg.out) if cfg.out else new_run_dir("runs", f"-{'lockstep' if cfg.lockstep else 'rt'}-{cfg.controller}")
    out.mkdir(parents=True, exist_ok=True)
    for f in ("autopilot.json", "sitl.json", "gcs.json"):
        (out / f).unlink(missing_ok=True)
    stop_event = stop_event or threading.Event()
    children: dict[str, Child] = {}
    error = None
    failed = None
    interrupted = False
    t_launch = time.monotonic()
    timeout = cfg.timeout or ((60.0 + cfg.duration * 0.5) if cfg.lockstep else (cfg.duration + 30.0))
    telemetry, parts = _telemetry_argvs(cfg, out)
    try:
        for attempt in range(3):
            if cfg.base_port is not None:
                sitl_port, gcs_port = cfg.base_port, cfg.base_port + 1
            else:
                sitl_port, gcs_port = free_udp_ports(2)
            argvs = _argvs(cfg, out, sitl_port, gcs_port, telemetry)
            # All three start together (the autopilot announces itself until the SITL and the GCS answer).
            children = {
                "sitl": Child("sitl", argvs["sitl"], out / "sitl.log", cfg.echo, "listening on"),
                "gcs": Child("gcs", argvs["gcs"], out / "gcs.log", cfg.echo, "listening on"),
                "autopilot": Child("autopilot", argvs["autopilot"], out / "autopilot.log", cfg.echo),
            }
            retry = False
            for c in (children["sitl"], children["gcs"]):
                while not c.ready.wait(0.05):
                    if stop_event.is_set():
                        raise KeyboardInterrupt
                    if time.monotonic() - c.started > 60:
                        break
                if c.code is not None:
                    if c.code == EXIT_ADDRESS_IN_USE and cfg.base_port is None and attempt < 2:
                        retry = True  # a free port was taken in between: try others
                    else:
                        failed = c.name
                        error = f"{c.name} failed at start-up (exit code {c.code}): {c.reason()}"
            if retry:
                _stop_all(children.values())
                for c in children.values():
                    c.finish()
                continue
            break
        if failed is None:
            ap = children["autopilot"]
            while True:
                if stop_event.is_set():
                    raise KeyboardInterrupt
                code = ap.wait(0.05)
                if code is not None:
                    if code != 0:
                        failed, error = "autopilot", f"autopilot failed (exit code {code}): {ap.reason()}"
                    break
                for c in (children["sitl"], children["gcs"]):
                    if c.code not in (None, 0):
                        failed, error = c.name, f"{c.name} failed (exit code {c.code}): {c.reason()}"
                        break
                if failed:
                    break
                if time.monotonic() - t_launch > timeout:
                    failed, error = "launch", f"flight did not finish within {timeout:.0f} s (wall clock)"
                    break
            if not failed:
                # Normal end: the GCS sees the autopilot power off; the SITL ends by itself in lockstep.
                if not cfg.lockstep:
                    children["sitl"].interrupt()
                for name in ("gcs", "sitl"):
                    c = children[name]
                    code = c.wait(5.0)
                    if code is None:
                        c.interrupt()
                        code = c.wait(5.0)
                    if code not in (None, 0):
                        failed, error = name, f"{name} failed (exit code {code}): {c.reason()}"
    except KeyboardInterrupt:
        interrupted = True
        error = "interrupted (Ctrl-C)"
    finally:
        _stop_all(children.values())
        for c in children.values():
            c.finish()
    rrd_path, rrd_error = _merge_telemetry(parts, out)
    if rrd_error and not failed and not interrupted:
        failed, error = "telemetry", rrd_error
    exit_code = 130 if interrupted else (1 if failed else 0)
    summary = _summary(cfg, out, children, failed, error, exit_code, time.monotonic() - t_launch, rrd_path)
    return LaunchResult(exit_code == 0, exit_code, error, out, summary)


def _telemetry_argvs(cfg: LaunchConfig, out: Path) -> tuple[dict[str, list[str]] | None, dict[str, Path]]:
    """One recording id for the flight; each process writes its own part file (merged at the end)."""
    if not (cfg.rrd or cfg.viewer or cfg.connect):
        return None, {}
    from autopilot.shared import telemetry as tm

    rid = tm.new_recording_id()
    parts = tm.part_paths(out) if cfg.rrd else {}
    for p in parts.values():
        p.parent.mkdir(parents=True, exist_ok=True)
        p.unlink(missing_ok=True)
    url = cfg.connect or (tm.spawn_viewer() if cfg.viewer else None)  # one viewer for both processes
    if url:  # the processes send data only; the layout that joins them comes from here
        from tools.views import flight_blueprint

        tm.send_blueprint(url, flight_blueprint(), rid)
    argv = {}
    for name in ("autopilot", "sitl"):
        argv[name] = ["--recording-id", rid]
        if name in parts:
            argv[name] += ["--rrd", str(parts[name])]
        if url:
            argv[name] += ["--connect", url]
    return argv, parts


def _merge_telemetry(parts: dict[str, Path], out: Path) -> tuple[Path | None, str | None]:
    """Merge the processes' part files into DIR/flight.rrd (whatever ended the flight); (path, error)."""
    existing = [p for p in parts.values() if p.exists() and p.stat().st_size > 0]
    if not existing:
        return None, ("no telemetry was written" if parts else None)
    from autopilot.shared import telemetry as tm
    from tools.views import flight_blueprint

    target = out / "flight.rrd"
    try:
        tm.merge_recordings(existing, target, blueprint=flight_blueprint(), remove_parts=True)
    except Exception as exc:  # noqa: BLE001  (a flight's other files stay valid; say what went wrong)
        return None, f"merging telemetry into {target} failed: {exc}"
    try:
        (out / ".parts").rmdir()
    except OSError:
        pass
    return target, None


def _stop_all(children):
    children = [c for c in children if c.code is None]
    for c in children:
        c.interrupt()
    deadline = time.monotonic() + 5.0
    for c in children:
        if c.wait(deadline - time.monotonic()) is None:
            c.kill()


def _load(path: Path):
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, ValueError):
        return None


def _summary(cfg, out: Path, children, failed, error, exit_code, wall, rrd_path=None) -> dict:
    ap = _load(out / "autopilot.json")
    sitl = _load(out / "sitl.json")
    gcs = _load(out / "gcs.json")
    runs = []
    if ap and ap.get("metric_samples"):
        runs.append({"name": ap["name"], "Lv": ap["Lv"], "metrics": ap["metrics"], "steps": ap["steps"]})
    summary = {
        "scenario": _scenario_name(cfg),
        "runs": runs,
        "transport": "mavlink",
        "mode": "lockstep" if cfg.lockstep else "realtime",
        "controller": cfg.controller,
        "Lv": _lv(cfg),
        "pfc": cfg.pfc,
        "sigma_xu": cfg.sigma_xu,
        "duration_s": cfg.duration,
        "rate_hz": cfg.rate,
        "physics_rate_hz": cfg.physics_rate,
        "start_time_s": cfg.start_time,
        "profile": {"kind": "csv" if cfg.csv else cfg.profile, "amplitude_deg": cfg.amplitude, "period_s": cfg.period,
                    "csv": cfg.csv},
        "ok": exit_code == 0,
        "exit_code": exit_code,
        "failed": failed,
        "error": error,
        "exit_codes": {n: c.code for n, c in children.items()},
        "wall_s": wall,
        "rtf": sitl.get("rtf") if sitl else None,
        "sim_time_s": sitl.get("sim_time_s") if sitl else None,
        "timing": ap.get("timing") if ap else None,
        "events": {"autopilot": ap.get("events") if ap else None, "sitl": sitl.get("events") if sitl else None},
        "counters": {
            "autopilot": ap.get("links") if ap else None,
            "sitl": sitl.get("link") if sitl else None,
            "gcs": gcs.get("link") if gcs else None,
        },
        "files": {
            "tlog": str(out / "flight.tlog"),
            "rrd": str(rrd_path) if rrd_path else None,
            "summary": str(out / "summary.json"),
            "logs": {n: str(out / f"{n}.log") for n in PROCESSES},
            "stats": {n: str(out / f"{n}.json") for n in PROCESSES},
        },
    }
    tmp = out / "summary.json.tmp"
    with open(tmp, "w") as f:
        json.dump(summary, f, indent=1)
    os.replace(tmp, out / "summary.json")
    return summary


def print_summary(res: LaunchResult) -> None:
    s = res.summary
    print()
    print(f"== {s['mode']} flight, {s['controller']} (Lv={s['Lv']:g}), {s['rate_hz']:g} Hz, "
          f"{s['duration_s']:g} s: {'OK' if s['ok'] else 'FAILED: ' + str(s['error'])}")
    if s["runs"]:
        m = s["runs"][0]["metrics"]
        print(f"   {'metric':<12}{'value':>14}")
        for k, v in m.items():
            print(f"   {k:<12}{v:>14.6g}")
        print(f"   {'steps':<12}{s['runs'][0]['steps']:>14d}")
    if s["rtf"] and s["mode"] == "lockstep":
        print(f"   real-time factor {s['rtf']:.1f}x (sim {s['sim_time_s']:.2f} s)")
    t = s.get("timing") or {}

    def fmt(d):
        return "-" if not d else f"p50 {d['p50']:.3f}  p99 {d['p99']:.3f}  max {d['max']:.3f} ms"

    if t:
        if s["mode"] == "realtime":
            print(f"   period jitter     {fmt(t.get('period_jitter_ms'))}; missed deadlines {t.get('missed_deadlines')}")
            print(f"   compute           {fmt(t.get('compute_ms'))} (deadline to servo sent)")
            # Not the in-to-out latency: the newest ATTITUDE waits up to a sensor period for the next deadline.
            print(f"   attitude age      {fmt(t.get('latency_ms'))} (ATTITUDE read to servo sent)")
        else:
            print(f"   in-to-out latency {fmt(t.get('latency_ms'))}")
    c = s["counters"]
    for name in PROCESSES:
        links = c.get(name)
        if not links:
            continue
        if "rx_packets" in links:
            links = {"link": links}
        for lname, l in links.items():
            rej = ", ".join(f"{k}={v}" for k, v in l["rejected"].items()) or "none"
            print(f"   {name + ' ' + lname:<16} rx {l['rx_packets']:>7}  tx {l['tx_packets']:>7}  rejected: {rej}")
    ev = (s["events"] or {}).get("autopilot") or {}
    ev = {k: v for k, v in ev.items() if v not in (0, [], None)}
    if ev:
        print(f"   autopilot events: {ev}")
    f = s["files"]
    rrd = f"  {f['rrd']}" if f.get("rrd") else ""
    print(f"   files: {f['tlog']}{rrd}  {f['summary']}  logs: {Path(f['logs']['autopilot']).parent}/*.log")
    if f.get("rrd"):
        print(f"   open the flight in the Rerun viewer: rerun {f['rrd']}")


def run_lockstep(scenario, run, workdir):
    """Fly one RunSpec of a Scenario in lockstep over real processes and UDP; metrics from what flew.

    Files go to ``workdir`` (one folder per run).  Returns a ``tools.scenario.RunResult`` whose series
    have the keys of ``tools.scenario.SERIES``, recorded by the autopilot (controller side, ``u`` = the
    command that flew, after PWM) and the SITL (``v``, ``p``, ``r``, ``delta_r`` at each frame's time)."""
    from tools.scenario import RunResult

    cfg = LaunchConfig(
        lockstep=True, duration=scenario.duration_s, controller="sac" if run.lv == 0 else "clsac", lv=run.lv,
        pfc=run.pfc or "paper", sigma_xu=run.sigma_xu or 0.0,
        name=run.name, rate=scenario.control_rate_hz, physics_rate=scenario.physics_rate_hz, profile="square",
        amplitude=math.degrees(scenario.amplitude_rad), period=scenario.period_s,
        u_limit_deg=math.degrees(scenario.u_limit_rad), out=str(Path(workdir)), echo=False, series=True,
        rrd=False,  # the experiment logs every run side by side in paper.rrd from the series
    )
    res = launch(cfg)
    if not res.ok or not res.summary["runs"]:
        raise RuntimeError(f"mavlink run {run.name} failed: {res.error} (see {res.out_dir})")
    return RunResult(run.name, run.lv, res.summary["runs"][0]["metrics"], load_series(res.out_dir))


def load_series(out_dir) -> dict:
    """Merge DIR/autopilot_series.npz and DIR/sitl_series.npz into tools.scenario.SERIES-style arrays."""
    import numpy as np

    out_dir = Path(out_dir)
    series: dict = {}
    try:
        with np.load(out_dir / "autopilot_series.npz") as a:
            series = {k: a[k] for k in a.files}
    except OSError:
        return {}
    if series.get("t") is not None and len(series["t"]):
        series["t"] = series["t"] - series["t"][0]
    try:
        with np.load(out_dir / "sitl_series.npz") as s:
            n = len(series.get("t", ()))
            for key, src in (("v", "v"), ("delta_r", "delta_r")):
                # SITL rows are the state after frame k, i.e. at t_{k+1}; the state at t_0 is the initial zero.
                col = np.concatenate([[0.0], s[src]])[:n]
                if len(col) == n:
                    series[key] = col
    except OSError:
        pass
    return series


def build_parser():
    from autopilot.shared.cli import finite_float, nonneg_float, OneLineArgumentParser, positive_float, rate_hz, rt_priority_arg

    p = OneLineArgumentParser(prog="python -m tools.launch", description=__doc__.split("\n\n")[0])
    p.add_argument("--lockstep", action="store_true", help="SITL as time master, as fast as possible (default: real time)")
    p.add_argument("--duration", type=positive_float, default=30.0, metavar="S", help="flight length in sim seconds (default 30)")
    p.add_argument("--controller", choices=("sac", "clsac"), default="clsac", help="default clsac")
    p.add_argument("--lv", type=nonneg_float, default=None, help="override Lv (default: 0 for sac, 20 for clsac)")
    p.add_argument("--pfc", choices=("paper", "robust"), default="paper",
                   help="parallel feedforward compensator: paper = 10/(4s+40) (default), robust = 10/(s+10)")
    p.add_argument("--sigma-xu", type=nonneg_float, default=0.0, metavar="SIGMA",
                   help="sigma-modification of K_Ix, K_Iu (default 0, the paper; 0.1 keeps long flights bounded)")
    p.add_argument("--rate", type=rate_hz, default=100.0, metavar="HZ", help="control rate (default 100)")
    p.add_argument("--physics-rate", type=positive_float, default=None, metavar="HZ",
                   help="default: the smallest whole multiple of --rate >= 1000 Hz (1000 at 100 Hz, 1200 at 400 Hz)")
    p.add_argument("--sensor-rate", type=positive_float, default=200.0, metavar="HZ", help="real time ATTITUDE rate (default 200)")
    p.add_argument("--telemetry-rate", type=nonneg_float, default=None, metavar="HZ",
                   help="GCS stream rate (default 50 Hz in real time, 10 Hz of sim time in lockstep)")
    p.add_argument("--out", default=None, metavar="DIR", help="output folder (default: a new runs/<timestamp>-... folder)")
    p.add_argument("--base-port", type=int, default=None, metavar="PORT",
                   help="SITL on PORT, GCS on PORT+1 (default: free ports chosen automatically)")
    p.add_argument("--start-time", type=nonneg_float, default=0.0, metavar="S", help="initial sim clock (default 0)")
    p.add_argument("profile", nargs="?", choices=("square", "step", "sine"), default="square", help="GCS roll profile")
    p.add_argument("--csv", default=None, metavar="FILE", help="GCS profile from a CSV file (time s, roll deg)")
    p.add_argument("--amplitude", type=finite_float, default=10.0, metavar="DEG", help="profile amplitude (default 10)")
    p.add_argument("--period", type=positive_float, default=10.0, metavar="S", help="profile period (default 10)")
    p.add_argument("--u-limit-deg", type=positive_float, default=30.0, help="rudder command limit (default 30)")
    p.add_argument("--timeout", type=positive_float, default=None, metavar="S", help="wall-clock limit of the whole flight")
    p.add_argument("--rt-priority", type=rt_priority_arg, default=0, metavar="N",
                   help="real time: run the autopilot under SCHED_FIFO priority N (SITL N-1); default 0 = normal")
    p.add_argument("--pin", action="store_true", help="give the autopilot CPU 1 to itself; the SITL and the GCS script share CPU 0")
    p.add_argument("--busy-wait", action="store_true",
                   help="real time: the autopilot never sleeps between steps (one CPU at 100 %%; best with --pin; "
                        "on a VM it avoids the hypervisor's wake-up delays, see README)")
    p.add_argument("--quiet", action="store_true", help="do not echo the processes' output (it is still in DIR/*.log)")
    g = p.add_argument_group("telemetry (Rerun)")
    g.add_argument("--viewer", action="store_true", help="show the flight live: spawn a Rerun viewer (or reuse one on port 9876)")
    g.add_argument("--connect", metavar="URL", default=None,
                   help="show the flight live in a running Rerun viewer, e.g. rerun+http://127.0.0.1:9876/proxy")
    g.add_argument("--no-rrd", dest="rrd", action="store_false", help="do not write DIR/flight.rrd")
    return p


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.busy_wait and args.lockstep:
        parser.error("--busy-wait is for real time (lockstep already polls before sleeping)")
    if args.busy_wait and args.rt_priority:
        from autopilot.shared.process import rt_throttling

        if rt_throttling():
            parser.error(f"--busy-wait with --rt-priority: a SCHED_FIFO thread that never sleeps is stopped by the "
                         f"kernel's real-time throttling ({rt_throttling()}); use one or the other")
    if args.base_port is not None and not 1 <= args.base_port <= 65534:
        parser.error(f"--base-port must be in 1..65534, got {args.base_port}")
    if args.csv and not os.path.isfile(args.csv):
        parser.error(f"--csv: no such file {args.csv!r}")
    from autopilot.shared.cli import default_physics_rate

    if args.physics_rate is None:
        args.physics_rate = default_physics_rate(args.rate)
    ratio = args.physics_rate / args.rate
    if abs(ratio - round(ratio)) > 1e-9:
        parser.error(f"--physics-rate ({args.physics_rate:g}) must be a whole multiple of --rate ({args.rate:g})")
    cfg = LaunchConfig(
        lockstep=args.lockstep, duration=args.duration, controller=args.controller, lv=args.lv, rate=args.rate,
        pfc=args.pfc, sigma_xu=args.sigma_xu,
        physics_rate=args.physics_rate, sensor_rate=args.sensor_rate, telemetry_rate=args.telemetry_rate,
        out=args.out, base_port=args.base_port, start_time=args.start_time, profile=args.profile,
        amplitude=args.amplitude, period=args.period, csv=args.csv, u_limit_deg=args.u_limit_deg,
        echo=not args.quiet, timeout=args.timeout, pin=args.pin, rrd=args.rrd, viewer=args.viewer, connect=args.connect,
        rt_priority=args.rt_priority, busy_wait=args.busy_wait,
    )
    stop = threading.Event()

    def on_signal(signum, frame):
        stop.set()

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    res = launch(cfg, stop)
    print_summary(res)
    if not res.ok:
        print(f"launch: error: {res.error} (logs in {res.out_dir})", file=sys.stderr)
    return res.exit_code


if __name__ == "__main__":
    sys.exit(main())
