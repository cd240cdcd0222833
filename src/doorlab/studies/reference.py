"""The original station's figures: the reference doorlab is measured against.

Source: issue 12 of the doorlab tracker ("Fidelity: the iiwa's reflected motor inertia, the door
at the arc's end, and the original station as the reference"). The 2019 problem-set code was run
again offline on drake 1.42.0 (the last release with the C++ ``ManipulationStation``) with the
official ``drake_models`` files, the problem set's eight experiments and control laws, the
original inverse-dynamics PID inner loop and the 2 ms step. Radial and orientation errors are
from the measured q over the arc, t = 11-21 s; the door angle is taken at t = 21 s (the arc's
end); the contact torque is the peak over the arc.

These are data from another simulator, typed in once here; everything doorlab prints next to
them is measured by doorlab.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class ReferenceRun:
    """One experiment of the original station (SI-adjacent display units, as published).

    Attributes:
        max_radial_mm, rms_radial_mm: Radial error of Q over the arc [mm].
        max_orientation_deg: Orientation error of L7 over the arc [deg].
        door_arc_end_deg: Door opening at t = 21 s [deg]; None with the doors open.
        peak_arc_contact_Nm: Peak |external joint torque| during the arc [N m].
    """

    max_radial_mm: float
    rms_radial_mm: float
    max_orientation_deg: float
    door_arc_end_deg: float | None
    peak_arc_contact_Nm: float


ORIGINAL_STATION: dict[str, ReferenceRun] = {
    "ik_2_open": ReferenceRun(38.50, 22.79, 11.33, None, 0.0),
    "ik_5_open": ReferenceRun(2.48, 1.29, 2.26, None, 0.0),
    "ik_10_open": ReferenceRun(1.60, 1.23, 1.62, None, 0.0),
    "ik_10_closed": ReferenceRun(0.34, 0.16, 1.68, 40.7, 0.61),
    "velocity_open": ReferenceRun(0.47, 0.29, 0.50, None, 0.0),
    "velocity_closed": ReferenceRun(0.35, 0.09, 0.52, 41.0, 0.67),
    "impedance_open": ReferenceRun(21.54, 9.04, 2.11, None, 0.0),
    "impedance_closed": ReferenceRun(2.71, 0.89, 2.28, 39.6, 1.44),
}
"""The original station's eight runs, keyed like ``doorlab.report.EXPERIMENTS`` (issue 12)."""
