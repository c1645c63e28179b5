"""Registers the Gymnasium environment ``Roll-v0`` (docs/gymnasium.md): ``gymnasium.make("sitl.gym:Roll-v0")``.

Registration only.  The environment flies the SITL's plants, faults, atmosphere and sensors, but it is judged by the
autopilot's verdict and metrics, so it lives in ``tools.experiment.gym`` (docs/architecture.md, "Dependency rule":
``sitl`` imports neither ``autopilot`` beyond ``autopilot.shared`` nor ``tools``).  It is named here by its import
path and loaded only when an environment is made: importing this module loads gymnasium and nothing else of the
project.
"""

from __future__ import annotations

import gymnasium

ENV_ID = "Roll-v0"

if ENV_ID not in gymnasium.registry:
    gymnasium.register(
        id=ENV_ID,
        entry_point="tools.experiment.gym.roll:RollEnv",
        vector_entry_point="tools.experiment.gym.vector:RollVectorEnv",
        disable_env_checker=False,
    )
