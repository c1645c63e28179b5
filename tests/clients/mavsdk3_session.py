"""One ground-station session with MAVSDK-Python 3.x (gRPC to the ``mavsdk_server`` binary its wheel ships), run by
tests/tools/test_clients.py in the clients' own virtual environment (never the product's).  Default settings: 245:190.

``python mavsdk3_session.py PORT GRPC_PORT OUT.json``: the same steps as mavsdk4_session.py (parameters, a refused
set, modes through MavlinkDirect, disarm and arm, a roll setpoint through Offboard.set_attitude), results in OUT.json.
"""

from __future__ import annotations

import asyncio
import json
import sys
import time

import mavsdk
from mavsdk import System
from mavsdk.mavlink_direct import MavlinkMessage
from mavsdk.offboard import Attitude

CUSTOM_MODE_ENABLED = 1  # MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
DO_SET_MODE = 176


async def step(out: dict, name: str, coro, timeout: float = 15.0):
    try:
        out[name] = await asyncio.wait_for(coro, timeout)
    except Exception as exc:  # noqa: BLE001  (every step is reported, whatever failed)
        out[name] = {"error": f"{type(exc).__name__}: {exc}"}


async def collect(gen, sink: list, pick) -> None:
    async for item in gen:
        sink.append(pick(item))


async def session(port: int, grpc_port: int, path: str) -> None:
    out: dict = {"client": "mavsdk", "version": getattr(mavsdk, "__version__", "3")}
    drone = System(port=grpc_port)  # default ids 245:190
    await drone.connect(system_address=f"udpin://127.0.0.1:{port}")

    async def connected():
        async for state in drone.core.connection_state():
            if state.is_connected:
                return {"connected": True}

    await step(out, "connect", connected(), 20.0)
    texts: list[str] = []
    rolls: list[float] = []
    heartbeats: list[dict] = []
    tasks = [
        asyncio.ensure_future(collect(drone.telemetry.status_text(), texts, lambda st: st.text)),
        asyncio.ensure_future(collect(drone.telemetry.attitude_euler(), rolls, lambda e: e.roll_deg)),
        asyncio.ensure_future(
            collect(drone.mavlink_direct.message("HEARTBEAT"), heartbeats, lambda m: json.loads(m.fields_json))
        ),
    ]

    async def all_params():
        p = await drone.param.get_all_params()
        return {"float": {f.name: f.value for f in p.float_params}, "int": {i.name: i.value for i in p.int_params}}

    async def set_lv():
        await drone.param.set_param_float("CLSAC_LV", 12.5)
        return "ok"

    async def set_am():
        await drone.param.set_param_float("CLSAC_AM", 3.0)
        return "accepted"

    await step(out, "all_params", all_params(), 30.0)
    await step(out, "get_lv", drone.param.get_param_float("CLSAC_LV"))
    await step(out, "set_lv", set_lv())
    await step(out, "get_lv_after", drone.param.get_param_float("CLSAC_LV"))

    async def set_failure_en(v: int):
        await drone.param.set_param_int("SYS_FAILURE_EN", v)  # PX4's type: INT32
        return "ok"

    await step(out, "set_failure_en", set_failure_en(1))
    await step(out, "get_failure_en", drone.param.get_param_int("SYS_FAILURE_EN"))
    await step(out, "reset_failure_en", set_failure_en(0))
    for _ in range(3):  # the STATUSTEXT stream may not be subscribed yet in mavsdk_server: refuse again then
        await step(out, "set_am_refused", set_am())
        await asyncio.sleep(1.0)
        if any("CLSAC_AM" in t for t in texts):
            break

    async def set_mode(custom: int):
        fields = {
            "target_system": 1,
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
        await drone.mavlink_direct.send_message(MavlinkMessage("COMMAND_LONG", 0, 0, 1, 1, json.dumps(fields)))
        t_end = time.monotonic() + 5
        while time.monotonic() < t_end:
            if heartbeats and heartbeats[-1].get("custom_mode") == custom:
                return custom
            await asyncio.sleep(0.05)
        raise TimeoutError(f"no HEARTBEAT with custom_mode {custom} within 5 s")

    async def action(name):
        await getattr(drone.action, name)()
        return "ok"

    await step(out, "mode_manual", set_mode(0))
    await step(out, "mode_clsac", set_mode(101))
    await step(out, "disarm", action("disarm"))
    await step(out, "arm", action("arm"))

    async def fly(roll_deg: float, seconds: float):
        t_end = time.monotonic() + seconds
        while time.monotonic() < t_end:
            await drone.offboard.set_attitude(Attitude(roll_deg, 0.0, 0.0, 0.5))
            await asyncio.sleep(0.05)
        return {"roll_deg": rolls[-1] if rolls else None, "samples": len(rolls)}

    await step(out, "fly", fly(15.0, 5.0))
    out["statustexts"] = list(texts)
    for t in tasks:
        t.cancel()
    with open(path, "w") as f:
        json.dump(out, f)
    drone._stop_mavsdk_server()  # noqa: SLF001  (the wheel's server process; no public stop in 3.x)


if __name__ == "__main__":
    asyncio.run(session(int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]))
