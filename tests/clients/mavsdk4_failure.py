"""MAVSDK 4.x's Failure plugin against the vehicle, run by tests/tools/test_failure_clients.py in the clients'
own virtual environment (never the product's).  Default settings: MAVSDK talks as 245:190.

``python mavsdk4_failure.py PORT OUT.json``: listen on udpin://127.0.0.1:PORT, find the vehicle, then
``Failure.inject(SYSTEM_SERVO, STUCK, 4)`` (the rudder jams where it is) and ``inject(SYSTEM_SERVO, GARBAGE, 4)`` (not
implemented); write each result (``SUCCESS`` or the FailureError's result name) and the status texts to OUT.json.
"""

from __future__ import annotations

import json
import sys
import time

from mavsdk import ComponentType, Configuration, Mavsdk
from mavsdk.plugins.failure import Failure, FailureError, FailureType, FailureUnit
from mavsdk.plugins.telemetry import Telemetry


def inject(failure: Failure, kind) -> str:
    try:
        return failure.inject(FailureUnit.SYSTEM_SERVO, kind, 4).name
    except FailureError as exc:
        return exc.result.name


def main(port: int, path: str) -> None:
    out: dict = {"client": "mavsdk", "version": __import__("mavsdk").__version__}
    mavsdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    mavsdk.add_any_connection(f"udpin://127.0.0.1:{port}")
    system = mavsdk.first_autopilot(20.0)
    if system is None:
        out["connect"] = {"error": "no autopilot within 20 s"}
    else:
        texts: list[str] = []
        Telemetry(system).subscribe_status_text(lambda st, _ud: texts.append(st.text))
        failure = Failure(system)
        t0 = time.monotonic()
        out["stuck"] = inject(failure, FailureType.STUCK)
        out["stuck_s"] = time.monotonic() - t0
        out["garbage"] = inject(failure, FailureType.GARBAGE)
        time.sleep(1.0)  # the status texts of both
        out["statustexts"] = list(texts)
    with open(path, "w") as f:
        json.dump(out, f)
    mavsdk.destroy()


if __name__ == "__main__":
    main(int(sys.argv[1]), sys.argv[2])
