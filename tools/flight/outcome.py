"""The verdict on a flight, from what flew and how each process ended: the fraction flown (``flown_report``),
who stalled first (``silences``, ``first_stall``), the completion verdict and the process to blame (``verdict``),
then the envelope (``envelope_verdict``) and the outcome's name (``outcome_of``).  No I/O."""

from __future__ import annotations

from autopilot.shared.process import (
    EXIT_FAILED,
    EXIT_OK,
    EXIT_OUT_OF_ENVELOPE,
)
from tools.flight.config import PROCESSES, FlightConfig


def _ended_normally(ap: dict | None) -> bool:
    """The autopilot's own stats say its run reached the end (not stopped, not a peer's silence)."""
    return bool(ap) and str(ap.get("exit_reason", "")).startswith("end of run")


def _sitl_flown_steps(cfg: FlightConfig, sitl: dict) -> int:
    """Control steps the aircraft flew under the autopilot's commands, from the SITL's own counters (the flight of
    an autopilot that left no stats): lockstep, its frames (each one waits for an answer); real time, the control
    periods of sim time from the first servo command it applied to the last, less the time it flew on its servo
    timeout in between (whatever it flew after the last command, nobody was behind it)."""
    if cfg.lockstep:
        return int(sitl.get("frames") or 0)
    first, last = sitl.get("first_servo_sim_s"), sitl.get("last_servo_sim_s")
    if first is None or last is None:
        return 0
    commanded = last - first - (sitl.get("servo_timeout_s") or 0.0)
    return max(0, int(commanded * cfg.rate + 1e-6) + 1)  # the last command's own period included


def flown_report(cfg: FlightConfig, stats: dict) -> dict:
    """What flew against what was asked: control steps, SITL frames and sim time; ``fraction`` = steps flown /
    steps asked.

    Lockstep: the autopilot's steps (each one a SITL frame answered).  Real time: the steps asked less every control
    period lost (docs/spec.md, "summary.json"): a step flown as a hold for want of attitude, a step that came more
    than the attitude timeout after its deadline or after the step before, and each control period of sim time the
    SITL flew on its servo timeout (rudder neutral, no command: ``servo_timeout_s``, plus the episode still on at
    the end unless the autopilot ended its run itself).  Without the autopilot's stats (it was killed) the steps
    come from what the SITL flew (``_sitl_flown_steps``)."""
    ap, sitl = stats["autopilot"], stats["sitl"]
    asked = round(cfg.duration * cfg.rate)
    lost = {"hold_steps": 0, "late_steps": 0, "servo_timeout_s": 0.0, "no_command_applied": False}
    if ap:
        source = "autopilot"
        steps = ap["steps"]
        if not cfg.lockstep:
            lost["hold_steps"] = ap.get("hold_steps", 0)
            lost["late_steps"] = ap.get("late_steps", 0)
            if sitl:
                lost["servo_timeout_s"] = sitl.get("servo_timeout_s", 0.0) + (
                    0.0 if _ended_normally(ap) else sitl.get("servo_timeout_open_s", 0.0)
                )
                if "first_servo_sim_s" in sitl and sitl["first_servo_sim_s"] is None and ap["steps"]:
                    # The SITL applied none of the autopilot's commands: it flew the whole flight with the rudder
                    # at neutral, and its servo timeout, which starts from a command applied, never started.
                    lost["no_command_applied"] = True
            timeout_steps = int(round(lost["servo_timeout_s"] * cfg.rate))
            lost_steps = lost["hold_steps"] + lost["late_steps"] + timeout_steps
            steps = (
                max(0, min(steps, asked) - lost_steps) if ap["metric_samples"] and not lost["no_command_applied"] else 0
            )
    elif sitl:
        source = "sitl"
        steps = min(_sitl_flown_steps(cfg, sitl), asked)
    else:
        source, steps = None, 0
    return {
        "steps": steps,
        "steps_asked": asked,
        "fraction": steps / asked if asked else 0.0,
        "frames": sitl.get("frames") if sitl else None,
        "sim_time_s": steps / cfg.rate,
        "duration_s": cfg.duration,
        "lost": lost,  # real time: what was not flown (steps, and sim s on the SITL's servo timeout)
        "source": source,  # whose counters the steps come from: the autopilot's, or the SITL's if it left none
        # lockstep: the SITL flew exactly the frames asked as well
        "complete": steps >= asked and (not cfg.lockstep or (sitl or {}).get("frames") == asked),
    }


GCS_END_SLACK_S = 0.5  # the ground station sees the vehicle's clock a telemetry period late (0.1 s in lockstep)


# A process that sent nothing for this long had stopped: each one sends at least a 1 Hz HEARTBEAT while it runs.
STALL_S = 2.0


# Which process's receive clocks hear which peer: (listener, where its stats keep that link's counters).
HEARD_BY = {
    "autopilot": (("sitl", ("link",)), ("gcs", ("link",))),
    "sitl": (("autopilot", ("links", "sitl")),),
    "gcs": (("autopilot", ("links", "gcs")),),
}


def _reached_end(name: str, st: dict | None, duration: float) -> bool:
    """Whether a child that ended says it ended at the end of the run: its exit reason is "end of run" and, for
    the ground-station script, the vehicle clock it saw reached the duration (a forged POWEROFF heartbeat also
    reads "end of run (vehicle powered off)", but in the middle of the profile)."""
    st = st or {}
    if not str(st.get("exit_reason", "")).startswith("end of run"):
        return False
    if name == "gcs":  # how far along its profile the vehicle's clock was
        if st.get("sim_ms") is None or st.get("origin_ms") is None:
            return False
        return (st["sim_ms"] - st["origin_ms"]) / 1000.0 >= duration - GCS_END_SLACK_S
    return True


def _ended_by_others(name: str, stats: dict, children: dict, duration: float) -> bool:
    """Whether a child that ended with status 0 ended because the run did: at its end (``_reached_end``), or, for the
    ground-station script, on the POWEROFF of an autopilot that itself failed (a non-zero exit status)."""
    if _reached_end(name, stats.get(name), duration):
        return True
    powered_off = str((stats.get(name) or {}).get("exit_reason", "")) == "end of run (vehicle powered off)"
    return name == "gcs" and powered_off and children["autopilot"].code not in (None, 0)


def _last_heard(name: str, stats: dict) -> tuple[float | None, list[str]]:
    """When a peer last accepted a packet from process ``name`` (monotonic), and which peers heard it."""
    times = []
    for listener, path in HEARD_BY[name]:
        c = stats.get(listener) or {}
        for key in path:
            c = c.get(key) or {}
        if c.get("last_rx_mono") is not None:
            times.append((c["last_rx_mono"], listener))
    return (max(times)[0], [n for _, n in times]) if times else (None, [])


def silences(children: dict, stats: dict, t_end: float) -> dict[str, tuple[float, float, str]]:
    """Each process's longest time without sending anything, begun before the flight ended: (from, seconds,
    evidence), on the machine's monotonic clock.  From the process's own send clock (its stats' ``sent``: the
    longest gap between two sends, or from its last send to the end of its run loop); for a process that left no
    stats (killed while stopped, SIGKILL), from its peers' receive clocks: from the last packet one of them
    accepted from it to its exit (or the end of the flight)."""
    out = {}
    for name in PROCESSES:
        st = stats.get(name)
        sent = (st or {}).get("sent")
        if sent:
            if sent.get("longest_gap_from_mono") is not None:
                out[name] = (sent["longest_gap_from_mono"], sent["longest_gap_s"], f"{name}'s own send clock")
            continue
        heard, by = _last_heard(name, stats)
        if heard is None:
            continue
        c = children.get(name)
        until = c.exited_at if c is not None and c.exited_at is not None else t_end
        out[name] = (heard, min(until, t_end) - heard, f"the receive clock of {' and '.join(by)}")
    return {n: s for n, s in out.items() if s[0] < t_end}


def first_stall(children: dict, stats: dict, t_end: float) -> tuple[str, float, float, str] | None:
    """The process that stopped sending first (name, from, seconds, evidence): of the silences longer than
    ``STALL_S``, the one that began first; None if no process went silent that long."""
    long = [(s[0], n, s[1], s[2]) for n, s in silences(children, stats, t_end).items() if s[1] >= STALL_S]
    if not long:
        return None
    t_from, name, seconds, evidence = min(long)
    return name, t_from, seconds, evidence


def _steps(n: int) -> str:
    return f"{n} step" if n == 1 else f"{n} steps"


def _stall_reason(children: dict, stall: tuple) -> str:
    name, t_from, seconds, evidence = stall
    t0 = min(c.started for c in children.values())
    return f"{name} stalled: sent nothing for {seconds:.1f} s from {t_from - t0:.1f} s after start ({evidence})"


def shortfall(flown: dict, stats: dict, rate: float, machine: dict | None = None) -> tuple[str, str]:
    """(process, reason) of a flight the autopilot flew to its end with steps lost.  The steps flown late and the
    time the SITL flew without a command are the autopilot's loss; the steps flown as a hold for want of attitude,
    the SITL's (its attitude did not arrive within the attitude timeout).  The owner of the larger loss, in control
    periods, is named (the autopilot on a tie); the reason lists every loss.  A SITL that applied none of the
    autopilot's commands (real time, ``lost["no_command_applied"]``) is named if they reached it, else the
    autopilot."""
    ap = stats.get("autopilot") or {}
    lost = flown["lost"]
    tmo = ap.get("attitude_timeout_s")
    autopilot_loss = lost["late_steps"] + round(lost["servo_timeout_s"] * rate)
    name = "sitl" if lost["hold_steps"] > autopilot_loss else "autopilot"
    parts = []
    if lost.get("no_command_applied"):
        # None applied: the SITL's fault if the commands reached it, else they never left the autopilot's side
        got = ((stats.get("sitl") or {}).get("link") or {}).get("rx_by_type", {}).get("SERVO_OUTPUT_RAW", 0)
        name = "sitl" if got else "autopilot"
        parts.append(
            f"the SITL applied none of the {got} servo commands it received (rudder neutral all flight)"
            if got
            else "no servo command reached the SITL (rudder neutral all flight)"
        )
    if lost["late_steps"]:
        parts.append(
            f"{_steps(lost['late_steps'])} flown later than the attitude timeout ({tmo:g} s) "
            f"(the latest {ap.get('max_lateness_s', 0.0):.3g} s late)"
        )
    if lost["servo_timeout_s"]:
        parts.append(f"the SITL flew {lost['servo_timeout_s']:.3g} s on its servo timeout (rudder neutral, no command)")
    if lost["hold_steps"]:
        parts.append(f"{_steps(lost['hold_steps'])} flown as a hold without attitude (none fresher than {tmo:g} s)")
    if not parts:
        parts.append(f"{flown['steps_asked'] - flown['steps']} of {flown['steps_asked']} steps not flown")
    return name, f"{name}: " + "; ".join(parts) + realtime_advice(lost, machine)


BUSY_SHARE = 0.8  # a machine whose CPUs were this busy while a real-time flight flew starved it


STARVED = "a real-time process starved of CPU"  # realtime_advice's finding, which the tests look for


def realtime_advice(lost: dict, machine: dict | None) -> str:
    """What a real-time flight that lost steps (late, held, on the servo timeout) adds to its reason: what to do, and
    how busy the machine was when it was busy (``machine``: ``tools.flight.children.machine_load``)."""
    if not (lost.get("late_steps") or lost.get("hold_steps") or lost.get("servo_timeout_s")):
        return ""
    load = ""
    if machine and (machine["busy"] >= BUSY_SHARE or (machine["load1"] or 0.0) > machine["cpus"]):
        avg = "" if machine["load1"] is None else f", load average {machine['load1']:.1f}"
        load = f" (the machine's {machine['cpus']} CPUs were {100 * machine['busy']:.0f} % busy{avg})"
    return (
        f"; {STARVED}{load}: fly --lockstep (no deadlines), or --pin --busy-wait (the "
        "autopilot alone on a CPU), or on a quieter machine"
    )


def verdict(
    children: dict, stats: dict, flown: dict, exit_code: int, failed, error, t_end: float, machine: dict | None = None
) -> tuple[int, str | None, str | None]:
    """(exit code, process that failed first, reason) of a flight from what flew and how each process ended.

    OK only if every step asked was flown (lockstep: and the SITL flew as many frames), every process exited with
    status 0 and wrote its stats.  Otherwise the culprit comes from evidence, in this order:

    1. if the autopilot flew its run to the end, no other process ended early or failed, but steps were lost (real
       time: late, holds, servo timeout), the owner of the larger loss (``shortfall``; a stall is noted);
    2. the process that stopped sending first (``first_stall``: a silence of ``STALL_S`` or more on its own send
       clock, or on its peers' receive clocks if it left no stats), whoever noticed it;
    3. the process that exited first (a child that ends early with status 0 included; one that ended with status 0
       at the end of the run, or the GCS script on the POWEROFF of an autopilot that failed, not), or, when it ended
       because a peer went silent (its stats' ``peer_lost``), that peer.

    The reason is one line with the numbers, plus the fraction flown; a real-time flight that lost steps also says
    what to do and, when it was high, the machine's CPU load (``machine``: ``tools.flight.children.machine_load``).
    """
    complete = flown["complete"]
    ap_exit = children["autopilot"].exited_at
    ap_exit = t_end if ap_exit is None else min(ap_exit, t_end)
    early = [  # a child that ended before the autopilot did, other than by reaching the end of the run itself
        c
        for n, c in children.items()
        if n != "autopilot"
        and c.exited_at is not None
        and c.exited_at < ap_exit
        and not _reached_end(n, stats.get(n), flown["duration_s"])
    ]
    clean = all(c.code == 0 for c in children.values()) and all(stats.values()) and not early
    pct = 100.0 * flown["fraction"]
    tail = (
        f"; flown {pct:.3g} % ({flown['steps']} of {flown['steps_asked']} steps, "
        f"{flown['sim_time_s']:g} of {flown['duration_s']:g} s)"
    )
    if complete and clean:
        return (EXIT_OK, None, None) if exit_code == EXIT_OK else (exit_code, failed, f"{error}{tail}")
    # exits seen while the flight ran (not those of stopping it), in order
    order = sorted(
        (c for c in children.values() if c.exited_at is not None and c.exited_at < t_end), key=lambda c: c.exited_at
    )
    if not order and failed is not None and failed not in children:  # the launcher itself ended it (wall clock)
        return exit_code, failed, f"{error}{tail}"
    stall = first_stall(children, stats, t_end)
    stalled = None if stall is None else _stall_reason(children, stall)
    ended_early = early or any(c.code not in (None, 0) for c in order)
    if not complete and _ended_normally(stats.get("autopilot")) and not ended_early:
        # every process flew to the end: what failed the flight is the steps lost (a stall, if any, is noted)
        name, why = shortfall(flown, stats, flown["steps_asked"] / flown["duration_s"], machine)
        return EXIT_FAILED, name, "; ".join([why, *([stalled] if stalled else [])]) + tail
    if stall is not None:
        name = stall[0]
        reports = [
            f"{n} reports: {st['exit_reason']}"
            for n, st in stats.items()
            if n != name and st and st.get("peer_lost") and st.get("exit_reason")
        ]
        return EXIT_FAILED, name, "; ".join([stalled, *reports]) + tail
    # a child that ended with status 0 at the end of the run, or (the GCS script) on the POWEROFF of an autopilot that
    # then failed, did not end the flight, however early it was reaped (on a busy machine the failing autopilot exits
    # after the script that saw it power off: a full disk, an internal error)
    ends = [c for c in order if not (c.code == 0 and _ended_by_others(c.name, stats, children, flown["duration_s"]))]
    first = ends[0] if ends else children.get(failed) or children["autopilot"]
    name = first.name
    seen = {name}
    while (peer := (stats.get(name) or {}).get("peer_lost")) and peer in children and peer not in seen:
        blamer, name = name, peer  # it ended because this peer went silent: blame the peer
        seen.add(name)
    culprit = children[name]
    own = (stats.get(name) or {}).get("exit_reason")
    if name != first.name:
        why = f"{name} stalled or died: {blamer} reports: {(stats.get(blamer) or {}).get('exit_reason')}"
    elif culprit.code not in (None, 0):
        why = f"{name} failed (exit code {culprit.code}): {culprit.reason()}"
    elif culprit.code == 0:
        why = f"{name} exited early (exit code 0): {own or culprit.reason()}"
        st = stats.get(name) or {}
        if st.get("sim_ms") is not None and st.get("origin_ms") is not None:
            why += f" after {(st['sim_ms'] - st['origin_ms']) / 1000.0:g} s of its profile"
    elif error:
        why = error
    else:
        missing = [n for n, st in stats.items() if not st]
        why = f"{name}: {own or culprit.reason()}" + (f" (no stats from {', '.join(missing)})" if missing else "")
    return EXIT_FAILED, name, why + tail


def diverged_verdict(children: dict, stats: dict, flown: dict, t_end: float) -> tuple[int, None, str] | None:
    """The SITL stopped the flight because its plant diverged (its stats' ``diverged``, its exit status 3): OUT OF
    ENVELOPE (exit 3) with the plant, the flight time and the state that left the bound, not a failure of the SITL.
    None (``verdict`` decides) if another process failed, or one stalled, before the plant diverged."""
    div = (stats.get("sitl") or {}).get("diverged")
    if not div or children["sitl"].code != EXIT_OUT_OF_ENVELOPE:
        return None
    before = [
        c
        for n, c in children.items()
        if n != "sitl" and c.exited_at is not None and c.exited_at < div["mono"] and c.code not in (None, 0)
    ]
    stall = first_stall(children, stats, t_end)
    if before or (stall is not None and stall[1] < div["mono"]):
        return None
    pct = 100.0 * flown["fraction"]
    tail = (
        f"; flown {pct:.3g} % ({flown['steps']} of {flown['steps_asked']} steps, "
        f"{flown['sim_time_s']:g} of {flown['duration_s']:g} s)"
    )
    why = f"the plant {div['plant']} diverged at {div['t_s']:.3f} s of flight: {div['reason']}"
    why += "; the SITL stopped the flight"
    return EXIT_OUT_OF_ENVELOPE, None, f"out of envelope: {why}{tail}"


def outcome_of(exit_code: int) -> str:
    """The launcher's last line for an exit status: OK (0), OUT OF ENVELOPE (3) or FAILED (anything else)."""
    return {EXIT_OK: "OK", EXIT_OUT_OF_ENVELOPE: "OUT OF ENVELOPE"}.get(exit_code, "FAILED")


def envelope_verdict(
    exit_code: int, failed: str | None, error: str | None, controlled: dict | None
) -> tuple[int, str | None, str | None]:
    """A completed flight (``exit_code`` 0 from ``verdict``) that left the envelope is OUT OF ENVELOPE (exit 3) with
    the autopilot's reason; one without the autopilot's verdict fails.  Any other outcome stays as it is."""
    if exit_code != EXIT_OK:
        return exit_code, failed, error
    if controlled is None:
        return EXIT_FAILED, "autopilot", "autopilot: its stats have no envelope verdict (controlled)"
    if not controlled["ok"]:
        return EXIT_OUT_OF_ENVELOPE, None, f"out of envelope: {controlled['reason']}"
    return exit_code, failed, error


def fault_recoveries(faults: list | None, t, roll, ref, um=None) -> list[dict]:
    """Per fault that started (``summary.json`` ``faults``: kind, value, start, end, source), the recovery of the
    roll after its onset (``autopilot.recovery.recovery``: its deviation from the commanded response ``ref``, the
    law's y_m,ol, back inside the command's band, staying there and following the command), judged up to the next
    fault's onset.  ``t``, ``roll``, ``ref``, ``um`` (the raw command: only settled seconds are judged): the
    autopilot's series (sim s, rad) of the steps it flew; None
    (no series): each fault "not measured".  No I/O."""
    from autopilot.recovery import recovery

    started = [f for f in faults or [] if f.get("started", True) and f.get("start") is not None]
    onsets = sorted(float(f["start"]) for f in started)
    out = []
    for f in started:
        onset = float(f["start"])
        later = [s for s in onsets if s > onset + 1e-9]
        entry = {k: f.get(k) for k in ("kind", "value", "start", "end", "source", "spec")}
        if t is None or not len(t):
            entry.update(recovered=None, time_s=None, reason="not measured: no series (--no-series)")
        else:
            until = later[0] if later else None
            entry.update(recovery(t, roll, ref, onset, until_s=until, raw_command=um).to_dict())
        out.append(entry)
    return out


def recovery_text(entry: dict) -> str:
    """One fault's recovery for the verdict line: ``effectiveness 0.3 at 10 s: recovered in 2.0 s``."""
    if entry.get("spec"):  # as the user wrote it (deg, deg/s, s): the value is SI
        head = f"{entry['spec'].split('@')[0].replace('=', ' ')} at {entry.get('start'):g} s"
    else:
        value = "" if entry.get("value") is None else f" {entry['value']:g}"
        head = f"{entry.get('kind')}{value} at {entry.get('start'):g} s"
    if entry.get("recovered"):
        return f"{head}: recovered in {entry['time_s']:.2f} s (band {entry['band_deg']:.1f} deg)"
    if entry.get("recovered") is False:  # the words never say "recovered" (autopilot.recovery's reasons neither)
        why = "; back in it, but not shown following the command" if "not shown" in (entry.get("reason") or "") else ""
        return f"{head}: no recovery (band {entry['band_deg']:.1f} deg{why})"
    return f"{head}: recovery {entry.get('reason')}"
