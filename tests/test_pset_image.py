"""The autograder's image: ``setup.sh`` installs exactly the versions pinned in the zip and only
what grading needs, and creates the sandbox's user.

A rehearsal of Gradescope's image build (``DOORLAB_AUTOGRADER_ROOT``): ``setup.sh`` from the
zip, with its dependencies from the package index (pip's cache reused; the test skips,
saying why, without the index). As root it runs in bubblewrap with a private copy of
``/etc``, so the user it creates exists there only, not on the machine running the tests.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from package_index import INSTALL_TIMEOUT_S, clean_environment, require_index
from packaging.utils import canonicalize_name

import doorlab
from doorlab.cli.parser import main
from doorlab.pset.classroom import gradescope

BOOTSTRAP = {"setuptools"}
"""What ``python3 -m venv`` itself puts in a venv besides pip (Python < 3.12)."""
NOT_FOR_GRADING = ("pandas", "pyarrow", "dask", "distributed")


def _pins(text: str) -> dict[str, str]:
    pins = {}
    for line in text.splitlines():
        if "==" in line and not line.startswith("#"):
            name, version = line.split("==", 1)
            pins[canonicalize_name(name)] = version
    return pins


def _forget_user(etc: Path, user: str) -> None:
    """``etc`` (a copy of /etc) without ``user`` and its group: an earlier rehearsal on this
    machine may have created them in the real /etc."""
    for name in ("passwd", "group", "shadow", "gshadow"):
        path = etc / name
        if path.is_file() and not path.is_symlink():
            lines = path.read_text().splitlines(keepends=True)
            path.write_text("".join(line for line in lines if not line.startswith(f"{user}:")))


@pytest.mark.slow
def test_setup_sh_installs_the_pinned_versions_only_and_creates_the_user(tmp_path):
    require_index()
    zips = []
    for name in ("first.zip", "second.zip"):  # one environment, two builds
        assert main(["pset", "autograder", str(tmp_path / name)]) == 0
        with zipfile.ZipFile(tmp_path / name) as archive:
            zips.append(archive.read(gradescope.CONSTRAINTS_NAME).decode())
    assert zips[0] == zips[1]
    pins = _pins(zips[0])
    assert {"drake", "numpy", "matplotlib", "pip"} <= set(pins)
    assert not set(NOT_FOR_GRADING) & set(pins)

    root = tmp_path / "autograder"
    with zipfile.ZipFile(tmp_path / "first.zip") as archive:
        archive.extractall(root / "source")
    env = clean_environment(root / "doorlab-venv")
    env[gradescope.ROOT_ENV] = str(root)
    # The image's python3: the Python the zip was written from (this one's base; the
    # machine's python3 may be older, which setup.sh refuses, as on such an image).
    image_bin = tmp_path / "image-bin"
    image_bin.mkdir()
    (image_bin / "python3").symlink_to(getattr(sys, "_base_executable", sys.executable))
    env["PATH"] = f"{image_bin}{os.pathsep}{env['PATH']}"
    command = ["bash", str(root / "source" / "setup.sh")]
    etc = None
    if os.geteuid() == 0 and shutil.which("bwrap"):
        etc = tmp_path / "etc"
        shutil.copytree("/etc", etc, symlinks=True, ignore_dangling_symlinks=True)
        _forget_user(etc, gradescope.SANDBOX_USER)  # as on a fresh image, whatever ran here
        command = ["bwrap", "--bind", "/", "/", "--bind", str(etc), "/etc"]
        command += ["--dev", "/dev", "--proc", "/proc", "bash", str(root / "source" / "setup.sh")]
    else:
        env["DOORLAB_SANDBOX_USER"] = "nobody"  # no root (or no bwrap): no user to create
    proc = subprocess.run(
        command, env=env, capture_output=True, text=True, timeout=INSTALL_TIMEOUT_S
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert "ready to grade" in proc.stdout
    assert f"distributions at the versions of {gradescope.CONSTRAINTS_NAME}" in proc.stdout

    listed = subprocess.run(
        [str(root / "doorlab-venv" / "bin" / "python"), "-m", "pip", "list", "--format=json"],
        env=env,
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    installed = {canonicalize_name(d["name"]): d["version"] for d in json.loads(listed)}
    assert installed.pop("doorlab") == doorlab.__version__
    for name in BOOTSTRAP:
        installed.pop(name, None)
    assert installed == pins  # exactly the pinned versions, nothing more

    if etc is not None:
        assert f"created the user {gradescope.SANDBOX_USER}" in proc.stdout
        passwd = (etc / "passwd").read_text()
        assert f"\n{gradescope.SANDBOX_USER}:" in f"\n{passwd}"
        assert "/usr/sbin/nologin" in passwd.split(f"{gradescope.SANDBOX_USER}:", 1)[1]
    else:
        pytest.skip("setup.sh's user: needs root and bubblewrap to rehearse (the rest held)")
