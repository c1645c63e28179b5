"""The KH2013A micro air vehicle simulator: the paper's lateral model and rudder servo, integrated exactly.

Public API::

    from sitl import Aircraft, AircraftConfig

    ac = Aircraft(AircraftConfig(physics_rate_hz=1000.0))
    x = ac.advance(delta_command, 10)    # 10 physics steps with the servo command held (exact ZOH)

``sitl.model`` holds the matrices as printed (paper section 5); ``python -m sitl`` puts the aircraft
behind a MAVLink endpoint (``sitl.endpoint``).  The simulator never imports the control law.
"""

from sitl.aircraft import Aircraft, AircraftConfig, AircraftConfigError, NonFiniteCommandError

__all__ = ["Aircraft", "AircraftConfig", "AircraftConfigError", "NonFiniteCommandError"]
