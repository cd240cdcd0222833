"""The fidelity table (benchmarks/fidelity_table.py) and the original station's reference data."""

from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

from doorlab.report import EXPERIMENTS
from doorlab.report.experiments import BEYOND
from doorlab.studies.reference import ORIGINAL_STATION

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "fidelity_table.py"


def _module():
    spec = importlib.util.spec_from_file_location("fidelity_table", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_reference_covers_the_eight_experiments():
    """One reference row per experiment of the problem set (the report's runs but those of the
    controllers beyond it, which the original station never had), door angles only with the
    doors closed."""
    pset = {name for name, s in EXPERIMENTS if s.controller not in BEYOND}
    assert len(pset) == 8
    assert set(ORIGINAL_STATION) == pset
    for name, ref in ORIGINAL_STATION.items():
        assert (ref.door_arc_end_deg is None) == name.endswith("_open")
        assert ref.rms_radial_mm <= ref.max_radial_mm


def _report(root: Path, scale: float, status: str = "ok") -> Path:
    """A fake report folder: every run's metrics.json with known figures times ``scale``."""
    for name, _ in EXPERIMENTS:
        closed = name.endswith("_closed")
        metrics = {
            "doors": "closed" if closed else "open",
            "status": status,
            "max_radial_error_m": 0.002 * scale,
            "rms_radial_error_m": 0.001 * scale,
            "max_orientation_error_rad": math.radians(1.5),
            "door_opening_arc_end_rad": math.radians(40.0) if closed else 0.0,
            "door_lag_max_rad": math.radians(1.0) if closed else None,
            "peak_external_torque_arc_Nm": 0.5 if closed else 0.0,
        }
        folder = root / "runs" / name
        folder.mkdir(parents=True)
        (folder / "metrics.json").write_text(json.dumps(metrics))
    return root


def test_table_puts_reference_and_both_loops_side_by_side(tmp_path):
    """Three rows per run (reference, stiffness, ID-PID) in display units; failures flagged."""
    fidelity = _module()
    a = _report(tmp_path / "a", 1.0)
    b = _report(tmp_path / "b", 2.0, status="slipped")
    out = tmp_path / "fidelity.md"
    assert fidelity.main([str(a), str(b), "--out", str(out)]) == 0
    text = out.read_text()
    assert text.count("| IK 10, closed |") == 3
    assert "| IK 10, closed | doorlab, stiffness | 2.00 / 1.00 | 1.50 | 40.0 | 0.50 |" in text
    assert "| IK 10, closed | doorlab, ID-PID | 4.00 / 2.00 **slipped** |" in text
    assert "| impedance, closed | original (ID-PID) | 2.71 / 0.89 | 2.28 | 39.6 | 1.44 |" in text
    rows = json.loads(out.with_suffix(".json").read_text())
    assert rows["velocity_open"]["stiffness"]["door_arc_end_deg"] is None


def test_not_a_report_folder_is_exit_2(tmp_path):
    fidelity = _module()
    assert fidelity.main([str(tmp_path), str(tmp_path), "--out", str(tmp_path / "x.md")]) == 2
    assert not (tmp_path / "x.md").exists()
