"""A benchmark's numbers from its table: success rates with Wilson intervals, the metrics'
quantiles, failures by kind. Pure: a table in, dictionaries out (no simulation, no clock).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from doorlab.bench.measures import FAILURE_KINDS, classify

Z_95 = 1.959963984540054
"""The standard normal's 97.5 % quantile: a two-sided 95 % interval."""
QUANTILES = (0.05, 0.25, 0.5, 0.75, 0.95)
"""The quantiles a metric's distribution is reported by (``q05`` .. ``q95``)."""
METRICS = {
    "max_radial_error_m": ("Q's radial error, max over the arc", "m"),
    "max_orientation_error_rad": ("L7's orientation error, max over the arc", "rad"),
    "peak_contact_force_arc_N": ("peak contact force at Q in the arc", "N"),
    "time_to_open_s": ("time to open, from the arc's start", "s"),
}
"""The distributions a card reports: column -> (what, SI unit). Each over the episodes that
have it (time to open: those that opened)."""


def wilson_interval(successes: int, trials: int, z: float = Z_95) -> tuple[float, float]:
    """Wilson's score interval for a binomial proportion (Wilson 1927): the p whose score
    test does not reject at the level of ``z``,

        (p^ + z^2 / 2n -+ z sqrt(p^ (1 - p^) / n + z^2 / 4n^2)) / (1 + z^2 / n),

    p^ = successes / trials. Unlike the normal (Wald) interval it stays in [0, 1], is not empty
    at 0 or n successes, and covers close to its level for small n (Brown, Cai and DasGupta
    2001).

    Args:
        successes: k, 0 <= k <= trials. trials: n >= 1. z: The normal quantile (1.96: 95 %).

    Returns:
        (low, high), 0 <= low <= k/n <= high <= 1.

    Raises:
        ValueError: n < 1, or k outside [0, n].
    """
    if not isinstance(trials, (int, np.integer)) or trials < 1:
        raise ValueError(f"trials must be an integer >= 1, got {trials!r}")
    if not 0 <= successes <= trials:
        raise ValueError(f"successes must be in [0, {trials}], got {successes!r}")
    n, p = float(trials), successes / trials
    denominator = 1.0 + z * z / n
    centre = (p + z * z / (2.0 * n)) / denominator
    half = z * math.sqrt(p * (1.0 - p) / n + z * z / (4.0 * n * n)) / denominator
    low, high = max(0.0, centre - half), min(1.0, centre + half)
    if successes == 0:
        low = 0.0  # exactly: the rounding of centre - half
    if successes == trials:
        high = 1.0
    return low, high


def rate(successes: int, trials: int) -> dict:
    """``successes``, ``success_rate`` and ``ci95`` ([low, high], Wilson) of a count."""
    low, high = wilson_interval(successes, trials)
    return {"successes": int(successes), "success_rate": successes / trials, "ci95": [low, high]}


def distribution(values: Sequence[float]) -> dict:
    """``n``, ``mean`` and the :data:`QUANTILES` (``q05`` ..) of the finite values (numpy's
    linear interpolation; None when there are none)."""
    x = np.asarray([v for v in values if v is not None and np.isfinite(v)], dtype=float)
    out: dict = {"n": int(len(x)), "mean": float(np.mean(x)) if len(x) else None}
    for q in QUANTILES:
        out[f"q{round(100 * q):02d}"] = float(np.quantile(x, q)) if len(x) else None
    return out


def summarize(rows: Sequence[dict], controllers: Sequence[str]) -> dict[str, dict]:
    """Per controller (in ``controllers``' order, by name): ``episodes``, ``successes``,
    ``success_rate``, ``ci95``, ``robosuite`` (the same under robosuite's definition),
    ``failures`` by kind, ``statuses`` and ``metrics`` (:data:`METRICS`' distributions).

    Args:
        rows: The benchmark table's rows (dicts), every controller's.
        controllers: The controllers' names, as the table's ``controller`` column has them.
    """
    out = {}
    for name in controllers:
        mine = [r for r in rows if r.get("controller") == name]
        if not mine:
            continue
        verdicts = [classify(r) for r in mine]
        successes = sum(v[0] for v in verdicts)
        failures = {kind: sum(v[2] == kind for v in verdicts) for kind in FAILURE_KINDS}
        statuses: dict[str, int] = {}
        for r in mine:
            statuses[str(r.get("status"))] = statuses.get(str(r.get("status")), 0) + 1
        out[name] = {
            "episodes": len(mine),
            **rate(successes, len(mine)),
            "robosuite": rate(sum(v[1] for v in verdicts), len(mine)),
            "failures": failures,
            "statuses": dict(sorted(statuses.items())),
            "metrics": {
                key: {"what": what, "unit": unit, **distribution([r.get(key) for r in mine])}
                for key, (what, unit) in METRICS.items()
            },
        }
    return out
