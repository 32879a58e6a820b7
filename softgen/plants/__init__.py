"""Emulated hardware as blocks: plants, actuator interfaces and sensors users can reuse.

- :mod:`softgen.plants.hardware`: a dirty-derivative velocity and emergency stops (the
  encoders and delay lines are :mod:`softgen.blocks.sensors`).
- :mod:`softgen.plants.gioste`: the GioSte pneumatic arm of thesis section 10.3
  (identified maps eq. 10.10-10.11, valves, its closed loop; runs and indices are
  :mod:`softgen.studies.gioste`).
- :mod:`softgen.plants.qbmove`: qbmove VSA robots (thesis sections 6.2, 7.3, 7.4):
  open-loop or servo-driven plant, encoders, torque sensors and stiffness estimators
  in one diagram; true spring torque, stiffness and rotatum of a run.
- :mod:`softgen.plants.pneumatic`: the McKibben pendulum of section 6.1 under the
  exact-model pressure allocation.
"""
