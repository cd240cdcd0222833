"""Benchmark group ``design/<controller>_<doors>``: the episode against Drake's floor and the
old (353b732) design, side by side in one process, round-robin over the repeats.

Per repeat, three simulations of the same 24 s episode, each timed around its advance only
(``Simulator.AdvanceTo`` for the floor; the episode's ``advance_interruptibly``, the
simulator's steps and the plan runner's ticks, for the others; no IK, no diagram building):

``floor``
    The same cell (the current station) with the episode's commands (q_ref, tau_ff every
    control period, the gripper setpoint) replayed from C++ ``TrajectorySource``s: no Python,
    no loggers. What Drake itself costs for this episode.
``python``
    The episode's own machinery (the Python plan runner at every control tick, the loggers)
    with a plan that does no work: it replays the recorded commands. ``python / floor`` is
    what a Python outer loop at the control rate costs before any control law runs, a
    floor for ``new`` as long as the laws run in Python.
``new``
    The episode as ``doorlab.run_controller`` runs it (``EpisodeResult.wall_time_s``).
``old``
    The 353b732 design (:mod:`doorlab.studies.legacy`): PD actuators, the whole scene colliding,
    Python ticks from t = 0.

Each is timed twice: wall-clock (``*_s``) and the CPU time of this process (``*_cpu_s``,
``time.process_time``), which other processes on a shared machine disturb far less (they
still share caches and memory bandwidth). Ratios are formed per repeat from the CPU times
(the four ran back to back) and their median is reported: ``new_over_floor`` (target
<= 1.15), ``old_over_new`` (>= 1.3), ``python_over_floor`` and ``new_over_python`` (their
product is ``new_over_floor``: the machinery's share and the law's); ``*_wall`` are the
first two from wall times.
"""

from __future__ import annotations

import contextlib
import gc
import statistics
import time
from collections.abc import Iterator, Sequence

from common import Context, CpuWatch, Metric, Settings

NEW_OVER_FLOOR_TARGET = 1.15
OLD_OVER_NEW_TARGET = 1.3


def recorded_commands(controller: str, doors: str, *, scenario=None):
    """Runs the episode once with the logs at the control period; returns (scenario, result).

    ``scenario``: run this one (its controller and doors) instead of the default episode.
    """
    from doorlab import Scenario, run_controller

    if scenario is None:
        scenario = Scenario(controller=controller, doors=doors)
    log_period = scenario.timeline.log_period
    scenario.timeline.log_period = scenario.timeline.control_period
    result, _ = run_controller(scenario)
    scenario.timeline.log_period = log_period
    return scenario, result


def build_floor(scenario, result):
    """A Simulator of the station driven by the recorded commands; returns (simulator, t_final).

    Every source is a C++ trajectory (zero-order holds at the recorded samples), so a step of
    this simulator costs what the plant and the inner loop cost, nothing else.
    """
    import numpy as np
    from pydrake.systems.analysis import ResetIntegratorFromFlags, Simulator
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import ConstantVectorSource, TrajectorySource
    from pydrake.trajectories import PiecewisePolynomial

    from doorlab.cell.station import build_station
    from doorlab.constants import Q_HOME
    from doorlab.episode.simulation import _initialize

    builder = DiagramBuilder()
    station = build_station(scenario.station)
    system = builder.AddSystem(station.diagram)
    t = result.t
    breaks = np.append(t, t[-1] + 1.0)

    def zoh(samples: np.ndarray) -> TrajectorySource:
        samples = np.vstack([samples, samples[-1:]]).T
        return builder.AddSystem(
            TrajectorySource(PiecewisePolynomial.ZeroOrderHold(breaks, samples))
        )

    for port, samples in (
        ("iiwa_position", result.q_commanded),
        ("iiwa_feedforward_torque", result.tau_feedforward),
    ):
        builder.Connect(zoh(samples).get_output_port(), system.GetInputPort(port))
    # The setpoint the schedule sent (result.wsg_width is the measured separation).
    gripper = scenario.station.gripper
    grasp_start = result.plan_starts[2]  # hold, move, then the grasp closes the fingers
    width = np.where(t < grasp_start, gripper.approach_width, gripper.grasp_width)
    builder.Connect(zoh(width[:, None]).get_output_port(), system.GetInputPort("wsg_position"))
    force = builder.AddSystem(ConstantVectorSource([gripper.force_limit]))
    builder.Connect(force.get_output_port(), system.GetInputPort("wsg_force_limit"))
    diagram = builder.Build()
    simulator = Simulator(diagram)
    ResetIntegratorFromFlags(simulator, "explicit_euler", scenario.station.time_step)
    _initialize(station, simulator.get_mutable_context(), Q_HOME, scenario)
    return simulator, float(t[-1])


@contextlib.contextmanager
def advance_clock() -> Iterator[list[float]]:
    """Within the block, sums the wall and CPU time [s] of every episode's advance
    (``doorlab.episode.simulation.advance_interruptibly``: the simulator's steps and the plan
    runner's ticks between its stops, which run outside ``Simulator.AdvanceTo``)."""
    from doorlab.episode import simulation

    spent = [0.0, 0.0]
    original = simulation.advance_interruptibly

    def timed(*args, **kwargs):
        wall, cpu = time.perf_counter(), time.process_time()
        try:
            return original(*args, **kwargs)
        finally:
            spent[0] += time.perf_counter() - wall
            spent[1] += time.process_time() - cpu

    simulation.advance_interruptibly = timed
    try:
        yield spent
    finally:
        simulation.advance_interruptibly = original


def time_floor(scenario, result) -> tuple[float, float]:
    """Wall and CPU time [s] of one floor episode (Initialize and AdvanceTo)."""
    simulator, t_final = build_floor(scenario, result)
    wall, cpu = time.perf_counter(), time.process_time()
    simulator.Initialize()
    simulator.AdvanceTo(t_final)
    return time.perf_counter() - wall, time.process_time() - cpu


class ReplayPlan:
    """A plan that sends, at each tick, the command a recorded episode sent there (no law)."""

    def __init__(self, result, t_start: float, period: float):
        # Logged at the control period: the sample at t_k + period holds the command of the
        # tick at t_k (the log at t shows what the plant steps with at t).
        self.name = "replay"
        self.duration = float(result.arc_window[1] - result.arc_window[0])
        self._t0 = t_start
        self._period = period
        self._t = result.t
        self._q_ref = result.q_commanded
        self._tau_ff = result.tau_feedforward

    def command(self, t: float, state):
        from doorlab.control.plans import Command

        i = min(round((self._t0 + t) / self._period) + 1, len(self._t) - 1)
        return Command(self._q_ref[i], self._tau_ff[i])


def replay_episode(scenario, result):
    """The episode's own machinery with :class:`ReplayPlan` as the arc plan (the grasp held
    at the recorded start), returning its :class:`~doorlab.episode.result.EpisodeResult`."""
    import numpy as np

    from doorlab.control.plans import JointSpacePlan
    from doorlab.episode.simulation import run_episode

    arc_start = result.plan_starts[3]
    q_start = result.q_commanded[np.searchsorted(result.t, arc_start) - 1]
    grasp = JointSpacePlan.hold(q_start, scenario.timeline.grasp_duration, name="grasp")
    replay = ReplayPlan(result, arc_start, scenario.timeline.control_period)
    width = scenario.station.gripper.grasp_width
    return run_episode(scenario, [grasp, replay], [width, width], q_start=q_start)


def time_python_floor(scenario, result) -> tuple[float, float]:
    """Wall and CPU time [s] of the episode's machinery replaying ``result``'s commands."""
    with advance_clock() as spent:
        replay_episode(scenario, result)
    return spent[0], spent[1]


def time_episode(run, scenario) -> tuple[float, float, float]:
    """(wall, CPU, simulated) time [s] of ``run(scenario)``'s simulation."""
    with advance_clock() as spent:
        result, _ = run(scenario)
    return spent[0], spent[1], result.sim_time_s


def bench_designs(names: Sequence[str], settings: Settings, ctx: Context) -> list[Metric]:
    """floor / new / old for each selected ``design/<controller>_<doors>``, round-robin."""
    from doorlab import Scenario, run_controller
    from doorlab.studies.legacy import run_legacy_controller

    ctx.warm()
    recorded = {}
    for name in names:
        controller, doors = name.split("/", 1)[1].split("_")
        recorded[name] = recorded_commands(controller, doors)
    keys = [f"{v}_{u}" for v in ("floor", "python", "new", "old") for u in ("s", "cpu_s")]
    keys += ["new_over_floor", "old_over_new", "new_over_floor_wall", "old_over_new_wall"]
    keys += ["python_over_floor", "new_over_python"]
    keys += ["new_rtf"]
    samples = {n: {k: [] for k in keys} for n in names}
    watches = {n: [] for n in names}
    for _ in range(settings.repeats):
        for name in names:
            controller, doors = name.split("/", 1)[1].split("_")
            scenario = Scenario(controller=controller, doors=doors)
            watch = CpuWatch()
            times = {"floor": time_floor(*recorded[name])}
            gc.collect()
            if controller != "ik":  # an IK episode has no Python tick to replay
                times["python"] = time_python_floor(*recorded[name])
                gc.collect()
            wall, cpu, sim_time = time_episode(run_controller, scenario)
            times["new"] = (wall, cpu)
            gc.collect()
            times["old"] = time_episode(run_legacy_controller, scenario)[:2]
            gc.collect()
            watches[name].append(watch.other_cores())
            s = samples[name]
            for variant, (wall, cpu) in times.items():
                s[f"{variant}_s"].append(wall)
                s[f"{variant}_cpu_s"].append(cpu)
            s["new_over_floor"].append(times["new"][1] / times["floor"][1])
            s["old_over_new"].append(times["old"][1] / times["new"][1])
            s["new_over_floor_wall"].append(times["new"][0] / times["floor"][0])
            s["old_over_new_wall"].append(times["old"][0] / times["new"][0])
            s["new_rtf"].append(sim_time / times["new"][0])
            if "python" in times:
                s["python_over_floor"].append(times["python"][1] / times["floor"][1])
                s["new_over_python"].append(times["new"][1] / times["python"][1])
            print(
                f"  {name}: CPU floor {times['floor'][1]:.2f} s, "
                f"python {times.get('python', (0.0, float('nan')))[1]:.2f} s, "
                f"new {times['new'][1]:.2f} s, "
                f"old {times['old'][1]:.2f} s (new/floor {s['new_over_floor'][-1]:.2f}, "
                f"old/new {s['old_over_new'][-1]:.2f})",
                flush=True,
            )
    metrics = []
    for name in names:
        s = samples[name]
        other = [w for w in watches[name] if w is not None]
        targets = {
            "new_over_floor": ("<", NEW_OVER_FLOOR_TARGET),
            "old_over_new": (">=", OLD_OVER_NEW_TARGET),
        }
        produced = [
            Metric(
                f"{name}/{key}",
                name,
                "s" if key.endswith("_s") else "x",
                values,
                better="higher"
                if key in ("old_over_new", "old_over_new_wall", "new_rtf")
                else "lower",
                target=targets.get(key),
            )
            for key, values in s.items()
            if values  # no python variant for IK
        ]
        for m in produced:
            m.other_cpu_cores = statistics.mean(other) if other else None
        metrics += produced
    return metrics
