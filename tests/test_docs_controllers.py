"""docs/guides/controllers.md's commands, as written (tests/doc_commands.py): a plug-in from a
file through ``run``, ``sweep``, ``report`` and ``bench``, the example package's controller by
its module, the rehearsal on the simulated driver (real-time, on the test's own bus), and the
Python block."""

from __future__ import annotations

import json

import pytest
from doc_commands import Page
from lcm_fixtures import lcm_url, multicast_route  # noqa: F401
from realtime_host import host_watch, watchdog_excused

pytestmark = pytest.mark.slow


def test_controllers(tmp_path, lcm_url, realtime):  # noqa: F811
    page = Page("docs/guides/controllers.md", tmp_path, env={"LCM_DEFAULT_URL": lcm_url})
    with (
        realtime(),
        host_watch() as host,
        watchdog_excused(host, "the plug-in's rehearsal lost the driver"),
    ):
        outcomes = page.run_blocks()
    ran = [o for o in outcomes if o.how == "ran"]
    assert len(ran) >= 5, [o.how for o in outcomes]
    for folder in ("dls_closed", "ff_closed", "dls_arm"):
        metrics = json.loads((tmp_path / folder / "metrics.json").read_text())
        assert metrics["status"] == "ok", (folder, metrics["status"])
    assert (tmp_path / "sweep_dls" / "results.csv").is_file()
    assert (tmp_path / "report_dls" / "runs" / "dls_closed" / "metrics.json").is_file()
    card = json.loads((tmp_path / "bench_dls" / "bench.json").read_text())
    assert {"dls", "velocity"} <= set(card["controllers"])
