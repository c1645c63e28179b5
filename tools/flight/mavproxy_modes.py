"""A MAVProxy module that gives this vehicle's modes their names: MANUAL, SAC, CLSAC, FAILSAFE, BASELINE.

Why it is needed: MAVProxy (and pymavlink's ``mode_string_v10``/``mode_mapping``) names a vehicle's modes by its
HEARTBEAT's ``type`` alone, from pymavlink's table of ArduPilot's vehicles (``AP_MAV_TYPE_MODE_MAP``), whatever its
``autopilot`` field says (only PX4 gets a table of its own).  This autopilot reports ``MAV_TYPE_FIXED_WING`` (what it
flies, for QGroundControl's and MAVSDK's sake) with ``MAV_AUTOPILOT_GENERIC``, so MAVProxy shows ArduPlane's table:
``mode`` lists AUTO, CRUISE, FBWA..., none of them this vehicle's but MANUAL (0 in both), and the prompt says
``Mode(101)``.  Loaded, this module puts this vehicle's table (``MODES``, ``autopilot.vehicle.Mode``'s numbers) in
place of ArduPlane's while the vehicle MAVProxy hears is a generic-autopilot fixed wing, and ArduPlane's back when it
hears an ArduPilot one or is unloaded.  Then ``mode`` lists MANUAL SAC CLSAC FAILSAFE BASELINE, ``mode CLSAC`` sends
DO_SET_MODE 101 (FAILSAFE is refused, with its reason: the vehicle enters and leaves it by itself), and the prompt
and ``status`` name the mode.

Use (docs/ground-stations.md), from the checkout, so that MAVProxy's Python finds it::

    PYTHONPATH=$PWD mavproxy.py --master=udpin:127.0.0.1:14550 --load-module tools.flight.mavproxy_modes

or ``module load tools.flight.mavproxy_modes`` at MAVProxy's prompt (MAVProxy's own venv: this module imports
nothing of the project, only MAVProxy and pymavlink, and those only when MAVProxy loads it)."""

from __future__ import annotations

# HEARTBEAT.custom_mode -> name: autopilot.vehicle.Mode (tests/tools/test_clients.py checks that they agree)
MODES = {
    0: "MANUAL",
    100: "SAC",
    101: "CLSAC",
    102: "FAILSAFE",
    103: "BASELINE",
    104: "MRAC",
    105: "CRM_MRAC",
    106: "L1",
    107: "INDI",
    108: "LAW",
}
NAME = "clsac_modes"


def init(mpstate):
    """MAVProxy's entry point: the module's instance."""
    from MAVProxy.modules.lib import mp_module
    from pymavlink import mavutil

    fixed_wing = mavutil.mavlink.MAV_TYPE_FIXED_WING
    generic = mavutil.mavlink.MAV_AUTOPILOT_GENERIC
    tables = mavutil.AP_MAV_TYPE_MODE_MAP

    class ClsacModes(mp_module.MPModule):
        def __init__(self, mpstate):
            super().__init__(mpstate, NAME, "the CL-SAC autopilot's mode names")
            self.ardupilot = tables.get(fixed_wing)  # ArduPlane's table, put back for an ArduPilot vehicle
            self.ours = False
            seen = self.master.messages.get("HEARTBEAT") if self.master is not None else None
            if seen is not None:  # loaded after the vehicle was detected: name its modes from now on
                self.mavlink_packet(seen)

        def mavlink_packet(self, m):
            if m.get_type() != "HEARTBEAT" or m.type != fixed_wing:
                return
            ours = m.autopilot == generic
            if ours == self.ours:
                return
            tables[fixed_wing] = dict(MODES) if ours else self.ardupilot
            self.ours = ours
            if ours:
                print(f"{NAME}: this vehicle's modes: {' '.join(MODES.values())} (FAILSAFE only by itself)")

        def unload(self):
            tables[fixed_wing] = self.ardupilot

    return ClsacModes(mpstate)
