"""doorlab on the real cell's LCM protocol (drake-iiwa-driver, drake-schunk-driver).

Modules:

- :mod:`doorlab.hardware.protocol`: channels, rates, utime semantics, the start guard, the
  driver's limits, the LCM URL check and a loopback test.
- :mod:`doorlab.hardware.sim_driver`: doorlab's simulated cell behind that protocol
  (``doorlab sim-driver``), as a process or as systems added to a diagram.
"""
