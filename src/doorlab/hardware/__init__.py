"""doorlab on the real arm: an iiwa and a WSG-50 over LCM (the drake-iiwa-driver and
drake-schunk-driver protocol), and a simulated driver to rehearse on.

The client (``doorlab run --hardware``):

- :mod:`doorlab.hardware.interface`: the real cell, a Diagram with the simulated station's ports;
- :mod:`doorlab.hardware.link`: the statuses as they arrive;
- :mod:`doorlab.hardware.episode`: an episode driven by the statuses, every command checked;
- :mod:`doorlab.hardware.estimates`: the door angle estimated from Q (no hinge sensor);
- :mod:`doorlab.hardware.metrics`, :mod:`doorlab.hardware.run`: the run folder.

The simulated driver (``doorlab sim-driver``):

- :mod:`doorlab.hardware.protocol`: channels, rates, utime semantics, the start guard, the
  driver's limits, the LCM URL check and a loopback test.
- :mod:`doorlab.hardware.sim_cell`: doorlab's simulated cell behind that protocol, as
  systems added to a diagram (its timing matches an episode in one process).
- :mod:`doorlab.hardware.sim_driver`: that cell as a process (``doorlab sim-driver``), paced
  to real time, with its ground truth.
"""
