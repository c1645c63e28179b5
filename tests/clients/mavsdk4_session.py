"""One ground-station session with MAVSDK 4.x (the ctypes binding of the C++ library), run by
tests/tools/test_clients.py in the clients' own virtual environment (never the product's).  Default settings: MAVSDK
talks as 245:190.

``python mavsdk4_session.py PORT OUT.json``: listen on udpin://127.0.0.1:PORT, find the vehicle, then download the
parameters, get CLSAC_LV, set it, set a refused CLSAC_AM, switch mode MANUAL -> CLSAC (COMMAND_LONG DO_SET_MODE
through MavlinkDirect: MAVSDK's mode API knows only PX4's and ArduPilot's modes), disarm and arm, and fly a roll
setpoint (Offboard.set_attitude: SET_ATTITUDE_TARGET); write what each step saw to OUT.json.  A step that fails
records its error and the session goes on, so the test reports every failing step.
"""

from __future__ import annotations

import json
import sys
import threading
import time

from mavsdk import ComponentType, Configuration, Mavsdk
from mavsdk.plugins.action import Action
from mavsdk.plugins.mavlink_direct import MavlinkDirect, MavlinkMessage
from mavsdk.plugins.offboard import Attitude, Offboard
from mavsdk.plugins.param import Param
from mavsdk.plugins.telemetry import Telemetry

CUSTOM_MODE_ENABLED = 1  # MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
DO_SET_MODE = 176


def step(out: dict, name: str, fn):
    try:
        out[name] = fn()
    except Exception as exc:  # noqa: BLE001  (every step is reported, whatever failed)
        out[name] = {"error": f"{type(exc).__name__}: {exc}"}


def main(port: int, path: str) -> None:
    out: dict = {"client": "mavsdk", "version": __import__("mavsdk").__version__}
    mavsdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    mavsdk.add_any_connection(f"udpin://127.0.0.1:{port}")
    system = mavsdk.first_autopilot(20.0)
    if system is None:
        out["connect"] = {"error": "no autopilot within 20 s"}
        json.dump(out, open(path, "w"))
        return
    out["connect"] = {"system_id": system.get_system_id()}
    lock = threading.Lock()
    texts: list[str] = []
    heartbeats: list[dict] = []
    rolls: list[float] = []
    telemetry = Telemetry(system)
    telemetry.subscribe_status_text(lambda st, _ud: texts.append(st.text))
    telemetry.subscribe_attitude_euler(lambda e, _ud: rolls.append(e.roll_deg))
    direct = MavlinkDirect(system)

    def on_heartbeat(msg, _ud):
        with lock:
            heartbeats.append(json.loads(msg.fields_json))

    direct.subscribe_message("HEARTBEAT", on_heartbeat)
    param = Param(system)
    action = Action(system)

    def all_params():
        p = param.get_all_params()
        return {"float": {f.name: f.value for f in p.float_params}, "int": {i.name: i.value for i in p.int_params}}

    step(out, "all_params", all_params)
    step(out, "get_lv", lambda: param.get_param_float("CLSAC_LV"))
    step(out, "set_lv", lambda: str(param.set_param_float("CLSAC_LV", 12.5)))
    step(out, "get_lv_after", lambda: param.get_param_float("CLSAC_LV"))
    step(out, "set_failure_en", lambda: str(param.set_param_int("SYS_FAILURE_EN", 1)))  # PX4's type: INT32
    step(out, "get_failure_en", lambda: param.get_param_int("SYS_FAILURE_EN"))
    step(out, "reset_failure_en", lambda: str(param.set_param_int("SYS_FAILURE_EN", 0)))
    for _ in range(3):  # as mavsdk3_session.py: refuse again if the STATUSTEXT did not arrive
        step(out, "set_am_refused", lambda: str(param.set_param_float("CLSAC_AM", 3.0)))
        time.sleep(1.0)
        if any("CLSAC_AM" in t for t in texts):
            break

    def set_mode(custom: int):
        fields = {
            "target_system": system.get_system_id(),
            "target_component": 1,
            "command": DO_SET_MODE,
            "confirmation": 0,
            "param1": CUSTOM_MODE_ENABLED,
            "param2": custom,
            "param3": 0,
            "param4": 0,
            "param5": 0,
            "param6": 0,
            "param7": 0,
        }
        msg = MavlinkMessage("COMMAND_LONG", 0, 0, system.get_system_id(), 1, json.dumps(fields))
        direct.send_message(msg)
        t_end = time.monotonic() + 5
        while time.monotonic() < t_end:
            with lock:
                if heartbeats and heartbeats[-1].get("custom_mode") == custom:
                    return custom
            time.sleep(0.05)
        raise TimeoutError(f"no HEARTBEAT with custom_mode {custom} within 5 s")

    step(out, "mode_manual", lambda: set_mode(0))
    step(out, "mode_clsac", lambda: set_mode(101))
    step(out, "disarm", lambda: str(action.disarm()))
    step(out, "arm", lambda: str(action.arm()))

    def fly(roll_deg: float, seconds: float):
        offboard = Offboard(system)
        t_end = time.monotonic() + seconds
        while time.monotonic() < t_end:  # MAVSDK also repeats the setpoint itself at 20 Hz
            offboard.set_attitude(Attitude(roll_deg, 0.0, 0.0, 0.5))
            time.sleep(0.05)
        return {"roll_deg": rolls[-1] if rolls else None, "samples": len(rolls)}

    step(out, "fly", lambda: fly(15.0, 5.0))
    out["statustexts"] = list(texts)
    with open(path, "w") as f:
        json.dump(out, f)
    mavsdk.destroy()


if __name__ == "__main__":
    main(int(sys.argv[1]), sys.argv[2])
