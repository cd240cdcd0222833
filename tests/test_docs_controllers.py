"""docs/guides/controllers.md's commands, as written (tests/doc_commands.py): a plug-in from a
file through ``run``, ``sweep``, ``report`` and ``bench``, the example package's controller by
its module, the rehearsal on the simulated driver (real-time, on the test's own bus), and the
Python block."""

from __future__ import annotations

import json

import pytest
from doc_commands import rehearsed
from lcm_fixtures import lcm_url, multicast_route  # noqa: F401

pytestmark = pytest.mark.slow


def test_controllers(tmp_path, lcm_url, realtime):  # noqa: F811
    work, outcomes = rehearsed(
        "docs/guides/controllers.md",
        tmp_path,
        realtime,
        lcm_url,
        "the plug-in's rehearsal lost the driver",
    )
    ran = [o for o in outcomes if o.how == "ran"]
    assert len(ran) >= 5, [o.how for o in outcomes]
    for folder in ("dls_closed", "ff_closed", "dls_arm"):
        metrics = json.loads((work / folder / "metrics.json").read_text())
        assert metrics["status"] == "ok", (folder, metrics["status"])
    assert (work / "sweep_dls" / "results.csv").is_file()
    assert (work / "report_dls" / "runs" / "dls_closed" / "metrics.json").is_file()
    card = json.loads((work / "bench_dls" / "bench.json").read_text())
    assert {"dls", "velocity"} <= set(card["controllers"])
