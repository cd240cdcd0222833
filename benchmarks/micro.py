"""Benchmark groups ``tick/*`` (one control tick) and ``ik/*`` (pointwise IK)."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable

from common import (
    IK10_TARGET_S,
    TICK_PERTURBATION,
    TICK_STATES,
    TICK_TARGET_US,
    Context,
    Metric,
    Settings,
)


def _pointwise_ik(ctx: Context, knots: int):
    """Pointwise IK along the arc exactly as ``doorlab.episode.controllers.build_ik_plan`` calls
    it."""
    from doorlab import Scenario
    from doorlab.constants import Q_HOME
    from doorlab.control.ik_pointwise import pointwise_ik

    scenario = Scenario(controller="ik")
    geometry = ctx.geometry()
    return pointwise_ik(
        ctx.plant(),
        geometry.p_WQ_ref,
        geometry.R_WL7_ref,
        duration=scenario.timeline.arc_duration,
        num_knots=knots,
        q_guess=Q_HOME,
        position_tolerance=scenario.ik.position_tolerance,
        theta_bound=scenario.ik.theta_bound,
        centered=scenario.ik.objective == "centered",
    )


def _arc_states(ctx: Context):
    """(times, states): TICK_STATES arm states along the arc, slightly off it."""
    import numpy as np
    from pydrake.trajectories import PiecewisePolynomial

    from doorlab import Scenario
    from doorlab.control.plans import ArmState

    def build():
        ik = _pointwise_ik(ctx, 10)
        zero = np.zeros((7, 1))
        spline = PiecewisePolynomial.CubicWithContinuousSecondDerivatives(
            ik.times, ik.q_knots.T, zero, zero
        )
        velocity = spline.derivative(1)
        duration = Scenario().timeline.arc_duration
        times = np.linspace(0.0, duration, TICK_STATES)
        rng = np.random.default_rng(0)
        states = [
            ArmState(
                spline.value(t).ravel() + rng.normal(0.0, TICK_PERTURBATION, 7),
                velocity.value(t).ravel(),
                np.zeros(7),
            )
            for t in times
        ]
        return [float(t) for t in times], states

    return ctx.get("arc_states", build)


def bench_tick(controller: str) -> Callable[[Settings, Context], list[Metric]]:
    def run(settings: Settings, ctx: Context) -> list[Metric]:
        import numpy as np

        from doorlab import Scenario
        from doorlab.episode.controllers import REGISTRY

        build = REGISTRY[controller].build
        scenario = Scenario(controller=controller)
        plan = build(scenario, ctx.geometry(), ctx.plant()).plan
        times, states = _arc_states(ctx)
        n = len(states)
        for i in range(100):  # warm-up
            plan.command(times[i % n], states[i % n])
        clock = time.perf_counter_ns
        medians, p90s, means = [], [], []
        for _ in range(settings.repeats):
            durations = np.empty(settings.tick_calls)
            for i in range(settings.tick_calls):
                t, state = times[i % n], states[i % n]
                start = clock()
                plan.command(t, state)
                durations[i] = clock() - start
            durations /= 1e3  # [us]
            medians.append(float(np.median(durations)))
            p90s.append(float(np.percentile(durations, 90)))
            means.append(float(np.mean(durations)))
        return [
            Metric(
                f"tick/{controller}",
                f"tick/{controller}",
                "us",
                medians,
                target=("<", TICK_TARGET_US),
                info={
                    "calls_per_repeat": settings.tick_calls,
                    "p90_us": statistics.median(p90s),
                    "mean_us": statistics.median(means),
                    "plan": type(plan).__name__,
                },
            )
        ]

    return run


def bench_ik(knots: int) -> Callable[[Settings, Context], list[Metric]]:
    def run(settings: Settings, ctx: Context) -> list[Metric]:
        _pointwise_ik(ctx, 2)  # warm-up: solver libraries, first-call costs
        samples, result = [], None
        for _ in range(settings.repeats):
            start = time.perf_counter()
            result = _pointwise_ik(ctx, knots)
            samples.append(time.perf_counter() - start)
        name = f"ik/{knots}_knots"
        return [
            Metric(
                name,
                name,
                "s",
                samples,
                target=("<", IK10_TARGET_S) if knots == 10 else None,
                info={
                    "solver": result.solver,
                    "max_position_residual_m": float(max(result.position_residuals)),
                },
            )
        ]

    return run
