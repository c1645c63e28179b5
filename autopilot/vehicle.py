"""The autopilot as a MAVLink vehicle for ground stations (docs/spec.md, "Ground stations").

:class:`Vehicle` answers everything a ground station (MAVProxy, QGroundControl, a pymavlink script) sends on
the autopilot's GCS link and keeps its streams: identity (HEARTBEAT, AUTOPILOT_VERSION, PROTOCOL_VERSION), the
modes (:class:`Mode`; DO_SET_MODE and SET_MODE; the standard-modes messages AVAILABLE_MODES and CURRENT_MODE),
arming, the parameter protocol over :class:`autopilot.params.ParamTable`, TIMESYNC, PING, MISSION_REQUEST_LIST
(MISSION_COUNT 0), the file-transfer protocol (NAK: no files), stream rates (SET_MESSAGE_INTERVAL,
REQUEST_DATA_STREAM), SYS_STATUS at 1 Hz and NAMED_VALUE_FLOAT for the adaptive gains, and failure injection
(MAV_CMD_INJECT_FAILURE, relayed to the SITL: ``autopilot.injection``).  Every COMMAND_LONG and COMMAND_INT gets a
COMMAND_ACK (a relayed one when the SITL has answered); what is not supported gets MAV_RESULT_UNSUPPORTED.

The autopilot (``autopilot.loop.Autopilot``, driven by its scheduler) owns the links and the control step; this
module only decides what to answer and what the step flies (``ControlStep.manual``, ``.armed``, ``.reconfigure``,
``.transfer``).
"""

from __future__ import annotations

import enum
import struct
import time
from types import SimpleNamespace

from autopilot.controllers import law_of
from autopilot.injection import FailureRelay
from autopilot.params import PARAM_ID_LEN, PARAMS, ParamError, ParamTable, decode, encode
from autopilot.shared.mavlink import OTHER_DIALECT_MESSAGES, all_dialect, mavlink
from autopilot.step import Failsafe

M = mavlink

# The standard-modes messages are in pymavlink's ``all`` and ``development`` dialects, not in ``common``.  Their
# wire format is the same MAVLink 2 frame: a common-dialect link packs them with the message's own id and CRC extra.
# CURRENT_MODE, sent every second, is packed by a fast packer on its wire layout (custom_mode, intended_custom_mode
# uint32, standard_mode uint8), so the autopilot does not load the ``all`` dialect (~110 M instructions at its start)
# for it; AVAILABLE_MODES, sent on request, is that dialect's class (``all_dialect``).  tests/autopilot/test_vehicle.py
# holds the packed CURRENT_MODE to pymavlink's bytes.
AVAILABLE_MODES = 435
CURRENT_MODE = 436
MAV_STANDARD_MODE_NON_STANDARD = 0  # the standard mode of every mode of ours (pymavlink's MAV_STANDARD_MODE)
_CURRENT_MODE_MSG = SimpleNamespace(
    id=CURRENT_MODE, crc_extra=OTHER_DIALECT_MESSAGES[CURRENT_MODE][1], unpacker=struct.Struct("<IIB")
)
# PROTOCOL_VERSION (300, minimal.xml) is in none of pymavlink 2.4's generated dialects: version, min_version,
# max_version (uint16), spec_version_hash[8], library_version_hash[8] (uint8), CRC extra 217 (computed from the
# definition with pymavlink's generator algorithm, tests/autopilot/test_vehicle.py).
PROTOCOL_VERSION = 300
_PROTOCOL_VERSION_MSG = SimpleNamespace(id=PROTOCOL_VERSION, crc_extra=217, unpacker=struct.Struct("<HHH8s8s"))


class Mode(enum.IntEnum):
    """The modes, as HEARTBEAT.custom_mode.  MANUAL is 0, which ArduPlane's table (what MAVProxy and pymavlink's
    ``mode_string_v10`` use for a fixed wing) also calls MANUAL; the others are numbers that table does not
    have, so those tools show ``Mode(100)`` etc., never a wrong name; MAVProxy names them all with the module
    ``tools.flight.mavproxy_modes`` loaded.  FAILSAFE is entered and left by itself."""

    MANUAL = 0
    SAC = 100
    CLSAC = 101
    FAILSAFE = 102
    BASELINE = 103  # the fixed-gain baseline law (``--controller baseline``), instead of SAC and CLSAC
    # the adaptive-law bench's laws (autopilot.controllers), each its own mode, and a user's own law (autopilot.law)
    MRAC = 104
    CRM_MRAC = 105
    L1 = 106
    INDI = 107
    LAW = 108


# Stream groups: what SET_MESSAGE_INTERVAL / REQUEST_DATA_STREAM set.  Per-step streams count control steps (sim
# time in lockstep); SYS_STATUS and CURRENT_MODE count wall seconds.
ATTITUDE_GROUP = (M.MAVLINK_MSG_ID_ATTITUDE, M.MAVLINK_MSG_ID_ATTITUDE_TARGET, M.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW)
NAMED_VALUE_FLOAT = M.MAVLINK_MSG_ID_NAMED_VALUE_FLOAT
SYS_STATUS = M.MAVLINK_MSG_ID_SYS_STATUS
GAINS_RATE_HZ = 10.0  # NAMED_VALUE_FLOAT Ke, Kx, Ku, e: a rate a plain ground station graphs
_STREAMS = {  # MAV_DATA_STREAM -> the groups it drives
    M.MAV_DATA_STREAM_ALL: ("attitude", "gains", "status"),
    M.MAV_DATA_STREAM_EXTENDED_STATUS: ("status",),
    M.MAV_DATA_STREAM_RAW_CONTROLLER: ("attitude",),
    M.MAV_DATA_STREAM_RC_CHANNELS: ("attitude",),
    M.MAV_DATA_STREAM_EXTRA1: ("attitude",),
    M.MAV_DATA_STREAM_EXTRA3: ("gains",),
}

# The messages the GCS link takes besides SET_ATTITUDE_TARGET (the loop's) and HEARTBEAT.
MSGIDS = (
    M.MAVLINK_MSG_ID_COMMAND_LONG,
    M.MAVLINK_MSG_ID_COMMAND_INT,
    M.MAVLINK_MSG_ID_SET_MODE,
    M.MAVLINK_MSG_ID_PARAM_REQUEST_LIST,
    M.MAVLINK_MSG_ID_PARAM_REQUEST_READ,
    M.MAVLINK_MSG_ID_PARAM_SET,
    M.MAVLINK_MSG_ID_MISSION_REQUEST_LIST,
    M.MAVLINK_MSG_ID_TIMESYNC,
    M.MAVLINK_MSG_ID_PING,
    M.MAVLINK_MSG_ID_REQUEST_DATA_STREAM,
    M.MAVLINK_MSG_ID_MANUAL_CONTROL,
    M.MAVLINK_MSG_ID_RC_CHANNELS_OVERRIDE,
    M.MAVLINK_MSG_ID_FILE_TRANSFER_PROTOCOL,
)
# Answers to one ground station (its address): at most REPLY_RATE packets per wall second, REPLY_BURST at once (two
# whole parameter lists); a request beyond that is read and counted (``replies_limited``) but not answered, as a
# lossy link would, and MAVLink's request protocols ask again.  A key holder flooding PARAM_REQUEST_LIST (about 26
# PARAM_VALUE to every ground station per request) costs the link at most REPLY_RATE answers a second.
REPLY_RATE = 50.0
REPLY_BURST = 60.0
_FTP_NAK = 129
_FTP_ERR_FILE_NOT_FOUND = 10


def _text(v) -> str:
    return (v.decode("utf-8", "replace") if isinstance(v, (bytes, bytearray)) else str(v)).split("\x00", 1)[0]


class Vehicle:
    """The ground-station side of the autopilot ``ap`` (an ``autopilot.loop.Autopilot``).

    ``params``: the table the law is flown from; ``mode``: the mode at start (SAC or CLSAC); ``armed``.
    ``handle(msg)`` for every accepted GCS message but setpoints; ``heartbeat()``; ``housekeeping(now)`` once a
    loop turn (1 Hz SYS_STATUS, CURRENT_MODE, automatic FAILSAFE); ``on_step(steps, t_ms)`` after each step;
    ``stream(bufs, msgids)`` sends to every ground station.
    """

    def __init__(self, ap, params: ParamTable, mode: Mode = Mode.CLSAC, armed: bool = True):
        law = law_of(ap.control.law)  # its modes: autopilot.controllers.LAWS
        self.selectable = (Mode.MANUAL, *(Mode[m] for m in law.modes))
        self.modes = (*self.selectable, Mode.FAILSAFE)  # what AVAILABLE_MODES lists
        if mode not in self.selectable and mode is not Mode.FAILSAFE and len(law.modes) == 1:
            mode = Mode[law.modes[0]]  # a law of one mode starts in it
        if mode not in self.selectable:
            raise ValueError(f"start mode must be one of {[m.name for m in self.selectable]}, got {mode!r}")
        self.ap = ap
        self.link = ap.gcs
        self.sysid, self.compid = ap.gcs.mav.srcSystem, ap.gcs.mav.srcComponent  # --sysid N: N:1
        self.params = params
        self.selected = mode
        self.mode = mode
        self.control = control = ap.control
        control.armed = armed
        # callables(name, value, accepted): each PARAM_SET for us, after it was applied or refused (telemetry)
        self.param_hooks: list = []
        # each value a ground station changed: sim time (s; None before the first attitude), name, from, to
        self.param_changes: list[dict] = []
        self.params_start = dict(params.items())  # every value as the flight starts (flags, then --params)
        self.every = {"attitude": ap._telemetry_every, "gains": self._every(GAINS_RATE_HZ)}
        self.status_period_s = 1.0
        self._next_status = 0.0
        self._pk_nvf = self.link.fast_packer(M.MAVLink_named_value_float_message)
        self._pk_pv = self.link.fast_packer(_PROTOCOL_VERSION_MSG)
        self._pk_current_mode = self.link.fast_packer(_CURRENT_MODE_MSG)
        self.failures = FailureRelay(ap)  # MAV_CMD_INJECT_FAILURE, relayed to the SITL
        self._reply_tokens: dict = {}  # station address -> (tokens, perf_counter): the answers' budget (REPLY_RATE)
        if mode in (Mode.SAC, Mode.CLSAC):
            control.reconfigure(self._law_config(mode))

    # --------------------------------------------------------------- streams
    def _every(self, hz: float) -> int:
        return max(1, int(round(self.ap.rate / hz))) if hz > 0 else 0

    def stream(self, bufs: list, msgids) -> None:
        """Packed messages, one datagram, to every ground station: each admitted one (the first to talk, those
        of ``--gcs-peer``, any signed one with signing on) and the default port (``UdpLink.broadcast``)."""
        self.link.broadcast(bufs, msgids)

    def send_all(self, msg) -> None:
        """A pymavlink message, or (fast packer, wire values...) (``_current_mode``), to every ground station: an
        admitting link sends to every admitted peer and the default port."""
        if type(msg) is tuple:
            self.link.send_fast(*msg)
        else:
            self.link.send(msg)

    def reply(self, msg) -> bool:
        """An answer to the station whose message is being handled, sent to every ground station (each checks the
        target fields it needs), within that station's budget (REPLY_RATE); whether it went."""
        if not self._answerable():
            return False
        self.send_all(msg)
        return True

    def _answerable(self, cost: float = 1.0) -> bool:
        """Take ``cost`` answers from the budget of the station being handled (``UdpLink.peer_addr``)."""
        addr = self.link.peer_addr
        now = time.perf_counter()
        left, then = self._reply_tokens.get(addr, (REPLY_BURST, now))
        left = min(REPLY_BURST, left + (now - then) * REPLY_RATE)
        if left < cost:
            self._reply_tokens[addr] = (left, now)
            self.ap.events["replies_limited"] += 1
            return False
        self._reply_tokens[addr] = (left - cost, now)
        if len(self._reply_tokens) > 64:  # addresses come and go: keep the latest
            del self._reply_tokens[next(iter(self._reply_tokens))]
        return True

    def on_step(self, steps: int, t_ms: int) -> None:
        """After each control step: NAMED_VALUE_FLOAT Ke, Kx, Ku, e every ``every['gains']`` steps."""
        n = self.every["gains"]
        if n and steps % n == 0 and self.selectable[1] in (Mode.SAC, Mode.CLSAC):  # the adaptive gains of CL-SAC
            law = self.control.law
            g = self.link
            pk = self._pk_nvf
            bufs = [
                g.pack_fast(pk, t_ms, float(v), name)
                for name, v in ((b"Ke", law.ke), (b"Kx", law.kx), (b"Ku", law.ku), (b"e", law.e))
            ]
            self.stream(bufs, (NAMED_VALUE_FLOAT,) * 4)

    def heartbeat(self, status: int) -> "M.MAVLink_heartbeat_message":
        base = M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if self.control.armed:
            base |= M.MAV_MODE_FLAG_SAFETY_ARMED
        if self.mode is Mode.MANUAL:
            base |= M.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
        elif self.mode not in (Mode.FAILSAFE,):
            base |= M.MAV_MODE_FLAG_STABILIZE_ENABLED
        mode = int(self.mode)
        return M.MAVLink_heartbeat_message(M.MAV_TYPE_FIXED_WING, M.MAV_AUTOPILOT_GENERIC, base, mode, status, 3)

    def housekeeping(self, now: float) -> None:
        """Automatic FAILSAFE in and out; SYS_STATUS and CURRENT_MODE at 1 Hz (wall clock); the failure injection in
        flight to the SITL (resent, or answered MAV_RESULT_FAILED)."""
        self.failures.housekeeping(now)
        mode = Mode.FAILSAFE if self.ap.failsafe is not Failsafe.NONE else self.selected
        if mode is not self.mode:
            self.mode = mode
            self._announce(station=False)
        if self.status_period_s > 0 and now >= self._next_status:
            self._next_status = now + self.status_period_s
            self.send_all(self._sys_status())
            self.send_all(self._current_mode())

    # ---------------------------------------------------------------- inputs
    def handle(self, msg) -> None:
        handler = self._handlers.get(msg.get_msgId())
        if handler is not None:
            handler(self, msg)

    def _for_us(self, msg) -> bool:
        ok = msg.target_system in (0, self.sysid) and msg.target_component in (0, self.compid)
        if not ok:
            self.link.reject("wrong_target")
        return ok

    def _on_command(self, msg) -> None:
        if not self._for_us(msg):
            return
        cmd = msg.command
        fn = self._commands.get(cmd)
        result = M.MAV_RESULT_UNSUPPORTED if fn is None else fn(self, msg)
        if fn is None:
            self.ap.events["unsupported_commands"] += 1
        after = None
        if isinstance(result, tuple):
            result, after = result
        if result is None:
            return  # relayed: answered when the SITL has answered (autopilot.injection)
        self.reply(M.MAVLink_command_ack_message(cmd, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()))
        if after is not None:
            after()

    def _on_set_mode(self, msg) -> None:
        if msg.target_system not in (0, self.sysid):
            self.link.reject("wrong_target")
            return
        result = self._set_mode(msg.base_mode, msg.custom_mode)
        self.reply(
            M.MAVLink_command_ack_message(
                M.MAV_CMD_DO_SET_MODE, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()
            )
        )

    def _on_param_request_list(self, msg) -> None:
        if not self._for_us(msg):
            return
        for i, (name, value) in enumerate(self.params.items()):
            self.reply(self._param_value(name, value, i))

    def _on_param_request_read(self, msg) -> None:
        if not self._for_us(msg):
            return
        idx = msg.param_index
        table = self.params.params
        name = _text(msg.param_id) if idx < 0 else (table[idx].name if idx < len(table) else None)
        try:
            if name is None:
                raise ParamError(f"no parameter with index {idx}")
            self.reply(self._param_value(name, self.params.get(name)))
        except ParamError:
            self.ap.events["param_errors"] += 1
            self.reply(self._param_error(msg, name or "", idx, M.MAV_PARAM_ERROR_DOES_NOT_EXIST))

    def _on_param_set(self, msg) -> None:
        if not self._for_us(msg):
            return
        name = _text(msg.param_id)
        value = decode(msg.param_value, msg.param_type)  # an INT32 (SYS_FAILURE_EN) bytewise or cast
        try:
            old = self.params.get(name) if name in self.params else None
            self.params.set(name, value)
        except ParamError as exc:
            self.ap.events["param_rejected"] += 1
            self.ap._event(M.MAV_SEVERITY_WARNING, refusal_text(name, value, exc), kind="refused PARAM_SET")
            for hook in self.param_hooks:
                hook(name, float(value), False)
            if name not in self.params:
                self.reply(self._param_error(msg, name, -1, M.MAV_PARAM_ERROR_DOES_NOT_EXIST))
                return
            read_only = "read-only" in str(exc)
            code = M.MAV_PARAM_ERROR_READ_ONLY if read_only else M.MAV_PARAM_ERROR_VALUE_OUT_OF_RANGE
            if self.reply(self._param_value(name, self.params.get(name))):  # the unchanged value, then why
                self.reply(self._param_error(msg, name, self.params.index(name), code))
            return
        self._apply_params(name)
        self.ap.events["param_sets"] += 1
        new = self.params.get(name)
        own = self.params.name_of(name)  # an alias (CLSAC_PID_KP) sets its parameter (PID_KP): autopilot.params
        if new != old:
            now = self.ap._now_sim_us()
            self.param_changes.append({"t_s": None if now is None else now * 1e-6, "name": own, "from": old, "to": new})
        # answered in the type it was set in when that is REAL32: MAVProxy, which reads an integer type bytewise only
        # from a PX4 autopilot, sets SYS_FAILURE_EN as REAL32 and shows the answer as it comes; by the name asked
        # (the station's handshake waits for it), then, for an alias, by the parameter's own name (every list's)
        as_float = msg.param_type == M.MAV_PARAM_TYPE_REAL32
        for said in (name,) if own == name else (name, own):
            self.send_all(self._param_value(said, new, mav_type=M.MAV_PARAM_TYPE_REAL32 if as_float else None))
        for hook in self.param_hooks:
            hook(own, float(new), True)

    def _on_mission_request_list(self, msg) -> None:
        if self._for_us(msg):
            self.reply(
                M.MAVLink_mission_count_message(msg.get_srcSystem(), msg.get_srcComponent(), 0, msg.mission_type)
            )

    def _on_timesync(self, msg) -> None:
        if msg.tc1 == 0:  # a request: answer with our clock in ns and the requester's ts1
            self.reply(M.MAVLink_timesync_message(time.monotonic_ns(), msg.ts1))

    def _on_ping(self, msg) -> None:
        if msg.target_system == 0 and msg.target_component == 0:  # a request (a response names its target)
            self.reply(M.MAVLink_ping_message(msg.time_usec, msg.seq, msg.get_srcSystem(), msg.get_srcComponent()))

    def _on_request_data_stream(self, msg) -> None:
        if not self._for_us(msg):
            return
        groups = _STREAMS.get(msg.req_stream_id)
        if groups is None:
            self.link.reject("unsupported_stream")
            return
        hz = float(msg.req_message_rate) if msg.start_stop else 0.0
        for g in groups:
            self._set_rate(g, hz)

    def _on_manual_control(self, msg) -> None:
        if msg.target not in (0, self.sysid):
            self.link.reject("wrong_target")
            return
        # r (yaw axis, -1000..1000) is the rudder: full scale = the rudder command limit.
        self._manual(max(-1.0, min(1.0, msg.r / 1000.0)) * self.params.config.u_limit_rad)

    def _on_rc_override(self, msg) -> None:
        if not self._for_us(msg):
            return
        pwm = getattr(msg, f"chan{self.ap.pwm.channel}_raw", 0)
        if pwm in (0, 65535):  # 0: release, UINT16_MAX: ignore this channel
            return
        lim = self.params.config.u_limit_rad
        self._manual(max(-lim, min(lim, self.ap.pwm.to_rad(pwm))))

    def _on_ftp(self, msg) -> None:
        """No files: every request gets NAK FileNotFound, so a ground station falls back at once (MAVProxy
        tries the parameter file over FTP first, then PARAM_REQUEST_LIST)."""
        if not self._for_us(msg):
            return
        p = bytes(msg.payload)
        seq = (p[0] | p[1] << 8) + 1
        nak = bytes([seq & 0xFF, (seq >> 8) & 0xFF, p[2], _FTP_NAK, 1, p[3], 0, 0, 0, 0, 0, 0, _FTP_ERR_FILE_NOT_FOUND])
        self.reply(
            M.MAVLink_file_transfer_protocol_message(
                0, msg.get_srcSystem(), msg.get_srcComponent(), list(nak + bytes(251 - len(nak)))
            )
        )

    _handlers = {
        M.MAVLINK_MSG_ID_COMMAND_LONG: _on_command,
        M.MAVLINK_MSG_ID_COMMAND_INT: _on_command,
        M.MAVLINK_MSG_ID_SET_MODE: _on_set_mode,
        M.MAVLINK_MSG_ID_PARAM_REQUEST_LIST: _on_param_request_list,
        M.MAVLINK_MSG_ID_PARAM_REQUEST_READ: _on_param_request_read,
        M.MAVLINK_MSG_ID_PARAM_SET: _on_param_set,
        M.MAVLINK_MSG_ID_MISSION_REQUEST_LIST: _on_mission_request_list,
        M.MAVLINK_MSG_ID_TIMESYNC: _on_timesync,
        M.MAVLINK_MSG_ID_PING: _on_ping,
        M.MAVLINK_MSG_ID_REQUEST_DATA_STREAM: _on_request_data_stream,
        M.MAVLINK_MSG_ID_MANUAL_CONTROL: _on_manual_control,
        M.MAVLINK_MSG_ID_RC_CHANNELS_OVERRIDE: _on_rc_override,
        M.MAVLINK_MSG_ID_FILE_TRANSFER_PROTOCOL: _on_ftp,
    }

    # -------------------------------------------------------------- commands
    def _cmd_set_mode(self, msg):
        return self._set_mode(int(msg.param1), int(msg.param2))

    def _cmd_arm(self, msg):
        arm = msg.param1 == 1.0
        if msg.param1 not in (0.0, 1.0):
            return M.MAV_RESULT_DENIED
        if arm != self.control.armed:
            self.control.armed = arm
            if arm:
                self.control.transfer()  # from neutral to the mode's command without a step
            self.ap._event(M.MAV_SEVERITY_NOTICE, "ARMED" if arm else "DISARMED: rudder neutral", kind="arm or disarm")
        return M.MAV_RESULT_ACCEPTED

    def _cmd_request_message(self, msg):
        mid = int(msg.param1)
        send = self._on_request.get(mid)
        if send is None:
            return M.MAV_RESULT_UNSUPPORTED
        return M.MAV_RESULT_ACCEPTED, lambda: send(self, msg)

    def _cmd_autopilot_capabilities(self, _msg):
        return M.MAV_RESULT_ACCEPTED, lambda: self.reply(self._autopilot_version())

    def _cmd_protocol_version(self, _msg):
        return M.MAV_RESULT_ACCEPTED, self._send_protocol_version

    def _cmd_set_message_interval(self, msg):
        mid, us = int(msg.param1), msg.param2
        group = (
            "attitude"
            if mid in ATTITUDE_GROUP
            else "gains"
            if mid == NAMED_VALUE_FLOAT
            else "status"
            if mid == SYS_STATUS
            else None
        )
        if group is None:
            return M.MAV_RESULT_UNSUPPORTED
        if us == 0:  # the default rate
            hz = {"attitude": self.ap.opts.telemetry_rate_hz, "gains": GAINS_RATE_HZ, "status": 1.0}[group]
        elif us < 0:  # -1: off
            hz = 0.0
        else:
            hz = 1e6 / us
        self._set_rate(group, hz)
        return M.MAV_RESULT_ACCEPTED

    def _cmd_inject_failure(self, msg):
        if msg.get_msgId() != M.MAVLINK_MSG_ID_COMMAND_LONG:
            return M.MAV_RESULT_COMMAND_LONG_ONLY  # param5 is our value: COMMAND_INT would make it an integer
        return self.failures.command(msg, time.perf_counter())

    _commands = {
        M.MAV_CMD_DO_SET_MODE: _cmd_set_mode,
        M.MAV_CMD_COMPONENT_ARM_DISARM: _cmd_arm,
        M.MAV_CMD_REQUEST_MESSAGE: _cmd_request_message,
        M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: _cmd_autopilot_capabilities,
        M.MAV_CMD_REQUEST_PROTOCOL_VERSION: _cmd_protocol_version,
        M.MAV_CMD_SET_MESSAGE_INTERVAL: _cmd_set_message_interval,
        M.MAV_CMD_INJECT_FAILURE: _cmd_inject_failure,
    }

    # ----------------------------------------------------------------- modes
    def _set_mode(self, base_mode: int, custom_mode: int) -> int:
        if not base_mode & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return M.MAV_RESULT_DENIED  # only custom modes name this autopilot's modes
        try:
            mode = Mode(custom_mode)
        except ValueError:
            return M.MAV_RESULT_DENIED
        if mode not in self.selectable:
            return M.MAV_RESULT_DENIED  # FAILSAFE is entered and left by itself; SAC/CLSAC need the CL-SAC law
        if mode is not self.selected:
            self._apply_mode(mode)
        return M.MAV_RESULT_ACCEPTED

    def _apply_mode(self, mode: Mode) -> None:
        """Select ``mode``: MANUAL holds the rudder command in force until the ground station moves it; SAC and
        CLSAC fly the law with Lv = 0 or the configured Lv.  The switch is bumpless (``ControlStep.transfer``)."""
        control = self.control
        if mode is Mode.MANUAL:
            control.manual = control.u_last
        else:
            control.manual = None
            control.reconfigure(self._law_config(mode))  # a parameter set while in MANUAL flies from now on
        control.transfer()
        self.selected = mode
        if self.mode is not Mode.FAILSAFE:
            self.mode = mode
        self._announce()

    def _law_config(self, mode: Mode):
        cfg = self.params.config
        return cfg.with_(lv=0.0) if mode is Mode.SAC else cfg

    def _announce(self, station: bool = True) -> None:
        """Say the mode in force; ``station``: a ground station's request changed it (so a station switching modes
        in a flood is said as a summary, and its HEARTBEAT and CURRENT_MODE come within its answers' budget: the
        1 Hz HEARTBEAT tells the mode anyway)."""
        self.ap._event(M.MAV_SEVERITY_NOTICE, f"mode {self.mode.name}", kind="mode change" if station else None)
        if not station or self._answerable(2.0):
            self.ap._send_heartbeat()
            self.send_all(self._current_mode())

    def _event(self, severity: int, text: str) -> None:
        self.ap._event(severity, text)

    def _manual(self, u: float) -> None:
        self.ap.events["manual_inputs"] += 1
        if self.selected is Mode.MANUAL:
            self.control.manual = u

    # ------------------------------------------------------------ parameters
    def _apply_params(self, name: str) -> None:
        """A valid set flies from the next control step; the law keeps its states (``ClSac.reconfigure``)."""
        p = self.params.params[self.params.index(name)]
        if p.option:
            setattr(self.ap.opts, p.option, self.params.option(p.option))
        elif self.selected is not Mode.MANUAL:  # MANUAL: the law's next mode flies it (_apply_mode)
            self.control.reconfigure(self._law_config(self.selected))

    def _param_value(self, name: str, value: float, index: int | None = None, mav_type: int | None = None):
        """PARAM_VALUE of ``name`` in its own type (SYS_FAILURE_EN: INT32, bytewise as PX4's: ``params.encode``), or
        in ``mav_type``."""
        i = self.params.index(name) if index is None else index
        t = self.params.params[self.params.index(name)].mav_type if mav_type is None else mav_type
        return M.MAVLink_param_value_message(name.encode(), encode(value, t), t, len(self.params), i)

    def _param_error(self, msg, name: str, index: int, code: int):
        return M.MAVLink_param_error_message(
            msg.get_srcSystem(), msg.get_srcComponent(), name.encode()[:PARAM_ID_LEN], index, code
        )

    # -------------------------------------------------------------- messages
    def _sys_status(self):
        ap = self.ap
        sensors = M.MAV_SYS_STATUS_SENSOR_3D_GYRO | M.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
        # Health bits of sensors not present read as healthy (as ArduPilot sends them; MAVProxy's fence module
        # would otherwise announce "fence breach"); the attitude ones go unhealthy in the attitude failsafe.
        healthy = 0xFFFFFFFF if ap.failsafe is Failsafe.NONE else 0xFFFFFFFF & ~sensors
        load = int(min(1000, 1000 * ap.timing.last_compute / ap.period))
        rej = sum(ap.gcs.rejected.values())
        drop = int(min(10000, 10000 * rej / max(1, ap.gcs.rx_datagrams)))
        return M.MAVLink_sys_status_message(
            sensors, sensors, healthy, load, 65535, -1, -1, drop, min(65535, rej), 0, 0, 0, 0
        )

    def _current_mode(self) -> tuple:
        """CURRENT_MODE as (its fast packer, the wire values): ``send_all`` and ``reply`` take it as a message."""
        return (self._pk_current_mode, int(self.mode), int(self.selected), MAV_STANDARD_MODE_NON_STANDARD)

    def _available_modes(self, index: int):
        modes = self.modes
        mode = modes[index - 1]
        every = all_dialect()
        props = every.MAV_MODE_PROPERTY_NOT_USER_SELECTABLE if mode not in self.selectable else 0
        return every.MAVLink_available_modes_message(
            len(modes), index, every.MAV_STANDARD_MODE_NON_STANDARD, int(mode), props, mode.name.encode()
        )

    def _send_available_modes(self, msg) -> None:
        n = len(self.modes)
        which = int(msg.param2)  # 0: all, else the 1-based mode index
        for i in range(1, n + 1) if which == 0 else ([which] if 1 <= which <= n else []):
            self.reply(self._available_modes(i))

    def _autopilot_version(self):
        caps = (
            M.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
            | M.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE  # SYS_FAILURE_EN, an INT32 (autopilot.params.encode)
            | M.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
            | M.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
            | M.MAV_PROTOCOL_CAPABILITY_MAVLINK2
        )
        return M.MAVLink_autopilot_version_message(caps, 0x01000000, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 0)

    def _send_protocol_version(self) -> None:
        g = self.link
        g.send_raw(g.pack_fast(self._pk_pv, 200, 100, 200, bytes(8), bytes(8)), PROTOCOL_VERSION)

    _on_request = {  # MAV_CMD_REQUEST_MESSAGE: message id -> sender(self, command)
        M.MAVLINK_MSG_ID_AUTOPILOT_VERSION: lambda self, _cmd: self.reply(self._autopilot_version()),
        PROTOCOL_VERSION: lambda self, _cmd: self._send_protocol_version(),
        AVAILABLE_MODES: _send_available_modes,
        CURRENT_MODE: lambda self, _cmd: self.reply(self._current_mode()),
        M.MAVLINK_MSG_ID_HEARTBEAT: lambda self, _cmd: self.reply(self.heartbeat(self.ap._status_state)),
        SYS_STATUS: lambda self, _cmd: self.reply(self._sys_status()),
    }

    def _set_rate(self, group: str, hz: float) -> None:
        if group == "status":
            self.status_period_s = 1.0 / hz if hz > 0 else 0.0
            return
        self.every[group] = n = self._every(hz)
        if group == "attitude":
            self.ap._telemetry_every = n


_DOCS = {p.name: p.doc for p in PARAMS}


def refusal_text(name: str, value: float, exc: ParamError) -> str:
    """The status text of a refused PARAM_SET: which value, why, and what the parameter is, in one sentence
    (``NAME=VALUE rejected: ...``), sent in MAVLink 2 chunks if it is longer than one STATUSTEXT."""
    why = str(exc)
    text = why if why.startswith(f"{name}=") else f"{name}={value:g} rejected: {why}"
    doc = _DOCS.get(name)
    return f"{text} ({doc})" if doc else text
