"""The product's aircraft, faults and verdict as Gymnasium environments (docs/gymnasium.md).

* ``tools.experiment.gym.roll.RollEnv``: ``gymnasium.make("sitl.gym:Roll-v0", plant=...)``, one aircraft;
* ``tools.experiment.gym.vector.RollVectorEnv``: N aircraft in one numpy step, ``gymnasium.make_vec("sitl.gym:Roll-v0",
  num_envs=N, vectorization_mode="vector_entry_point")``;
* ``tools.experiment.gym.ars``: a linear policy trained by augmented random search, scored on held-out faults.

``gymnasium`` is the optional extra ``.[gym]``: only these modules import it.
"""
