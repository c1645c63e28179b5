"""The layer the autopilot, the SITL and the tools share; it imports nothing else of this project.

* the MAVLink wire contract: ``mavlink`` (dialect, system/component IDs, the lockstep frame clock and its
  2^32 wrap, roll <-> quaternion), ``link`` (the UDP link and its counters), ``fastmav`` (byte-identical
  fast packers), ``tlog`` (the standard telemetry log) and ``pwm`` (the servo calibration);
* process plumbing: ``cli`` (argument types and the one-line-error parser), ``process`` (signals, atomic
  JSON, exit codes, CPU pinning and real-time scheduling), ``series`` (per-step ``.npz`` recorder) and
  ``events`` (status events: printed, sent as STATUSTEXT, handed to hooks);
* ``numerics`` (the exact zero-order hold both the control law and the simulator use);
* ``telemetry`` (the Rerun writer primitives: buffered tables, state channels, file merge).

The dependency rule (docs/architecture.md, "Dependency rule"; checked by ``tests/project/test_architecture.py``): the
control law, the loop and the autopilot's telemetry live in ``autopilot``; the simulator lives in
``sitl``; neither imports the other, and ``sitl`` imports only this package from ``autopilot``.
Importing ``autopilot.shared`` does not import the control law (``autopilot/__init__`` is lazy).
"""
