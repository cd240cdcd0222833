"""The cell the plans command: the SDF models, the frames' names, the Drake station (the
original ManipulationStation's ports), the lab arm behind kuka_driver's cycle, the limits a
command must respect, the door's model and the handle's arc.

Above the configuration, below the control laws.
"""
