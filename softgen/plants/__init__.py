"""Emulated hardware as blocks: plants, actuator interfaces and sensors users can reuse.

- :mod:`softgen.plants.hardware`: generic encoders with a dirty derivative, transport
  delay lines, emergency stops.
- :mod:`softgen.plants.gioste`: the GioSte pneumatic arm of thesis section 10.3
  (identified maps eq. 10.10-10.11, valves, its closed loop).
"""
