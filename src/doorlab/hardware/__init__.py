"""doorlab on the real arm: an iiwa and a WSG-50 over LCM (the drake-iiwa-driver and
drake-schunk-driver protocol), and a simulated driver to rehearse on.

- :mod:`doorlab.hardware.interface`: the real cell, a Diagram with the simulated station's ports;
- :mod:`doorlab.hardware.link`: the statuses as they arrive;
- :mod:`doorlab.hardware.episode`: an episode driven by the statuses, every command checked;
- :mod:`doorlab.hardware.estimates`: the door angle estimated from Q (no hinge sensor);
- :mod:`doorlab.hardware.run`: ``doorlab run --hardware``'s run folder.
"""
