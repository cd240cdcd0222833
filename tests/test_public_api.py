"""Every name ``doorlab`` offered before its modules were grouped into sub-packages (issue 28)
is still there: ``from doorlab import X`` gives the same object as its module, and
``import doorlab`` alone stays light (the names that need pydrake load on first use)."""

from __future__ import annotations

import subprocess
import sys

import pytest

import doorlab

PUBLIC_AT_649B4E0 = {
    # name: the module that defines it at main 649b4e0 (doorlab.__all__ and doorlab._LAZY there)
    "REGISTRY": "doorlab.controllers",
    "ConfigError": "doorlab.errors",
    "DoorlabError": "doorlab.errors",
    "EpisodeResult": "doorlab.episode",  # re-exported by doorlab.simulation then
    "IkError": "doorlab.errors",
    "OutputError": "doorlab.errors",
    "Scenario": "doorlab.config",
    "SimulationError": "doorlab.errors",
    "get_controller": "doorlab.controllers",
    "load_scenario": "doorlab.config",
    "run_controller": "doorlab.controllers",
    "run_episode": "doorlab.simulation",
    "validate": "doorlab.config",
}
"""``doorlab.__all__`` at main 649b4e0, copied here (not read from the code) so that a name
dropped from ``__all__`` fails this test."""

NOW_DEFINED_IN = {
    "REGISTRY": "doorlab.episode.controllers",
    "EpisodeResult": "doorlab.episode.result",
    "get_controller": "doorlab.episode.controllers",
    "run_controller": "doorlab.episode.controllers",
    "run_episode": "doorlab.episode.simulation",
}
"""Where the names whose module moved live now (the others did not move)."""


def test_every_name_public_at_649b4e0_is_still_public():
    assert set(PUBLIC_AT_649B4E0) <= set(doorlab.__all__)
    assert doorlab.__version__ == "0.1.0"


@pytest.mark.parametrize("name", sorted(PUBLIC_AT_649B4E0))
def test_from_doorlab_import_gives_the_modules_object(name):
    import importlib

    namespace: dict = {}
    exec(f"from doorlab import {name}", namespace)
    module = NOW_DEFINED_IN.get(name, PUBLIC_AT_649B4E0[name])
    assert namespace[name] is getattr(importlib.import_module(module), name)


def test_star_import_and_dir_list_them():
    namespace: dict = {}
    exec("from doorlab import *", namespace)
    assert set(PUBLIC_AT_649B4E0) <= set(namespace)
    assert set(PUBLIC_AT_649B4E0) <= set(dir(doorlab))


def test_importing_doorlab_loads_no_pydrake_and_no_sub_package():
    """The console script handles signals before the heavy imports (doorlab.cli.entry), and the
    student's view holds only some modules: ``import doorlab`` must load none of them."""
    code = (
        "import sys, doorlab\n"
        "loaded = sorted(m for m in sys.modules if m.startswith(('pydrake', 'doorlab.')))\n"
        "print(loaded)\n"
        "doorlab.Scenario\n"
        "print('pydrake' in sys.modules)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120
    ).stdout.splitlines()
    assert out == ["['doorlab.errors']", "True"]


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'station'"):
        doorlab.station  # noqa: B018 (the module moved to doorlab.cell.station)
