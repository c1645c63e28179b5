"""The simulated plant behind a MAVLink endpoint (transport and timing only; physics in the plant, ``sitl.plant``).

Real time (:meth:`Sitl.run_realtime`): physics follows the wall clock at the physics rate (on each
wake-up the aircraft advances by the whole physics steps elapsed, servo command held: exact ZOH),
ATTITUDE goes out at the sensor rate, the newest valid SERVO_OUTPUT_RAW is held.  A servo message
whose time_usec is not newer than the last applied one (wrap-aware) is stale and ignored.  If the
autopilot is silent for ``servo_timeout_s`` the rudder goes to neutral and the SITL says so.

Lockstep (:meth:`Sitl.run_lockstep`), the SITL is the time master: frame k has sim time
t_k = K/rate (global frame K = K0 + k, K0 = start_time * rate).  Send ATTITUDE(time_boot_ms = t_k in
ms); wait for SERVO_OUTPUT_RAW with time_usec == t_k in us mod 2**32; anything else is counted
(stale / unexpected) and ignored; resend the same ATTITUDE (signed again: not a replay) every
``resend_timeout_s``; give up after ``give_up_s`` with a clear error; then advance one control period.  After the
last frame the end-of-run frame (t0 + duration) is sent a few times so the autopilot knows the run is over.

Hook point: ``Sitl.hooks`` callables get a :class:`SitlRecord` after each frame (lockstep) or each
ATTITUDE sent (real time).
"""

from __future__ import annotations

import gc
import math
import select
import sys
import time
from collections import Counter, deque
from dataclasses import dataclass

from autopilot.shared.events import StatusEvents
from autopilot.shared.fastmav import HOT_DECODERS
from autopilot.shared.link import UdpLink
from autopilot.shared.mavlink import frame_ms, frame_usec, mavlink, usec_diff, vehicle_ids
from autopilot.shared.numerics import wrap_pi
from autopilot.shared.process import EXIT_OUT_OF_ENVELOPE
from autopilot.shared.pwm import PWM_VALID_RANGE, PwmMap
from autopilot.shared.series import SeriesRecorder
from autopilot.shared.signing import SIGNING_LINK_SIM, Signing
from sitl import plant as plants
from sitl.fault_injection import FaultInjection

M = mavlink
ATTITUDE = M.MAVLINK_MSG_ID_ATTITUDE
COMMAND_LONG = M.MAVLINK_MSG_ID_COMMAND_LONG
HEARTBEAT = M.MAVLINK_MSG_ID_HEARTBEAT
SERVO_OUTPUT_RAW = M.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW


SERVO_AHEAD_US = 50_000  # real time: a servo stamp this far ahead of the clock of the one held is rejected


class LockstepGiveUp(RuntimeError):
    """The autopilot did not answer a lockstep frame within the give-up time."""


class PlantDiverged(RuntimeError):
    """The plant's state left what the SITL flies (``sitl.plant.divergence``): the flight is stopped, out of the
    envelope (``Sitl.diverged`` says when and why)."""


@dataclass
class SitlOptions:
    listen: tuple = ("127.0.0.1", 14560)
    lockstep: bool = False
    rate_hz: float = 100.0  # lockstep frame rate (= the autopilot's control rate)
    physics_rate_hz: float = 1000.0
    sensor_rate_hz: float = 200.0  # real time ATTITUDE rate
    duration_s: float = 0.0  # 0 = until stopped
    start_time_s: float = 0.0
    servo_timeout_s: float = 0.5
    resend_timeout_s: float = 0.25
    give_up_s: float = 10.0
    spin_s: float = 0.0  # lockstep: busy-poll this long for the servo answer before sleeping in select
    connect_timeout_s: float = 0.0  # lockstep: wait this long for the autopilot (0 = forever)
    disturbances: object = None  # sitl.disturbances.Disturbances (air, sensors, link faults, plant); None = ideal
    verbose: bool = True
    signing_key: bytes | None = None  # MAVLink 2 signing (autopilot.shared.signing); None = off
    peer: tuple | None = None  # the autopilot's (host, port); None = the first that talks with its IDs
    sysid: int = 1  # the vehicle's system id (--sysid): the SITL is N:200, the autopilot's SITL link N:140
    plant: str = plants.KH2013A  # sitl.plant: kh2013a, FILE.toml or jsbsim:MODEL[:KEY=VALUE,...]
    faults: tuple = ()  # sitl.damage.Fault, scheduled (--fault); a ground station's come while flying


class SitlRecord:
    """After a frame / sensor message: sim time (s), truth state x (6, a copy), applied rudder command (rad),
    the PWM it came from, the global frame index (lockstep) or None, and the Sitl object."""

    __slots__ = ("t_sim", "x", "u", "pwm", "frame", "sitl")

    def __init__(self, t_sim, x, u, pwm, frame, sitl):
        self.t_sim, self.x, self.u, self.pwm, self.frame, self.sitl = t_sim, x, u, pwm, frame, sitl


# The SITL's per-frame series (``--series``): the truth state after each frame and the command applied.
SERIES_KEYS = ("t", "v", "p", "r", "phi", "delta_r", "delta_r_dot", "u")


def _series_row(rec: SitlRecord) -> tuple:
    x = rec.x
    return (rec.t_sim, x[0], x[1], x[2], x[3], x[4], x[5], rec.u)


def series_recorder(mimo: bool = False) -> SeriesRecorder:
    """A SITL hook recording (t, v, p, r, phi, delta_r, delta_r_dot, u) per frame / sensor message; ``mimo``: and
    ``u2``, the second surface's command applied (rad)."""
    if mimo:
        return SeriesRecorder((*SERIES_KEYS, "u2"), lambda rec: (*_series_row(rec), rec.sitl.u2))
    return SeriesRecorder(SERIES_KEYS, _series_row)


class Sitl:
    def __init__(self, opts: SitlOptions, pwm: PwmMap, out=None, pwm2: PwmMap | None = None):
        """``pwm2``: a square MIMO plant's second surface (its own SERVO_OUTPUT_RAW channel, ``--channel2``)."""
        self.opts = opts
        self.pwm = pwm
        self.pwm2 = pwm2
        self.out = out or sys.stdout
        self.inj = None  # sitl.disturbances.Injector when opts.disturbances is given
        params = None
        dist = plants.injected(opts.plant, opts.disturbances)  # JSBSim flies its own atmosphere
        if dist is not None:
            from sitl.disturbances import Injector

            rate = opts.rate_hz if opts.lockstep else opts.sensor_rate_hz
            self.inj = Injector(dist, 1.0 / opts.physics_rate_hz, rate, opts.lockstep, opts.start_time_s)
            params = self.inj.params()
        damaged = plants.needs_damaged_model(opts.faults)
        self.aircraft = plants.build(opts.plant, opts.physics_rate_hz, params, opts.disturbances, damaged)
        self._euler = plants.spec(opts.plant).euler  # ATTITUDE carries the plant's own pitch, yaw and q
        self.mimo = bool(getattr(self.aircraft, "mimo", False))
        if self.mimo != (pwm2 is not None):
            raise plants.PlantError(
                f"--plant {opts.plant}: "
                + (
                    "a square MIMO plant needs --channel2 (its second surface's channel)"
                    if self.mimo
                    else "--channel2 is for a square MIMO plant (jsbsim:MODEL:surface=aileron+rudder)"
                )
            )
        self._advance_plant = self.aircraft.advance if self.inj is None else self._advance_disturbed
        self._rt_faults = self.inj is not None and not opts.lockstep and self.inj.up is not None
        _, autopilot_id, sitl_id = vehicle_ids(opts.sysid)
        self.link = UdpLink(
            "autopilot",
            sitl_id,
            opts.listen,
            opts.peer,  # the autopilot's address when given (--autopilot), else learned from its first packet
            peers=[autopilot_id],
            msgids=[SERVO_OUTPUT_RAW, HEARTBEAT, COMMAND_LONG],
            learn_remote=opts.peer is None,
            signing=Signing(opts.signing_key, SIGNING_LINK_SIM) if opts.signing_key else None,
        )
        self.hooks: list = []
        self.events = Counter()
        self.say = StatusEvents("sitl", self.link, self.events, verbose=opts.verbose, out=self.out)
        self.event_hooks = self.say.hooks  # callables(severity, text), for each status event
        self.stop_requested = False
        self.u = 0.0  # applied rudder command (rad)
        self.pwm_applied = pwm.neutral
        self.frames = 0
        self.wall_first_frame = None
        self.wall_last_frame = None
        self.sim_t0 = 0.0
        self.exit_reason = ""
        self.peer_lost = None  # the peer whose silence ended the run ("autopilot"), for the launcher's verdict
        self.diverged = None  # the plant diverged: {"t_s", "reason", "plant", "mono"} (``_check_plant``)
        # real time: sim time flown on the servo timeout (rudder neutral, no command from the autopilot), in the
        # episodes that ended (the autopilot came back) and in the one still on when the run ended
        self.servo_timeout_s = 0.0
        self.servo_timeout_open_s = 0.0
        self.first_servo_sim_s = None  # real time: sim time when the first servo command was applied ...
        self.last_servo_sim_s = None  # ... and the last one
        self._servos: list = []  # servo commands received (PWM checked), not yet consumed: (time_usec, pwm, t_rx)
        self._servo_field = f"servo{pwm.channel}_raw"
        self._servo_index = HOT_DECODERS[SERVO_OUTPUT_RAW].index(self._servo_field)
        # MIMO: the second surface's pulse of each servo message, by its time_usec, taken with the first's frame
        self._servo2_field = f"servo{pwm2.channel}_raw" if pwm2 else None
        self._servo2_index = HOT_DECODERS[SERVO_OUTPUT_RAW].index(self._servo2_field) if pwm2 else None
        self._pwm2_by_usec: dict = {}
        self.pwm2_applied = pwm2.neutral if pwm2 else None
        self.u2 = 0.0
        self._side_hist = None  # MIMO with disturbances: the sideslip's sensor delay line (_measure_sideslip)
        if pwm2:
            from autopilot.shared.fastmav import AOA_SSA

            self._pk_aoa = self.link.fast_packer(AOA_SSA)
        self.link.on_hot(SERVO_OUTPUT_RAW, self._on_servo)  # the usual servo datagram, without a message object
        self._fds = [self.link.sock]  # select(2): microsecond timeouts (epoll rounds up to milliseconds)
        self._pk_att = self.link.fast_packer(M.MAVLink_attitude_message)
        self._wall0 = None  # real time: the wall clock of physics step 0
        # The faults (sitl.damage): scheduled, and a ground station's; self._advance flies them (fault_injection)
        self.faulting = FaultInjection(self, opts.faults)
        self._advance = self.faulting.advance
        self._psi = self._psi_t = self._psi_r = 0.0  # heading, the time and yaw rate it was integrated to

    def _heading(self, r: float | None = None) -> float:
        """Heading psi (rad, wrapped to (-pi, pi]) for ATTITUDE.yaw: psi' = r (level turn, pitch 0), integrated with
        the trapezoid rule between ATTITUDE messages.  Not a state of the lateral model (docs/spec.md, "Units").
        ``r``: the yaw rate now, if the caller has it (else read from the truth state)."""
        t = self.aircraft.time
        r = float(self.aircraft.truth[2]) if r is None else r
        if t > self._psi_t:
            self._psi = wrap_pi(self._psi + 0.5 * (r + self._psi_r) * (t - self._psi_t))
        self._psi_t, self._psi_r = t, r
        return self._psi

    # ------------------------------------------------------------------ util
    def _heartbeat(self):
        self.link.send(
            M.MAVLink_heartbeat_message(M.MAV_TYPE_GENERIC, M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE, 3)
        )

    def _on_msg(self, msg, t_rx):
        mid = msg.get_msgId()
        if mid == SERVO_OUTPUT_RAW:
            if self._servo2_field:
                self._pwm2_by_usec[msg.time_usec] = getattr(msg, self._servo2_field)
            self._take_servo(t_rx, msg.time_usec, getattr(msg, self._servo_field))
        elif mid == COMMAND_LONG:
            self.faulting.command(msg, t_rx)

    def _on_servo(self, t_rx, values):
        """SERVO_OUTPUT_RAW from the link's hot path: the payload in wire order (the rudder at ``_servo_index``)."""
        if self._servo2_index is not None:
            self._pwm2_by_usec[values[0]] = values[self._servo2_index]
        self._take_servo(t_rx, values[0], values[self._servo_index])

    def _apply_second(self, usec: int) -> None:
        """MIMO: the second surface flies the pulse that came with the first's servo message ``usec`` (the last one
        applied if it had none or an invalid one); older ones are dropped."""
        held = self._pwm2_by_usec
        pwm2 = None if usec is None else held.pop(usec, None)  # None: the message was lost (link faults): hold
        if usec is not None and len(held) > 64:  # those before it were lost or overtaken: never flown
            for old in [t for t in held if usec_diff(t, usec) < 0]:
                del held[old]
        if len(held) > 4096:
            held.clear()
        if pwm2 is not None and PWM_VALID_RANGE[0] <= pwm2 <= PWM_VALID_RANGE[1]:
            self.pwm2_applied = pwm2
        self.u2 = self.aircraft.u2 = self.pwm2.to_rad(self.pwm2_applied)

    def _send_sideslip(self, ms: int) -> None:
        """MIMO: AOA_SSA (ArduPilot's, deg) with the plant's angle of attack and sideslip, just before ATTITUDE."""
        alpha, beta = self.aircraft.sideslip()
        raw = self.link.pack_fast(self._pk_aoa, ms * 1000, math.degrees(alpha), math.degrees(beta))
        self.link.send_raw(raw, self._pk_aoa.msgid)

    def _take_servo(self, t_rx, usec: int, pwm: int):
        """A servo command from the autopilot: a PWM out of range is rejected (``bad_pwm``, while the link is
        handling the packet), the others wait in ``_servos`` (or, with real-time link faults, in the injector)."""
        if not PWM_VALID_RANGE[0] <= pwm <= PWM_VALID_RANGE[1]:
            self.link.reject("bad_pwm")
            return
        item = (usec, pwm, t_rx)
        if self._rt_faults:  # real-time link faults: the channel takes it; what it delivers now is taken now
            # (with no delay, this very message; with one, those that came due), the rest later by _deliver
            for d_usec, d_pwm, _t in self.inj.downlink(t_rx, item):
                self._servos.append((d_usec, d_pwm, t_rx))
            return
        self._servos.append(item)

    def _advance_disturbed(self, u: float, n: int):
        return self.inj.advance(self.aircraft, u, n)

    def _deliver(self, now: float) -> None:
        """Real-time link faults: send the ATTITUDE datagrams and take the servo messages that are due."""
        for raw in self.inj.uplink_raw(now, None):
            self.link.send_raw(raw, ATTITUDE)
        for usec, pwm, _t_rx in self.inj.downlink(now):
            self._servos.append((usec, pwm, now))

    def _measure_sideslip(self) -> tuple[float, float]:
        """MIMO with ``self.inj``: (alpha, beta) as the sensor reports them: the attitude's sensor delay (whole
        samples, ``sitl.sensors``) on both; the roll's bias and noise are the roll sensor's, not the sideslip's."""
        hist = self._side_hist
        if hist is None:
            d = self.inj.sensors.cfg.delay if self.inj.sensors is not None else 0
            hist = self._side_hist = deque(maxlen=d + 1)
        hist.append(self.aircraft.sideslip())
        return hist[0]  # D samples old once full, the first sample before (as sitl.sensors.Sensors)

    def _send_attitude_disturbed(self, ms: int, k: int | None) -> bytes:
        """ATTITUDE with the sensor errors and the link faults of ``self.inj`` (see sitl.disturbances.Injector);
        a MIMO plant's AOA_SSA goes with it, through the same link faults (lockstep: the same sample held or
        delivered; real time: one datagram, AOA_SSA then ATTITUDE, delayed, lost or duplicated whole)."""
        inj = self.inj
        phi, p, r = inj.measure(self.aircraft.truth)
        phi = wrap_pi(phi)
        theta, psi, q = self._pitch_yaw_q()
        side = self._measure_sideslip() if self.mimo else None
        if k is not None:  # lockstep: this frame carries the newest sample delivered, once per datagram arriving
            if side is None:
                (phi, p, r), n = inj.uplink_frame(k, (phi, p, r))
            else:
                (phi, p, r, side), n = inj.uplink_frame(k, (phi, p, r, side))
                aoa = self.link.pack_fast(self._pk_aoa, ms * 1000, math.degrees(side[0]), math.degrees(side[1]))
                self.link.send_raw(aoa, self._pk_aoa.msgid)
            raw = self.link.pack_fast(self._pk_att, ms, phi, theta, psi, p, q, r)
            for _ in range(max(1, n)):
                self.link.send_raw(raw, ATTITUDE)
            return raw
        aoa = b""  # packed first: the signatures' timestamps increase along the datagram (else ATTITUDE is a replay)
        if side is not None:
            aoa = self.link.pack_fast(self._pk_aoa, ms * 1000, math.degrees(side[0]), math.degrees(side[1]))
        raw = self.link.pack_fast(self._pk_att, ms, phi, theta, psi, p, q, r)
        out_raw = aoa + raw
        for out in inj.uplink_raw(time.perf_counter(), out_raw):
            self.link.send_raw(out, ATTITUDE)
        return raw

    def _send_attitude(self, ms: int, k: int | None = None) -> bytes:
        """ATTITUDE from the truth state: roll, pitch, yaw, rollspeed, pitchspeed, yawspeed (float32 on the wire).

        ``k``: the global frame index in lockstep (for the link faults)."""
        if self.inj is not None:  # the sensor errors and link faults (a MIMO plant's AOA_SSA with them)
            return self._send_attitude_disturbed(ms, k)
        if self.mimo:  # the sideslip as JSBSim has it, just before ATTITUDE
            self._send_sideslip(ms)
        if self._euler:
            phi, theta, psi, p, q, r = self.aircraft.attitude()
            raw = self.link.pack_fast(self._pk_att, ms, phi, theta, psi, p, q, r)
            self.link.send_raw(raw, ATTITUDE)
            return raw
        x = self.aircraft.truth.tolist()  # the float64 values as Python floats, exactly (float(x[i]) each)
        # roll wrapped to (-pi, pi] where it is measured, as a real attitude sensor reports it
        raw = self.link.pack_fast(self._pk_att, ms, wrap_pi(x[3]), 0.0, self._heading(x[2]), x[1], 0.0, x[2])
        self.link.send_raw(raw, ATTITUDE)
        return raw

    def _servo_waiting(self) -> bool:
        """Read what waits in the socket: a servo command there (this process was stopped or starved, not the
        autopilot) is applied on the next pass instead of a servo timeout."""
        self.link.poll(self._on_msg)
        return bool(self._servos) or (self._rt_faults and self.inj.down.next_due() < float("inf"))

    def _pitch_yaw_q(self) -> tuple[float, float, float]:
        """(pitch, yaw, pitch rate) for ATTITUDE: the plant's own (JSBSim), else 0, the integrated heading, 0."""
        if self._euler:
            _phi, theta, psi, _p, q, _r = self.aircraft.attitude()
            return theta, psi, q
        return 0.0, self._heading(), 0.0

    def _wait(self, timeout: float):
        if select.select(self._fds, (), (), max(0.0, timeout))[0]:
            self.link.poll(self._on_msg)

    # -------------------------------------------------------------- lockstep
    def run_lockstep(self) -> int:
        opts = self.opts
        rate = opts.rate_hz
        ratio = opts.physics_rate_hz / rate
        nphys = int(round(ratio))
        k0 = int(round(opts.start_time_s * rate))
        self.sim_t0 = k0 / rate
        n_frames = int(round(opts.duration_s * rate)) if opts.duration_s > 0 else 0
        link = self.link
        perf = time.perf_counter
        # Wait for the autopilot to announce itself (HEARTBEAT at start-up, every 50 ms until its peers answer).
        t_start = perf()
        next_hb = t_start
        while not link.rx_accepted and not self.stop_requested:
            now = perf()
            if opts.connect_timeout_s and now - t_start > opts.connect_timeout_s:
                self.exit_reason = f"no autopilot after {opts.connect_timeout_s:g} s"
                self.peer_lost = "autopilot"
                raise LockstepGiveUp(
                    f"no autopilot talked to {link.local[0]}:{link.local[1]} within {opts.connect_timeout_s:g} s"
                )
            self._wait(0.05)
        if self.stop_requested:
            self.exit_reason = "stopped by signal"
            return 0
        if opts.verbose:
            print(
                f"sitl: autopilot at {link.remote[0]}:{link.remote[1]}; lockstep from t={self.sim_t0:.3f} s",
                file=self.out,
                flush=True,
            )
        advance = self._advance
        inj = self.inj
        ev = self.events
        resend = opts.resend_timeout_s
        give_up = opts.give_up_s
        spin = opts.spin_s
        K = k0
        hooks = self.hooks
        # The last frame's (sim time, command, PWM, frame): its SitlRecord is made and handed to the hooks once the
        # next ATTITUDE is out (the state is the one that ATTITUDE was measured from), while the autopilot computes.
        rec = None
        poll = select.poll()
        poll.register(link.sock, select.POLLIN)
        poll = poll.poll  # the busy poll: one poll(2) per turn (an empty recvfrom costs twice that, and raises)
        self.wall_first_frame = perf()
        while not self.stop_requested:
            if n_frames and self.frames >= n_frames:
                # End-of-run frame: tells the autopilot the run is over (sent a few times, nobody answers).
                raw = self._send_attitude(frame_ms(K, rate), K)
                self._run_hooks(rec)
                rec = None
                for _ in range(2):
                    self._wait(0.01)
                    link.resend(raw, ATTITUDE)
                self.exit_reason = "end of run (duration reached)"
                break
            raw = self._send_attitude(frame_ms(K, rate), K)
            t_sent = perf()
            if rec is not None:
                # Off the critical path: the autopilot is computing this frame's answer meanwhile.
                self._run_hooks(rec)
                rec = None
            expected = frame_usec(K, rate)
            t_resend = t_sent + resend
            t_give_up = t_sent + give_up
            pwm = None
            servos = self._servos
            while pwm is None and not self.stop_requested:
                if not servos:
                    now = perf()
                    if now >= t_give_up:
                        self.exit_reason = f"autopilot did not answer frame t={K / rate:.3f} s"
                        self.peer_lost = "autopilot"
                        raise LockstepGiveUp(
                            f"no SERVO_OUTPUT_RAW for frame t={K / rate:.3f} s (time_usec {expected}) after "
                            f"{give_up:g} s, resent {ev['resends_frame']} times: is the autopilot running with "
                            f"--lockstep --rate {rate:g} (and a GCS, or --no-pace)?"
                        )
                    if now >= t_resend:
                        link.resend(raw, ATTITUDE)
                        ev["resends"] += 1
                        ev["resends_frame"] += 1
                        t_resend = now + resend
                    if now >= next_hb:
                        next_hb = now + 1.0
                        self._heartbeat()
                    if spin > 0:
                        t_end = now + spin
                        while not servos and perf() < t_end:
                            if poll(0):
                                link.poll(self._on_msg, most=1)  # the answer first; anything more on the next turn
                        if servos:
                            continue
                        now = perf()
                    self._wait(min(t_resend, t_give_up, next_hb) - now)
                    continue
                usec, got, _t_rx = servos.pop(0)
                if usec != expected:
                    d = usec_diff(usec, expected)
                    ev["stale_servo" if d < 0 else "unexpected_servo"] += 1
                    continue
                pwm = got  # its PWM was checked on arrival (_take_servo)
            if pwm is None:  # stopped by a signal while waiting for the answer
                break
            ev["resends_frame"] = 0
            usec2 = expected  # MIMO: the servo message whose second pulse the rudder flies
            if inj is not None:  # link faults: the newest command delivered by this frame, else hold
                if self.mimo:  # the message, both pulses: the rudder's is delivered or held with the aileron's
                    delivered = inj.downlink_frame(K, (pwm, expected))
                    pwm, usec2 = (self.pwm_applied, None) if delivered is None else delivered
                else:
                    delivered = inj.downlink_frame(K, pwm)
                    pwm = self.pwm_applied if delivered is None else delivered
            self.pwm_applied = pwm
            self.u = u = self.pwm.to_rad(pwm)
            if self.mimo:
                self._apply_second(usec2)
            advance(u, nphys)
            self._check_plant()
            K += 1
            self.frames += 1
            self.wall_last_frame = perf()
            if hooks:
                rec = (K / rate, u, pwm, K)
            now = self.wall_last_frame
            if now >= next_hb:
                next_hb = now + 1.0
                self._heartbeat()
        self._run_hooks(rec)  # stopped between a frame and the next ATTITUDE: its record is not lost
        if self.stop_requested:
            self.exit_reason = self.exit_reason or "stopped by signal"
        return 0

    def _run_hooks(self, rec) -> None:
        """The hooks on the frame ``rec`` = (sim time, command, PWM, frame) (None: nothing to hand), with the state
        the aircraft is in now (that frame's: nothing stepped it since)."""
        if rec is not None:
            t, u, pwm, k = rec
            r = SitlRecord(t, self.aircraft.truth.copy(), u, pwm, k, self)
            for h in self.hooks:
                h(r)

    # ------------------------------------------------------------- real time
    def run_realtime(self) -> int:
        opts = self.opts
        ac = self.aircraft
        ev = self.events
        perf = time.perf_counter
        phys_rate = opts.physics_rate_hz
        sensor_period = 1.0 / opts.sensor_rate_hz
        self.sim_t0 = opts.start_time_s
        self._wall0 = t0 = perf()  # physics step k is due at wall time t0 + k / physics rate
        next_sensor = t0
        next_hb = t0
        last_usec = None
        last_servo_wall = None
        timed_out = False
        timeout_from = 0  # physics step at which the current servo timeout began
        self.wall_first_frame = t0
        n_frames = int(round(opts.duration_s * opts.sensor_rate_hz)) if opts.duration_s > 0 else 0

        def catch_up(now):
            n = int((now - t0) * phys_rate) - ac.steps
            if n > 0:
                self._advance(self.u, n)
                self._check_plant()

        while not self.stop_requested:
            now = perf()
            rem = (min(next_sensor, self.inj.next_due()) if self._rt_faults else next_sensor) - now
            if rem > 0:
                self._wait(min(rem, 0.05))
            if self._rt_faults:
                self._deliver(perf())
            servos = self._servos
            while servos:
                usec, pwm, t_rx = servos.pop(0)
                d = None if last_usec is None or timed_out else usec_diff(usec, last_usec)
                if d is not None and d <= 0:
                    ev["stale_servo"] += 1
                elif d is not None and d > (t_rx - last_servo_wall) * 1e6 + SERVO_AHEAD_US:
                    ev["future_servo"] += 1  # ahead of the autopilot's clock as we hold it: never "newest"
                else:  # its PWM was checked on arrival (_take_servo)
                    catch_up(t_rx)  # the old command held up to the moment the new one arrived
                    if timed_out:
                        self.servo_timeout_s += (ac.steps - timeout_from) / phys_rate
                    if last_usec is None:
                        self.first_servo_sim_s = ac.steps / phys_rate  # as sim_time_s: from the start
                    self.last_servo_sim_s = ac.steps / phys_rate
                    last_usec = usec
                    last_servo_wall = t_rx
                    self.pwm_applied = pwm
                    self.u = self.pwm.to_rad(pwm)
                    if self.mimo:
                        self._apply_second(usec)
                    ev["servo_applied"] += 1
                    if timed_out:
                        timed_out = False
                        self.say(M.MAV_SEVERITY_NOTICE, "autopilot back: servo commands applied again")
            now = perf()
            if now < next_sensor:
                continue
            catch_up(now)
            self._send_attitude(int((self.sim_t0 + ac.steps / phys_rate) * 1000.0) & 0xFFFFFFFF)
            self.frames += 1
            self.wall_last_frame = now
            next_sensor += sensor_period
            if next_sensor < now:  # fell behind by more than a sensor period: skip, stay on the grid
                skipped = int((now - next_sensor) / sensor_period) + 1
                ev["sensor_slots_skipped"] += skipped
                next_sensor += skipped * sensor_period
            if (
                last_servo_wall is not None
                and not timed_out
                and now - last_servo_wall > opts.servo_timeout_s
                and not self._servo_waiting()
            ):
                timed_out = True
                catch_up(now)
                timeout_from = ac.steps
                self.u = 0.0
                self.pwm_applied = self.pwm.neutral
                if self.mimo:
                    self.u2 = self.aircraft.u2 = 0.0
                    self.pwm2_applied = self.pwm2.neutral
                ev["servo_timeouts"] += 1
                self.say(M.MAV_SEVERITY_WARNING, f"autopilot silent {now - last_servo_wall:.2f} s: rudder neutral")
            if now >= next_hb:
                next_hb = now + 1.0
                self._heartbeat()
            if self.hooks:
                t_rec = self.sim_t0 + ac.steps / phys_rate
                rec = SitlRecord(t_rec, ac.truth.copy(), self.u, self.pwm_applied, None, self)
                for h in self.hooks:
                    h(rec)
            if n_frames and self.frames >= n_frames:
                self.exit_reason = "end of run (duration reached)"
                break
        if timed_out:
            self.servo_timeout_open_s = (ac.steps - timeout_from) / phys_rate
        if self.stop_requested:
            self.exit_reason = self.exit_reason or "stopped by signal"
        return 0

    def _check_plant(self) -> None:
        """Stop the flight (``PlantDiverged``) once the plant has diverged: an unstable plant is flown until its
        state is no longer finite or leaves ``sitl.plant.STATE_LIMIT``."""
        why = plants.divergence(self.aircraft.truth)
        if why is None:
            return
        t = self.aircraft.time  # flight time: physics steps since the start
        self.diverged = {"t_s": t, "reason": why, "plant": self.opts.plant, "mono": time.monotonic()}
        self.exit_reason = f"the plant diverged at {t:.3f} s of flight: {why}"
        raise PlantDiverged(self.exit_reason)

    def run(self) -> int:
        gc.collect()
        gc.freeze()  # the long-lived heap (numpy, scipy) stays out of the cyclic collector's full passes
        try:
            return self.run_lockstep() if self.opts.lockstep else self.run_realtime()
        except PlantDiverged:  # the frame (or the catch-up) that diverged is not flown: no ATTITUDE could carry it
            return EXIT_OUT_OF_ENVELOPE
        finally:
            self.link.send_clock.end(time.monotonic())

    def stats(self) -> dict:
        wall = (
            (self.wall_last_frame - self.wall_first_frame) if (self.wall_first_frame and self.wall_last_frame) else 0.0
        )
        if self.opts.lockstep:
            sim = self.frames / self.opts.rate_hz
        else:
            sim = self.aircraft.time
        return {
            "mode": "lockstep" if self.opts.lockstep else "realtime",
            "frames": self.frames,
            "sim_t0": self.sim_t0,
            "sim_time_s": sim,
            "wall_s": wall,
            "rtf": (sim / wall) if wall > 0 else None,
            "physics_steps": self.aircraft.steps,
            "final_state": [float(v) for v in self.aircraft.truth],
            "plant": self.opts.plant,
            "events": {k: v for k, v in self.events.items() if k != "resends_frame"},
            "link": self.link.counters(),
            "exit_reason": self.exit_reason,
            "peer_lost": self.peer_lost,
            "diverged": self.diverged,  # the plant diverged: when (flight time), why, which plant
            # real time: sim s flown on the servo timeout (rudder neutral), ended episodes and the one open at the end
            "servo_timeout_s": self.servo_timeout_s,
            "servo_timeout_open_s": self.servo_timeout_open_s,
            "servo_timeout_s_limit": self.opts.servo_timeout_s,
            "first_servo_sim_s": self.first_servo_sim_s,
            "last_servo_sim_s": self.last_servo_sim_s,
            "sent": self.link.send_clock.summary(),  # monotonic clock of its sends (the verdict's evidence)
            "faults": self.faulting.records(),  # sitl.damage: each fault, its source and whether it started
            **({"disturbances": self.inj.stats()} if self.inj is not None else {}),
        }

    def close(self):
        self.link.close()
