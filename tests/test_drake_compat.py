"""doorlab on every supported Drake (issue 45): what differs between releases is asked of
``doorlab.runtime.drake_compat``, and a scenario that needs what the running Drake lacks
(TAMSI on 1.57 and later) is refused at validation, in one line naming what it has."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.specifiers import SpecifierSet
from pydrake.multibody.plant import DiscreteContactApproximation

from doorlab.cli.parser import USAGE_ERROR, main
from doorlab.config import CONTACT_APPROXIMATIONS, Scenario, validate
from doorlab.errors import ConfigError
from doorlab.pset.classroom.wheel import _distribution
from doorlab.runtime import drake_compat

PYPROJECT = Path(__file__).resolve().parents[1] / "pyproject.toml"

WITHOUT_TAMSI = ("sap", "lagged", "similar")
"""What Drake 1.57 and later have."""


def test_the_approximations_are_the_running_drakes():
    """Every approximation pydrake's enum has, by the name MultibodyPlantConfig takes; tamsi
    exactly when the enum has kTamsi (1.56 and earlier)."""
    available = drake_compat.contact_approximations()
    assert set(WITHOUT_TAMSI) <= set(available) <= set(CONTACT_APPROXIMATIONS)
    assert ("tamsi" in available) == hasattr(DiscreteContactApproximation, "kTamsi")
    assert drake_compat.drake_version()[0].isdigit()


@pytest.fixture
def no_tamsi(monkeypatch):
    """A Drake without TAMSI (1.57 on), whatever runs here."""
    monkeypatch.setattr(drake_compat, "contact_approximations", lambda: WITHOUT_TAMSI)


def test_tamsi_on_a_drake_without_it_is_refused_naming_what_it_has(no_tamsi):
    scenario = Scenario()
    scenario.station.contact_approximation = "tamsi"
    with pytest.raises(ConfigError) as info:
        validate(scenario)
    message = str(info.value)
    assert "\n" not in message and "station.contact_approximation 'tamsi'" in message
    assert message.endswith("this Drake has sap, lagged, similar")
    assert "1.56" in message  # which releases have it
    scenario.station.contact_approximation = "similar"
    assert validate(scenario) is scenario


def test_run_with_tamsi_on_a_drake_without_it_exits_2_in_one_line(no_tamsi, tmp_path, capsys):
    """At validation, before anything is built or written: exit 2, one line, no folder."""
    out = tmp_path / "run"
    code = main(["run", "--set", "station.contact_approximation=tamsi", "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert code == USAGE_ERROR == 2
    assert len(err.splitlines()) == 1 and "this Drake has sap, lagged, similar" in err
    assert not out.exists()


@pytest.mark.skipif("tamsi" in drake_compat.contact_approximations(), reason="this Drake has TAMSI")
def test_the_running_drake_without_tamsi_refuses_it(tmp_path, capsys):
    """Where Drake has no TAMSI (1.57 on), the real check, not a stand-in."""
    code = main(["run", "--set", "station.contact_approximation=tamsi", "--out", str(tmp_path)])
    assert code == 2 and "this Drake has" in capsys.readouterr().err


def _drake_specifier(requirements) -> SpecifierSet:
    (spec,) = [r.specifier for r in map(Requirement, requirements) if r.name == "drake"]
    return spec


def test_the_installed_and_the_students_doorlab_admit_every_supported_drake():
    """pyproject's range, the installed doorlab's metadata and so the wheels' (the students'
    handout and the autograder carry the installed metadata) are one: 1.51.1 up to the newest
    tested, the running Drake among them."""
    metadata = _distribution().read_text("METADATA").splitlines()
    installed = _drake_specifier(
        line.split(":", 1)[1].strip() for line in metadata if line.startswith("Requires-Dist:")
    )
    declared = _drake_specifier(re.findall(r'^\s*"(drake[^"]*)"', PYPROJECT.read_text(), re.M))
    assert installed == declared, "the installed metadata is older: pip install -e ."
    for version in (drake_compat.OLDEST, drake_compat.NEWEST_TESTED, drake_compat.drake_version()):
        assert declared.contains(version), version


def test_the_fidelity_page_shows_the_measured_table():
    """docs/explanation/fidelity.md's Drake releases tables are the results file's, as
    benchmarks/drake_releases.py wrote it (every table row of it, verbatim)."""
    root = PYPROJECT.parent
    results = (root / "benchmarks" / "results" / "drake_releases.md").read_text()
    page = (root / "docs" / "explanation" / "fidelity.md").read_text()
    rows = [line for line in results.splitlines() if line.startswith("| ")]
    assert len(rows) > 20
    assert [row for row in rows if row not in page] == []
    assert "Over tolerance or different: none." in results
