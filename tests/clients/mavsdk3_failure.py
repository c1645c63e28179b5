"""MAVSDK-Python 3.x's Failure plugin (gRPC to the ``mavsdk_server`` its wheel ships) against the vehicle, run by
tests/tools/test_failure_clients.py in the clients' own virtual environment (never the product's).  Default ids 245:190.

``python mavsdk3_failure.py PORT GRPC_PORT OUT.json``: the same steps as mavsdk4_failure.py: ``failure.inject(
SYSTEM_SERVO, STUCK, 4)`` and ``inject(SYSTEM_SERVO, GARBAGE, 4)``; each result (``SUCCESS`` or the FailureError's
result name) and the status texts in OUT.json.
"""

from __future__ import annotations

import asyncio
import json
import sys
import time

import mavsdk
from mavsdk import System
from mavsdk.failure import FailureError, FailureType, FailureUnit


async def inject(drone: System, kind) -> str:
    try:
        await asyncio.wait_for(drone.failure.inject(FailureUnit.SYSTEM_SERVO, kind, 4), 15.0)
        return "SUCCESS"
    except FailureError as exc:
        return exc._result.result.name  # noqa: SLF001  (3.x keeps the result on the error's FailureResult)


async def session(port: int, grpc_port: int, path: str) -> None:
    out: dict = {"client": "mavsdk", "version": getattr(mavsdk, "__version__", "3")}
    drone = System(port=grpc_port)
    await drone.connect(system_address=f"udpin://127.0.0.1:{port}")

    async def connected():
        async for state in drone.core.connection_state():
            if state.is_connected:
                return True

    await asyncio.wait_for(connected(), 20.0)
    texts: list[str] = []

    async def collect():
        async for st in drone.telemetry.status_text():
            texts.append(st.text)

    task = asyncio.ensure_future(collect())
    await asyncio.sleep(0.5)  # mavsdk_server subscribes to the status texts
    t0 = time.monotonic()
    out["stuck"] = await inject(drone, FailureType.STUCK)
    out["stuck_s"] = time.monotonic() - t0
    out["garbage"] = await inject(drone, FailureType.GARBAGE)
    await asyncio.sleep(1.0)
    out["statustexts"] = list(texts)
    task.cancel()
    with open(path, "w") as f:
        json.dump(out, f)
    drone._stop_mavsdk_server()  # noqa: SLF001  (the wheel's server process; no public stop in 3.x)


if __name__ == "__main__":
    asyncio.run(session(int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]))
