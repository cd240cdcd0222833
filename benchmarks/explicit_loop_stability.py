#!/usr/bin/env python3
"""Is a fully explicit joint loop stable at the plant's step? Spectral radii, no simulation.

The ``stiffness`` inner loop applies its spring Kq (q_ref - q) as an explicit torque (from
q_n) and leaves the damping (Dq dq_scale + h Kq) to the joints themselves, which SAP
integrates implicitly. Would it also be stable with the damping explicit (one explicit torque
for the whole law)? Linearized about a configuration q0 (gravity compensated, q_ref = q0),
one SAP step of the arm alone is

    implicit damping: (M + h D) v+ = M v - h K q        q+ = q + h v+
    explicit damping:  M v+ = (M - h D) v - h K q       q+ = q + h v+

and the loop is stable iff the spectral radius of that map is < 1. Printed for the defaults
at q_home and at the velocity plan's grasp configuration, with M(q) of the controllers' arm
model (links, lumped gripper, reflected rotor inertia).

    python benchmarks/explicit_loop_stability.py [--set KEY=VALUE ...]
"""

from __future__ import annotations

import argparse

import numpy as np


def spectral_radius(M: np.ndarray, K: np.ndarray, D: np.ndarray, h: float, implicit: bool):
    """Largest |eigenvalue| of one step of the linearized joint loop (see the module doc)."""
    identity = np.eye(len(M))
    if implicit:
        B = np.linalg.inv(M + h * D)
        A_vv, A_vq = B @ M, -h * B @ K
    else:
        M_inv = np.linalg.inv(M)
        A_vv, A_vq = identity - h * M_inv @ D, -h * M_inv @ K
    A = np.block([[identity + h * A_vq, h * A_vv], [A_vq, A_vv]])
    return float(np.max(np.abs(np.linalg.eigvals(A))))


def main() -> None:
    from doorlab import Scenario
    from doorlab.cell.geometry import scenario_door_geometry
    from doorlab.cell.station import joint_damping, make_controller_plant
    from doorlab.cli.commands import apply_overrides
    from doorlab.constants import Q_HOME
    from doorlab.episode.controllers import _grasp_configuration

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--set", dest="overrides", action="append", default=[])
    args = parser.parse_args()
    scenario = apply_overrides(Scenario(), args.overrides)
    config = scenario.station
    plant = make_controller_plant()
    context = plant.CreateDefaultContext()
    h = config.time_step
    K = np.diag(config.inner_loop.kq)
    D = np.diag(joint_damping(config))
    q_grasp = _grasp_configuration(scenario, scenario_door_geometry(scenario), plant)
    print(f"time step {1e3 * h:g} ms, Kq {config.inner_loop.kq}, acting damping {np.diag(D)}")
    for name, q in (("q_home", Q_HOME), ("grasp", q_grasp)):
        plant.SetPositions(context, q)
        M = plant.CalcMassMatrix(context)
        implicit = spectral_radius(M, K, D, h, implicit=True)
        explicit = spectral_radius(M, K, D, h, implicit=False)
        print(
            f"{name:7s} spectral radius: implicit damping {implicit:.5f}, "
            f"explicit damping {explicit:.5f} ({'stable' if explicit < 1 else 'UNSTABLE'})"
        )


if __name__ == "__main__":
    main()
