"""The MAVLink wire contract shared by the SITL, the autopilot and the GCS script (docs/spec.md, "MAVLink").

MAVLink 2, common dialect.  System/component IDs, the lockstep frame clock (and its uint32 wrap), the
roll <-> quaternion mapping and the SET_ATTITUDE_TARGET type mask.  No sockets here (``link``).
"""

from __future__ import annotations

import math

from pymavlink.dialects.v20 import common as mavlink  # noqa: F401  (MAVLink 2, common dialect; re-exported)

# ------------------------------------------------------------------------------------- other dialects
# The messages of dialects other than common that a flight's processes exchange: the vehicle's standard-modes messages
# (development dialect) and ArduPilot's AOA_SSA (ardupilotmega; a square MIMO plant's sideslip): id -> (name, CRC
# extra).  pymavlink's ``all`` dialect holds them and every other, but loading it costs a process about 110 M
# instructions (~35 ms): the links check these by this table and load ``all`` (``all_dialect``) only for another
# dialect's message or for a message class.  tests/autopilot/shared/test_mavlink_units.py holds them to pymavlink's.
OTHER_DIALECT_MESSAGES = {435: ("AVAILABLE_MODES", 134), 436: ("CURRENT_MODE", 193), 11020: ("AOA_SSA", 205)}


def all_dialect():
    """pymavlink's ``all`` dialect (every message it knows, a superset of common with the same CRC extras), loaded at
    the first call."""
    from pymavlink.dialects.v20 import all as dialect

    return dialect


# ---------------------------------------------------------------------------------------------- IDs
AUTOPILOT_ID = (1, 1)  # the autopilot as ground stations see it (its GCS link; MAV_COMP_ID_AUTOPILOT1)
# The autopilot's link to the SITL: its own component (MAV_COMP_ID_SERVO1, it drives the rudder servo), so a tlog
# reader tells its SERVO_OUTPUT_RAW to the SITL from the copy streamed to the ground stations by 1:1.
AUTOPILOT_SITL_ID = (1, 140)
SITL_ID = (1, 200)
GCS_ID = (255, 190)
# The ground stations admitted by default (docs/spec.md, "Which ground stations are admitted"): QGroundControl,
# Mission Planner and MAVProxy talk as system 255, MAVSDK as 245 (its default 245:190); any other system that
# announces itself with a MAV_TYPE_GCS heartbeat is admitted too (``UdpLink(learn_gcs=...)``).
GCS_SYSTEMS = (255, 245)
SYSID_RANGE = (1, 254)  # the vehicle's system id (--sysid): 0 is broadcast, 255 the ground stations'


def vehicle_ids(sysid: int = AUTOPILOT_ID[0]) -> tuple[tuple[int, int], tuple[int, int], tuple[int, int]]:
    """(autopilot GCS link, autopilot SITL link, SITL) system:component of the vehicle with system id ``sysid``:
    the same components as AUTOPILOT_ID, AUTOPILOT_SITL_ID and SITL_ID, under the vehicle's own system id."""
    return (sysid, AUTOPILOT_ID[1]), (sysid, AUTOPILOT_SITL_ID[1]), (sysid, SITL_ID[1])


# ---------------------------------------------------------------------------------------- frames
USEC_WRAP = 1 << 32  # SERVO_OUTPUT_RAW.time_usec is uint32: wraps every 4294.967296 s (71.6 min)
MAX_LOCKSTEP_RATE_HZ = 1000.0  # a frame must be identifiable from a millisecond timestamp


def frame_ms(k: int, rate: float) -> int:
    """time_boot_ms of global frame ``k`` (sim time k / rate), floored to the millisecond."""
    if float(rate).is_integer():
        return (k * 1000) // int(rate)
    return int(math.floor(k * 1000.0 / rate + 1e-6))


def frame_from_ms(ms: int, rate: float) -> int:
    """The global frame index whose :func:`frame_ms` is ``ms`` (exact for rates up to 1 kHz).

    frame_ms floors k*1000/rate, so k lies in [ms*rate/1000, (ms+1)*rate/1000): one integer when rate <= 1000.
    """
    if float(rate).is_integer():
        r = int(rate)
        return -((-ms * r) // 1000)  # ceil(ms * r / 1000)
    return int(math.ceil(ms * rate / 1000.0 - 1e-6))


def frame_usec(k: int, rate: float) -> int:
    """SERVO_OUTPUT_RAW.time_usec that answers frame ``k``: the frame's sim time in microseconds, mod 2**32."""
    if float(rate).is_integer() and 1_000_000 % int(rate) == 0:
        us = k * (1_000_000 // int(rate))
    else:
        us = int(round(k * 1e6 / rate))
    return us % USEC_WRAP


def usec_diff(a: int, b: int) -> int:
    """Signed difference a - b of two uint32 microsecond stamps, assuming |a - b| < 2**31 (wrap-aware)."""
    d = (a - b) % USEC_WRAP
    return d - USEC_WRAP if d >= (USEC_WRAP >> 1) else d


def usec_newer(a: int, b: int) -> bool:
    """True if uint32 stamp ``a`` is strictly after ``b`` (across the 71.6-minute wrap)."""
    return usec_diff(a, b) > 0


# ------------------------------------------------------------------------------------- attitude
def roll_to_quaternion(roll: float) -> list[float]:
    """Quaternion [w, x, y, z] of a pure roll (pitch = yaw = 0)."""
    return [math.cos(0.5 * roll), math.sin(0.5 * roll), 0.0, 0.0]


def quaternion_to_roll(q) -> float:
    """Roll angle (rad) of quaternion [w, x, y, z] (ZYX Euler); NaN if the quaternion is unusable."""
    w, x, y, z = (float(v) for v in q)
    n = w * w + x * x + y * y + z * z
    if not math.isfinite(n) or n < 1e-12:
        return math.nan
    return math.atan2(2.0 * (w * x + y * z), n - 2.0 * (x * x + y * y))


# Bits of SET_ATTITUDE_TARGET.type_mask (ATTITUDE_TARGET_TYPEMASK)
TYPEMASK_IGNORE_RATES = 1 | 2 | 4
TYPEMASK_IGNORE_THRUST = 64
TYPEMASK_IGNORE_ATTITUDE = 128
SETPOINT_TYPEMASK = TYPEMASK_IGNORE_RATES | TYPEMASK_IGNORE_THRUST
