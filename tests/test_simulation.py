"""The episode timeline and the log container, without simulating."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from doorlab.config import Scenario
from doorlab.constants import Q_HOME
from doorlab.control.plans import JointSpacePlan
from doorlab.episode.plan_runner import PlanRunner
from doorlab.episode.result import EpisodeResult
from doorlab.episode.schedule import PLAN_SETTLE_TIME, make_schedule
from doorlab.errors import ConfigError

Q_START = Q_HOME + 0.1


def problem_set_schedule(scenario: Scenario):
    grasp = JointSpacePlan.hold(Q_START, scenario.timeline.grasp_duration, name="grasp")
    arc = JointSpacePlan.hold(Q_START, scenario.timeline.arc_duration, name="arc")
    return make_schedule(
        [grasp, arc], [0.005, 0.005], q_initial=Q_HOME, q_start=Q_START, scenario=scenario
    )


def test_default_schedule_is_the_originals_timeline():
    """Hold 0-2 s, move 2-9 s, grasp 9-11 s, arc 11-22 s (10 s + 1 s): the problem set's
    t = 11 s."""
    schedule = problem_set_schedule(Scenario())
    assert [s.plan.name for s in schedule] == ["hold", "move_to_start", "grasp", "arc"]
    assert [s.t_start for s in schedule] == [0.0, 2.0, 9.0, 11.0]
    assert schedule[-1].t_end == 22.0
    assert all(s.t_end - s.t_start == s.plan.duration + PLAN_SETTLE_TIME for s in schedule)
    approach = Scenario().station.gripper.approach_width
    assert [s.gripper_width for s in schedule] == [approach, approach, 0.005, 0.005]


def test_move_plan_joins_the_initial_and_start_configurations_at_rest():
    """The cubic move starts at q_initial and ends at q_start with zero velocity at both."""
    move = problem_set_schedule(Scenario())[1].plan
    traj = move.trajectory
    np.testing.assert_allclose(traj.value(traj.start_time()).ravel(), Q_HOME, atol=1e-12)
    np.testing.assert_allclose(traj.value(traj.end_time()).ravel(), Q_START, atol=1e-12)
    for t in (traj.start_time(), traj.end_time()):
        np.testing.assert_allclose(traj.EvalDerivative(t, 1).ravel(), 0.0, atol=1e-12)


def test_plan_runner_picks_the_active_plan_in_any_order():
    """At each boundary the next plan takes over; after the schedule the last plan holds;
    asking for an earlier time (e.g. a re-initialized simulator) steps back."""
    schedule = problem_set_schedule(Scenario())
    runner = PlanRunner(schedule, control_period=0.005)
    names = [runner.active(t).plan.name for t in (0.0, 1.999, 2.0, 9.0, 10.99, 11.0, 30.0)]
    assert names == ["hold", "hold", "move_to_start", "grasp", "grasp", "arc", "arc"]
    assert runner.active(0.5).plan.name == "hold"


def test_schedule_needs_one_gripper_setpoint_per_plan():
    """Mismatched plan and setpoint lists are a configuration error, not an IndexError."""
    with pytest.raises(ConfigError, match="one gripper setpoint per plan"):
        make_schedule(
            [JointSpacePlan.hold(Q_START, 1.0)],
            [],
            q_initial=Q_HOME,
            q_start=Q_START,
            scenario=Scenario(),
        )


def test_episode_result_round_trips_through_npz(tmp_path):
    """save then load gives back every channel exactly."""
    rng = np.random.default_rng(0)
    n = 17
    result = EpisodeResult(
        t=np.arange(n) * 0.01,
        **{
            name: rng.normal(size=(n, 7))
            for name in (
                "q_commanded",
                "q_measured",
                "v_measured",
                "tau_external",
                "tau_feedforward",
                "tau_commanded",
            )
        },  # fmt: skip
        door_angles=rng.normal(size=(n, 2)),
        wsg_width=rng.normal(size=n),
        plant_positions=rng.normal(size=(n, 11)),
        plan_names=("hold", "move_to_start", "grasp", "arc"),
        plan_starts=np.array([0.0, 2.0, 9.0, 11.0]),
        arc_window=np.array([11.0, 21.0]),
        wall_time_s=1.25,
        scenario_yaml="controller: ik\n",
    )
    result.save(tmp_path / "log.npz")
    loaded = EpisodeResult.load(tmp_path / "log.npz")
    for field in dataclasses.fields(EpisodeResult):
        a, b = getattr(result, field.name), getattr(loaded, field.name)
        if isinstance(a, np.ndarray):
            np.testing.assert_array_equal(a, b)
        else:
            assert a == b, field.name


def test_a_plan_sending_nan_stops_the_run_with_a_simulation_error():
    """A buggy plan (NaN q_ref) is caught by the plant and reported with the time, not a
    raw Drake traceback."""
    from doorlab.control.plans import Command
    from doorlab.episode.simulation import run_episode
    from doorlab.errors import SimulationError

    class NanPlan:
        name, duration = "nan", 0.5

        def command(self, t, state):
            return Command(np.full(7, np.nan), np.zeros(7))

    scenario = Scenario()
    t = scenario.timeline
    t.hold_duration, t.approach_duration, t.extra_time = 0.1, 0.2, 0.1
    with pytest.raises(SimulationError, match=r"failed at t = 2\.30\d s: .*NaN"):
        run_episode(scenario, [NanPlan()], [0.02], q_start=Q_HOME)


def test_joint_space_plans_in_cpp_send_what_the_runner_sent():
    """Without feedback plans (an IK episode) the C++ sources replace the Python runner: the
    logged q_ref equals, sample for sample, the plans evaluated at the runner's ticks, each
    sample in force from the first plant step after its tick (the log at a tick shows the
    previous tick's command, as the runner's discrete state did)."""
    from doorlab.episode.simulation import run_episode

    scenario = Scenario()
    scenario.timeline.hold_duration = 0.2
    scenario.timeline.approach_duration = 0.3
    scenario.timeline.extra_time = 0.0
    move = JointSpacePlan.cubic([0.0, 0.3], np.vstack([Q_START, Q_START + 0.05]), name="arc")
    result = run_episode(scenario, [move], [0.005], q_start=Q_START)
    schedule = make_schedule([move], [0.005], q_initial=Q_HOME, q_start=Q_START, scenario=scenario)
    runner = PlanRunner(schedule, control_period=scenario.timeline.control_period)
    period = scenario.timeline.control_period
    state = None
    for t, q_logged in zip(result.t[1:], result.q_commanded[1:], strict=True):
        tick = (np.ceil(t / period - 1e-6) - 1) * period  # the last tick strictly before t
        scheduled = runner.active(tick)
        expected = scheduled.plan.command(tick - scheduled.t_start, state).q_ref
        np.testing.assert_allclose(q_logged, expected, atol=1e-12, rtol=0)


@pytest.mark.parametrize("time_step_us", [2000, 3000])
def test_a_tick_sees_the_arm_after_the_steps_up_to_it_and_acts_from_the_next(time_step_us):
    """At every tick t_k, on a plant step or between two, the plan sees the arm as logged at
    the first plant step after t_k (a log at t shows the state before the step at t), and that
    step runs on its command. The ticks that fall on a step are the ones float rounding used
    to get wrong: with events at t_k itself, about one in five (5 ms ticks, 2 ms steps) saw
    the arm a step earlier and acted a step sooner. A 3 ms step checks a grid the ticks share
    less often (every third tick on a step)."""
    from doorlab.control.plans import Command
    from doorlab.episode.simulation import run_episode

    seen: list[tuple[float, np.ndarray, np.ndarray]] = []

    class Probe:
        name, duration = "probe", 0.6

        def command(self, t, state):
            q_ref = state.q + 1e-3 * np.sin(40.0 * t)  # a new command at every tick
            seen.append((t, state.q.copy(), q_ref))
            return Command(q_ref, np.zeros(7))

    scenario = Scenario()
    scenario.station.time_step = time_step_us * 1e-6
    timeline = scenario.timeline
    # The probe starts at 4.3 s, where (2 ms steps) 49 of the 160 ticks on a step have event
    # times an ulp before the step's (offset + k 5 ms against n 2 ms, as Drake sums them).
    timeline.hold_duration, timeline.approach_duration, timeline.extra_time = 0.1, 2.2, 0.0
    timeline.log_period = scenario.station.time_step
    result = run_episode(scenario, [Probe()], [0.02], q_start=Q_HOME)
    t_start = result.plan_starts[-1]
    on_step = 0
    for t, q_seen, q_ref in seen:
        tick = t_start + t
        steps = tick / scenario.station.time_step
        on_step += abs(steps - round(steps)) < 1e-6
        i = np.searchsorted(result.t, tick + 1e-9)  # the first step after the tick
        np.testing.assert_array_equal(result.q_measured[i], q_seen, err_msg=f"tick {tick}")
        np.testing.assert_allclose(result.q_commanded[i], q_ref, atol=1e-12, rtol=0)
    # (0.6 s + 1 s settle) / 5 ms ticks from 4.3 s; on a step: 4300 + 5 k ms divisible by h.
    ticks_ms = [4300 + 5 * k for k in range(320)]
    assert len(seen) == 320
    assert on_step == sum(t * 1000 % time_step_us == 0 for t in ticks_ms) > 0


def test_the_simulated_episode_has_no_python_system():
    """The plan runner ticks between simulator stops, not as a system of the diagram: every
    system of a velocity-like episode (station, wiring, logger) is one of Drake's C++ systems.
    A Python LeafSystem anywhere in it would cost Python at every plant step (Drake asks each
    subsystem for witness functions after every discrete update; pydrake answers for a
    Python one through the GIL), whatever its own events."""
    from pydrake.systems.framework import Diagram

    from doorlab.control.plans import Command
    from doorlab.episode.simulation import build_simulated_episode

    class Feedback:  # any plan that is not a joint-space plan needs the runner
        name, duration = "feedback", 0.1

        def command(self, t, state):
            return Command(state.q, np.zeros(7))

    scenario = Scenario()
    schedule = make_schedule(
        [Feedback()], [0.02], q_initial=Q_HOME, q_start=Q_START, scenario=scenario
    )
    episode = build_simulated_episode(scenario, schedule, q_initial=Q_HOME)
    assert episode.commands.runner is not None

    def leaves(diagram):
        for system in diagram.GetSystems():
            yield from leaves(system) if isinstance(system, Diagram) else (system,)

    python = [
        f"{s.get_name()} ({type(s).__module__}.{type(s).__name__})"
        for s in leaves(episode.diagram)
        if not type(s).__module__.startswith("pydrake.")
    ]
    assert python == []
