"""The simulator (SITL): one interface (``sitl.plant``, ``--plant``) to three kinds of plant: the paper's KH2013A
micro air vehicle (its lateral model and rudder servo, integrated exactly), linear plants from a plant file
(``sitl.linear_plant``) and JSBSim aircraft (``sitl.jsbsim_plant``).

Public API (the linear plants' aircraft)::

    from sitl import Aircraft, AircraftConfig

    ac = Aircraft(AircraftConfig(physics_rate_hz=1000.0))
    x = ac.advance(delta_command, 10)    # 10 physics steps with the servo command held (exact ZOH)

``sitl.model`` holds the KH2013A's matrices as printed (paper section 5); ``sitl.plant.build`` gives any of the
three kinds; ``python -m sitl --plant PLANT`` puts it behind a MAVLink endpoint
(``sitl.endpoint``).  The simulator never imports the control law.
"""

from sitl.aircraft import Aircraft, AircraftConfig, AircraftConfigError, NonFiniteCommandError

__all__ = ["Aircraft", "AircraftConfig", "AircraftConfigError", "NonFiniteCommandError"]
