"""The episode advances in chunks (so signals are handled during C++-only episodes), with logs
bit-identical to one ``AdvanceTo`` call (issue 19; the cost: benchmarks/chunked_advance.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

import doorlab.episode.simulation as simulation
from doorlab.config import Scenario
from doorlab.episode.controllers import run_controller

CHANNELS = (
    "t",
    "q_commanded",
    "q_measured",
    "v_measured",
    "tau_external",
    "tau_feedforward",
    "tau_commanded",
    "door_angles",
    "wsg_width",
    "plant_positions",
)


def _short(controller: str) -> Scenario:
    scenario = Scenario(controller=controller, doors="closed")
    t = scenario.timeline
    t.hold_duration, t.approach_duration, t.grasp_duration = 0.1, 1.0, 0.2
    t.arc_duration, t.extra_time = 2.0, 0.3
    return scenario


@pytest.mark.slow
@pytest.mark.parametrize("controller", ["ik", "velocity"])
def test_chunks_give_the_logs_of_one_call_bit_for_bit(controller, monkeypatch):
    """IK (C++ systems only) and the velocity plan (a Python runner): the default chunk and an
    odd one (off every event grid) reproduce one AdvanceTo exactly."""
    logs = {}
    for chunk in (math.inf, simulation.ADVANCE_CHUNK_S, 0.0371):
        monkeypatch.setattr(simulation, "ADVANCE_CHUNK_S", chunk)
        logs[chunk], _ = run_controller(_short(controller))
    one = logs.pop(math.inf)
    for chunk, result in logs.items():
        for name in CHANNELS:
            assert np.array_equal(getattr(result, name), getattr(one, name)), (chunk, name)


def test_the_advance_returns_to_python_every_chunk(monkeypatch):
    """Each AdvanceTo call covers at most one chunk (paced: at most rate x 0.1 s of it)."""
    targets = []

    class Recorder:
        def __init__(self):
            self.t = 0.0

        def get_context(self):
            return self

        def get_time(self):
            return self.t

        def AdvanceTo(self, t):
            targets.append(t)
            self.t = t

    simulation.advance_interruptibly(Recorder(), 1.0)
    assert np.allclose(np.diff([0.0, *targets]), simulation.ADVANCE_CHUNK_S)
    assert targets[-1] == 1.0
    targets.clear()
    simulation.advance_interruptibly(Recorder(), 0.1, realtime_rate=0.1)
    steps = np.diff([0.0, *targets])
    assert steps.max() <= 0.1 * simulation.MAX_PACED_CHUNK_WALL_S + 1e-12
    assert targets[-1] == 0.1
