"""Emulated robots: plants, sensors and their references assembled as diagrams.

:mod:`softgen.plants.qbmove` — qbmove VSA robots (thesis sections 6.2, 7.3, 7.4):
open-loop or servo-driven plant, encoders, torque sensors, estimators in one
diagram; true spring torque, stiffness and rotatum of a run.
:mod:`softgen.plants.pneumatic` — the McKibben pendulum of section 6.1 under the
exact-model pressure allocation.
"""
