"""Robustness to an unknown hinge: every controller against the cupboard's yaw error.

The true cupboard is the believed one turned by ``station.cupboard_yaw_error`` about the
left handle's vertical axis (:func:`doorlab.cell.geometry.true_door_geometry`). The problem set's
plans follow the believed arc; the adaptive plan estimates the hinge. This module

- runs a controller on a yaw error and reduces the episode to one :class:`RobustnessRow`
  (:func:`run_case`, :func:`run_grid` in parallel processes);
- finds the largest yaw error up to which a controller opens the door
  (:func:`largest_opening_yaw`: a scan outwards, then bisection);
- turns rows and results into a Markdown table and figures (:func:`robustness_table`,
  :func:`plot_robustness`; the adaptive plan's :func:`doorlab.outputs.plots.plot_hinge_convergence`,
  which a run folder draws too) without re-running anything.

"Opens" means: status ok, the door turned by at least :data:`OPEN_THRESHOLD_DEG` by the arc's
end (t = 21 s of the problem set's timeline), and the handle is still between the fingers at the
episode's end.
"""

from __future__ import annotations

import concurrent.futures
import copy
import dataclasses
import math
import multiprocessing
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

from doorlab.cell.geometry import DoorGeometry, true_door_geometry
from doorlab.config import Scenario, validate
from doorlab.episode.result import EpisodeResult
from doorlab.errors import IkError, SimulationError

OPEN_THRESHOLD_DEG = 39.0
"""A door counts as opened from this rotation at the arc's end on [deg] (the acceptance's)."""

ACCEPTANCE_YAW_ERRORS_DEG = (-10.0, -5.0, 0.0, 5.0, 10.0)
"""The acceptance grid of cupboard yaw errors [deg]."""


@dataclass(frozen=True)
class RobustnessRow:
    """One controller on one yaw error (SI units; NaN where the run produced no episode).

    Attributes:
        controller: Registry name. yaw_error_rad: station.cupboard_yaw_error [rad].
        status: The run's status (ok, slipped, speed_limit, diverged, ik_failed).
        door_opening_rad: Door rotation at the arc's end (t = arc_window[1]) [rad]: the
            primary figure, the one "opens" is judged by.
        door_opening_final_rad: Door rotation at the episode's end [rad].
        handle_held: Handle between the fingers at the end.
        peak_contact_torque_arc_Nm: Peak |external joint torque| during the arc [N m].
        peak_contact_force_arc_N: Peak |contact force at Q| during the arc [N].
        max_radial_error_m: Max |radial error of Q| against the TRUE arc [m].
        hinge_estimate_error_m: Final hinge estimate's error (adaptive only) [m].
    """

    controller: str
    yaw_error_rad: float
    status: str
    door_opening_rad: float
    door_opening_final_rad: float
    handle_held: bool | None
    peak_contact_torque_arc_Nm: float
    peak_contact_force_arc_N: float
    max_radial_error_m: float
    hinge_estimate_error_m: float | None

    @property
    def opened(self) -> bool:
        """Status ok, door turned >= OPEN_THRESHOLD_DEG, handle held."""
        return bool(
            self.status == "ok"
            and self.handle_held
            and self.door_opening_rad >= math.radians(OPEN_THRESHOLD_DEG)
        )

    def to_dict(self) -> dict:
        """JSON-ready dictionary (with ``opened``)."""
        return {**dataclasses.asdict(self), "opened": self.opened}


def case_scenario(base: Scenario, controller: str, yaw_error_rad: float) -> Scenario:
    """``base`` with the controller, closed doors and the yaw error set (a copy, validated)."""
    scenario = copy.deepcopy(base)
    scenario.controller = controller
    scenario.doors = "closed"
    scenario.door_angles = None
    scenario.station.cupboard_yaw_error = float(yaw_error_rad)
    return validate(scenario)


def run_case(
    base: Scenario, controller: str, yaw_error_rad: float
) -> tuple[RobustnessRow, EpisodeResult | None]:
    """Runs one controller on one yaw error.

    Returns:
        The row and the episode (None when IK or the physics failed: the row says which).
    """
    from doorlab.episode.controllers import run_controller
    from doorlab.episode.metrics import compute_metrics

    scenario = case_scenario(base, controller, yaw_error_rad)
    nan = float("nan")
    try:
        result, _ = run_controller(scenario)
    except (IkError, SimulationError) as e:
        status = "ik_failed" if isinstance(e, IkError) else "diverged"
        return RobustnessRow(
            controller, yaw_error_rad, status, nan, None, nan, nan, nan, None
        ), None
    m = compute_metrics(result, scenario, true_door_geometry(scenario))
    row = RobustnessRow(
        controller=controller,
        yaw_error_rad=float(yaw_error_rad),
        status=m.status,
        door_opening_rad=m.door_opening_arc_end_rad,
        door_opening_final_rad=m.door_opening_rad,
        handle_held=m.handle_held,
        peak_contact_torque_arc_Nm=m.peak_external_torque_arc_Nm,
        peak_contact_force_arc_N=m.peak_contact_force_arc_N,
        max_radial_error_m=m.max_radial_error_m,
        hinge_estimate_error_m=m.hinge_estimate_error_m,
    )
    return row, result


def row_from_metrics(metrics: Mapping, yaw_error_rad: float) -> RobustnessRow:
    """A row from a run folder's ``metrics.json`` (a dict with DoorMetrics' keys, or the
    ``{"controller", "doors", "status", "error"}`` of a failed run): for a report that ran the
    cases as run folders and re-runs nothing.
    """
    nan = float("nan")

    def number(key: str) -> float:
        value = metrics.get(key)
        return nan if value is None else float(value)

    hinge = metrics.get("hinge_estimate_error_m")
    if hinge is not None and not math.isfinite(float(hinge)):
        hinge = None
    held = metrics.get("handle_held")
    held = None if held is None or (isinstance(held, float) and math.isnan(held)) else bool(held)
    return RobustnessRow(
        controller=str(metrics["controller"]),
        yaw_error_rad=float(yaw_error_rad),
        status=str(metrics["status"]),
        door_opening_rad=number("door_opening_arc_end_rad"),
        door_opening_final_rad=number("door_opening_rad"),
        handle_held=held,
        peak_contact_torque_arc_Nm=number("peak_external_torque_arc_Nm"),
        peak_contact_force_arc_N=number("peak_contact_force_arc_N"),
        max_radial_error_m=number("max_radial_error_m"),
        hinge_estimate_error_m=None if hinge is None else float(hinge),
    )


def rows_from_sweep(frame, *, yaw_field: str = "station.cupboard_yaw_error") -> list:
    """Rows from a :mod:`doorlab.sweep` results table (one row per run, doors closed, an axis
    over ``station.cupboard_yaw_error``), e.g. ``examples/sweep_hinge_error.yaml``'s: the
    report can build its robustness section from a sweep without re-running anything.

    Args:
        frame: The sweep's results table (a pandas DataFrame).
        yaw_field: The column holding the yaw error [rad].

    Returns:
        RobustnessRow per run, in (controller, yaw error) order.
    """
    rows = [
        row_from_metrics(record, float(record[yaw_field]))
        for record in frame.to_dict(orient="records")
    ]
    return sorted(rows, key=lambda r: (r.controller, r.yaw_error_rad))


def _row_only(base: Scenario, controller: str, yaw_error_rad: float) -> RobustnessRow:
    return run_case(base, controller, yaw_error_rad)[0]


def run_grid(
    base: Scenario,
    controllers: Sequence[str],
    yaw_errors_rad: Sequence[float],
    *,
    jobs: int = 1,
) -> list[RobustnessRow]:
    """Every controller on every yaw error, ``jobs`` episodes at a time (processes).

    Returns:
        Rows in (controller, yaw error) order.
    """
    cases = [(c, float(y)) for c in controllers for y in yaw_errors_rad]
    if jobs <= 1:
        return [_row_only(base, c, y) for c, y in cases]
    context = multiprocessing.get_context("spawn")  # Drake objects do not survive fork
    with concurrent.futures.ProcessPoolExecutor(jobs, mp_context=context) as pool:
        futures = [pool.submit(_row_only, base, c, y) for c, y in cases]
        return [f.result() for f in futures]


@dataclass(frozen=True)
class LargestYaw:
    """The largest |yaw error| a controller opens the door at, on one side.

    Attributes:
        controller: Registry name. sign: +1 or -1 (the side of the yaw error).
        opened_rad: Largest |yaw| found that opens [rad] (the lower end of the bracket).
        failed_rad: The |yaw| past opened_rad found not to open [rad] (nan: none up to the cap).
        runs: Episodes it took.
    """

    controller: str
    sign: int
    opened_rad: float
    failed_rad: float
    runs: int


def largest_opening_yaw(
    base: Scenario,
    controller: str,
    sign: int,
    *,
    opened_rad: float = 0.0,
    step_rad: float = math.radians(2.5),
    cap_rad: float = math.radians(45.0),
    tolerance_rad: float = math.radians(0.5),
) -> LargestYaw:
    """The largest |yaw error| on one side up to which ``controller`` opens the door at every
    yaw tried: a scan outwards in ``step_rad`` steps to the first failure, then bisection
    between the last success and it.

    Success need not be monotone (the adaptive plan's grasp hits the door at some large yaw
    errors and not at larger ones), so the result is the edge of the range that opens from
    ``opened_rad`` outwards; a failing island narrower than the step could be missed.

    Args:
        opened_rad: A |yaw| known to open (e.g. from the grid) [rad]: the scan starts there.
        step_rad: Scan step [rad].
        cap_rad: Largest |yaw| tried [rad] (the scenario's own limit is 45 deg).
        tolerance_rad: Bisection stops when the bracket is this narrow [rad].
    """
    runs = 0
    lo, hi = float(opened_rad), float("nan")
    steps = math.ceil((cap_rad - lo) / step_rad - 1e-9)  # no float drift past the cap
    for k in range(1, steps + 1):
        trial = min(float(opened_rad) + k * step_rad, cap_rad)
        runs += 1
        if run_case(base, controller, sign * trial)[0].opened:
            lo = trial
        else:
            hi = trial
            break
    if not math.isfinite(hi):
        return LargestYaw(controller, sign, lo, hi, runs)
    while hi - lo > tolerance_rad:
        mid = (lo + hi) / 2
        runs += 1
        if run_case(base, controller, sign * mid)[0].opened:
            lo = mid
        else:
            hi = mid
    return LargestYaw(controller, sign, lo, hi, runs)


def robustness_table(rows: Iterable[RobustnessRow]) -> str:
    """Markdown table: one line per (controller, yaw error), in the given order."""
    lines = [
        "| controller | yaw error [deg] | status | door opened at the arc's end / at the "
        "episode's end [deg] | handle held | "
        "peak contact torque in the arc [N m] | peak contact force at Q [N] | "
        "max radial error, true arc [mm] | final hinge estimate error [mm] |",
        "|---|---|---|---|---|---|---|---|---|",
    ]

    def num(value: float | None, scale: float = 1.0, digits: int = 2) -> str:
        if value is None or not math.isfinite(value):
            return "-"
        return f"{value * scale:.{digits}f}"

    for r in rows:
        held = {True: "yes", False: "no"}.get(r.handle_held, "-")
        lines.append(
            f"| {r.controller} | {math.degrees(r.yaw_error_rad):+.1f} | {r.status} | "
            f"{num(r.door_opening_rad, 180.0 / math.pi, 1)} / "
            f"{num(r.door_opening_final_rad, 180.0 / math.pi, 1)} | "
            f"{held} | {num(r.peak_contact_torque_arc_Nm)} | {num(r.peak_contact_force_arc_N)} | "
            f"{num(r.max_radial_error_m, 1e3, 1)} | {num(r.hinge_estimate_error_m, 1e3, 1)} |"
        )
    return "\n".join(lines)


def plot_robustness(rows: Sequence[RobustnessRow]):
    """Door opened and peak contact torque in the arc against the yaw error, per controller.

    Returns:
        A matplotlib Figure with two panels.
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 4), constrained_layout=True)
    ax_door, ax_torque = fig.subplots(1, 2)
    controllers = list(dict.fromkeys(r.controller for r in rows))
    for name in controllers:
        mine = sorted((r for r in rows if r.controller == name), key=lambda r: r.yaw_error_rad)
        yaw = [math.degrees(r.yaw_error_rad) for r in mine]
        door = [math.degrees(r.door_opening_rad) for r in mine]
        (line,) = ax_door.plot(yaw, door, "o-", label=name)
        failed = [(y, d) for y, d, r in zip(yaw, door, mine, strict=True) if not r.opened]
        if failed:
            ax_door.plot(*zip(*failed, strict=True), "x", color=line.get_color(), ms=10)
        ax_torque.plot(yaw, [r.peak_contact_torque_arc_Nm for r in mine], "o-", label=name)
    ax_door.axhline(OPEN_THRESHOLD_DEG, color="k", lw=0.8, ls="--")
    ax_door.set(
        xlabel="cupboard yaw error [deg]",
        ylabel="door opened at the arc's end [deg]",
        title=f"Door opened (x: not opened, i.e. < {OPEN_THRESHOLD_DEG:g} deg or handle lost)",
    )
    ax_torque.set(
        xlabel="cupboard yaw error [deg]",
        ylabel="peak |contact torque| in the arc [N m]",
        title="Peak contact torque on the arm",
        yscale="log",
    )
    for ax in (ax_door, ax_torque):
        ax.grid(True, alpha=0.3)
        ax.legend()
    return fig


def opening_summary(rows: Iterable[RobustnessRow]) -> dict[str, list[float]]:
    """{controller: yaw errors [rad] at which it opened the door}, from rows."""
    out: dict[str, list[float]] = {}
    for r in rows:
        out.setdefault(r.controller, [])
        if r.opened:
            out[r.controller].append(r.yaw_error_rad)
    return out


@dataclass(frozen=True)
class RobustnessSection:
    """What a report's robustness section shows, computed from rows and episodes only.

    Attributes:
        table_markdown: :func:`robustness_table` of the rows.
        figures: {"robustness": door opened and peak torque against yaw error,
            "hinge_convergence": the adaptive plan's hinge estimate error against time}.
        findings: One generated sentence per controller (measured values only).
    """

    table_markdown: str
    figures: dict
    findings: tuple[str, ...]


def _why_not(row: RobustnessRow) -> str:
    """Why a row did not open the door: its status, a lost handle, or the door's angle."""
    if row.status != "ok":
        return row.status
    if not row.handle_held:
        return "handle lost"
    return f"{math.degrees(row.door_opening_rad):.1f} deg by the arc's end"


def robustness_findings(rows: Sequence[RobustnessRow]) -> tuple[str, ...]:
    """One sentence per controller: where it opens the door and its contact torque range."""
    out = []
    for name in dict.fromkeys(r.controller for r in rows):
        mine = sorted((r for r in rows if r.controller == name), key=lambda r: r.yaw_error_rad)
        opened = [f"{math.degrees(r.yaw_error_rad):+.0f}" for r in mine if r.opened]
        failed = [
            f"{math.degrees(r.yaw_error_rad):+.0f} ({_why_not(r)})" for r in mine if not r.opened
        ]
        torques = [
            r.peak_contact_torque_arc_Nm
            for r in mine
            if math.isfinite(r.peak_contact_torque_arc_Nm)
        ]
        if opened:
            sentence = f"{name}: opens the door at yaw errors {', '.join(opened)} deg"
            if failed:
                sentence += f", not at {', '.join(failed)}"
        else:
            sentence = f"{name}: opens the door at none of them ({', '.join(failed)})"
        if torques:
            sentence += (
                f"; peak contact torque in the arc {min(torques):.2f}-{max(torques):.2f} N m"
            )
        errors = [r.hinge_estimate_error_m for r in mine if r.hinge_estimate_error_m is not None]
        if errors:
            sentence += f"; final hinge estimate within {1e3 * max(errors):.1f} mm of the truth"
        out.append(sentence + ".")
    return tuple(out)


def robustness_section(
    rows: Sequence[RobustnessRow],
    adaptive_results: Mapping[str, tuple[EpisodeResult, DoorGeometry]],
) -> RobustnessSection:
    """The robustness section of a report from a grid's rows and the adaptive episodes.

    Args:
        rows: :func:`run_grid` output (every controller on every yaw error).
        adaptive_results: {label: (adaptive episode, its TRUE geometry)} for the convergence
            plot (e.g. one per yaw error of the grid).
    """
    from doorlab.outputs.plots import plot_hinge_convergence

    return RobustnessSection(
        table_markdown=robustness_table(rows),
        figures={
            "robustness": plot_robustness(rows),
            "hinge_convergence": plot_hinge_convergence(adaptive_results),
        },
        findings=robustness_findings(rows),
    )
