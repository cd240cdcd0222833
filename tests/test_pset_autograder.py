"""``doorlab pset autograder``: the Gradescope zip, its wheel and ``run_autograder`` end to end.

One zip is written per module and unpacked into a stand-in for Gradescope's ``/autograder``
(``DOORLAB_AUTOGRADER_ROOT``). setup.sh's installation needs PyPI, so the fixture does its
offline part: a fresh venv at ``ROOT/doorlab-venv`` with the zip's wheel installed
(``--no-deps --no-index``); doorlab's dependencies come from this interpreter's site-packages
through a path file, which adds the folder but runs none of its ``.pth`` files, so the editable
doorlab of the test environment is not importable there: the wheel's doorlab grades.
"""

from __future__ import annotations

import base64
import hashlib
import importlib.metadata
import json
import os
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

import pset_fixtures
import pytest
import readable_site
from pset_attacks import attack_folder, evidence

import doorlab
from doorlab.cli.parser import main
from doorlab.pset.classroom import gradescope
from doorlab.pset.grading.grader import TESTS
from doorlab.pset.handout.folder import STUDENT_FILES, init_folder
from doorlab.pset.isolation.bwrap_root import BWRAP_ENV

FULL_MARKS = sum(t.max_score for t in TESTS)
RUN_TIMEOUT_S = 900
"""One grading: ~20-40 s with 2 jobs on 2 busy cores (8 jobs, 6 of them episodes)."""
JOBS = ("--jobs", "2")
"""run_autograder's arguments here (Gradescope passes none: the zip's 1 job)."""


@pytest.fixture(scope="module")
def zip_path(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("zip") / "autograder.zip"
    assert main(["pset", "autograder", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def root(tmp_path_factory, zip_path) -> Path:
    """Gradescope's /autograder after setup.sh: source/, run_autograder, doorlab-venv/."""
    return _install(tmp_path_factory.mktemp("autograder"), zip_path, sys.executable)


def _install(root: Path, zip_path: Path, python: str) -> Path:
    """The zip unpacked into ``root`` and its wheel installed into ``root/doorlab-venv``, a
    venv of ``python`` (doorlab's dependencies from this environment, see the module)."""
    with zipfile.ZipFile(zip_path) as archive:
        archive.extractall(root / "source")
        for info in archive.infolist():  # extractall drops the mode bits
            (root / "source" / info.filename).chmod(info.external_attr >> 16 & 0o777)
    shutil.copy2(root / "source" / "run_autograder", root / "run_autograder")
    venv = root / "doorlab-venv"
    subprocess.run([python, "-m", "venv", "--without-pip", str(venv)], check=True)
    python = venv / "bin" / "python"
    settings = json.loads((root / "source" / gradescope.SETTINGS_NAME).read_text())
    subprocess.run(
        [sys.executable, "-m", "pip", "--python", str(python), "install", "--quiet"]
        + ["--no-deps", "--no-index", str(root / "source" / settings["wheel"])],
        check=True,
    )
    purelib = subprocess.run(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    # This environment's packages where the sandbox user can read them (a copy where the
    # checkout is in a folder only its owner can read).
    dependencies = readable_site.readable_site_packages()
    Path(purelib, "doorlab_test_dependencies.pth").write_text("\n".join(dependencies))
    return root


@pytest.fixture(scope="module")
def reference_args(tmp_path_factory) -> tuple[str, ...]:
    """``--reference FILE``: the session's reference episodes (``pset_fixtures``), so the
    gradings after the first full one simulate only the student's episodes."""
    path = tmp_path_factory.mktemp("reference") / "results.json"
    path.write_text(json.dumps({"extra_data": {"reference": pset_fixtures.reference()}}))
    return ("--reference", str(path))


def _run(root: Path, *args: str, env_extra: dict | None = None) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTHON")}
    env[gradescope.ROOT_ENV] = str(root)
    env.update(env_extra or {})
    return subprocess.run(
        ["bash", str(root / "run_autograder"), *args],
        cwd=root,  # Gradescope's working directory
        env=env,
        capture_output=True,
        text=True,
        timeout=RUN_TIMEOUT_S,
    )


def _submit(root: Path, make) -> Path:
    """A fresh ROOT/submission made by ``make(folder)``; no results yet."""
    shutil.rmtree(root / "submission", ignore_errors=True)
    shutil.rmtree(root / "results", ignore_errors=True)
    (root / "results").mkdir()
    make(root / "submission")
    return root / "submission"


def _results(root: Path) -> dict:
    return json.loads((root / "results" / "results.json").read_text())


# The zip ---------------------------------------------------------------------------------


def test_zip_holds_the_scripts_the_settings_and_this_doorlab_as_a_wheel(zip_path, tmp_path):
    with zipfile.ZipFile(zip_path) as archive:
        names = set(archive.namelist())
        settings = json.loads(archive.read(gradescope.SETTINGS_NAME))
        wheel_name = settings["wheel"]
        assert names == {
            "setup.sh",
            "run_autograder",
            gradescope.SETTINGS_NAME,
            gradescope.ASSIGNMENT_NAME,
            gradescope.CONSTRAINTS_NAME,
            wheel_name,
        }
        for script in ("setup.sh", "run_autograder"):
            info = archive.getinfo(script)
            assert info.external_attr >> 16 & 0o111, f"{script} is not executable"
            text = archive.read(script).decode()
            assert text.startswith("#!/usr/bin/env bash\n")
            check = subprocess.run(["bash", "-n"], input=text, text=True, capture_output=True)
            assert check.returncode == 0, check.stderr
        setup = archive.read("setup.sh").decode()
        wheel = archive.read(wheel_name)
    # The files setup.sh takes from the zip: the wheel and the pinned versions.
    assert f'WHEEL="$SOURCE/{wheel_name}"' in setup
    assert f'CONSTRAINTS="$SOURCE/{gradescope.CONSTRAINTS_NAME}"' in setup
    assert settings["doorlab"] == doorlab.__version__
    assert settings["package_sha256"] == gradescope.package_digest()
    assert settings["student_files"] == list(STUDENT_FILES)
    assert settings["jobs"] == 1  # fits Gradescope's default 768 MB (the teaching guide: its peak)
    assert settings["digest"] == gradescope.zip_digest(settings)
    assert wheel_name == f"doorlab-{doorlab.__version__}-py3-none-any.whl"

    # The wheel: exactly the imported package's files (models, templates included), and a
    # RECORD whose hashes and sizes match them.
    package = Path(doorlab.__file__).resolve().parent
    wheel_file = tmp_path / wheel_name
    wheel_file.write_bytes(wheel)
    with zipfile.ZipFile(wheel_file) as w:
        entries = set(w.namelist())
        info_dir = f"doorlab-{doorlab.__version__}.dist-info"
        package_entries = {n for n in entries if not n.startswith(info_dir)}
        assert package_entries == {str(p) for p in gradescope.package_files()}
        assert {
            "doorlab/cell/models/package.xml",
            "doorlab/pset/handout/templates/README.md.j2",
        } <= entries
        assert not any("__pycache__" in n or n.endswith(".pyc") for n in entries)
        for name in ("METADATA", "WHEEL", "RECORD", "entry_points.txt"):
            assert f"{info_dir}/{name}" in entries
        # The console script is the installed distribution's (pyproject's [project.scripts]).
        (script,) = [
            e
            for e in importlib.metadata.entry_points(group="console_scripts")
            if e.name == "doorlab"
        ]
        entry = f"doorlab = {script.value}"
        assert entry in w.read(f"{info_dir}/entry_points.txt").decode()
        assert "Requires-Dist: drake" in w.read(f"{info_dir}/METADATA").decode()
        record = w.read(f"{info_dir}/RECORD").decode().splitlines()
        assert len(record) == len(entries)
        for line in record:
            name, digest, size = line.rsplit(",", 2)
            if name == f"{info_dir}/RECORD":
                continue
            data = w.read(name)
            expected = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=")
            assert digest == "sha256=" + expected.decode() and int(size) == len(data), name
            if not name.startswith(info_dir):
                assert data == (package.parent / name).read_bytes(), name


def test_the_same_doorlab_writes_the_same_zip(zip_path, tmp_path):
    again = tmp_path / "again.zip"
    assert main(["pset", "autograder", str(again)]) == 0
    assert again.read_bytes() == zip_path.read_bytes()


def test_autograder_refuses_bad_destinations_and_leaves_nothing_half_written(
    tmp_path, capsys, monkeypatch
):
    out = tmp_path / "ag.zip"
    assert main(["pset", "autograder", str(out)]) == 0
    capsys.readouterr()

    def refused(*args: str) -> str:
        assert main(["pset", "autograder", *args]) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1, err
        return err

    assert "--force" in refused(str(out))
    mine = tmp_path / "mine.zip"
    mine.write_bytes(b"a teacher's own zip")
    assert "not an autograder zip written by doorlab" in refused(str(mine), "--force")
    assert mine.read_bytes() == b"a teacher's own zip"
    assert "is a file" in refused(str(mine / "ag.zip"))
    assert "ending in .zip" in refused(str(tmp_path / "ag.tar"))
    (tmp_path / "folder.zip").mkdir()
    assert "is a folder" in refused(str(tmp_path / "folder.zip"))
    assert main(["pset", "autograder", str(out), "--force", "--jobs", "3"]) == 0
    with zipfile.ZipFile(out) as archive:
        assert json.loads(archive.read(gradescope.SETTINGS_NAME))["jobs"] == 3

    # Interrupted while writing (Ctrl-C or SIGTERM): the old zip stays, no partial file.
    def interrupt(name: str, context: dict) -> str:
        raise KeyboardInterrupt

    monkeypatch.setattr(gradescope, "_render", interrupt)
    before = sorted(p.name for p in tmp_path.iterdir())
    with pytest.raises(KeyboardInterrupt):
        gradescope.write_autograder(out, force=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    with zipfile.ZipFile(out) as archive:  # still the whole --jobs 3 zip
        assert archive.testzip() is None
        assert json.loads(archive.read(gradescope.SETTINGS_NAME))["jobs"] == 3


# run_autograder --------------------------------------------------------------------------


@pytest.mark.slow
def test_setup_check_accepts_the_installed_wheel_and_rejects_another_doorlab(root, tmp_path):
    python = root / "doorlab-venv" / "bin" / "python"
    where = subprocess.run(
        [str(python), "-I", "-c", "import doorlab; print(doorlab.__file__)"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    assert Path(where).is_relative_to(root / "doorlab-venv"), where
    check = subprocess.run(
        [
            str(python),
            "-I",
            "-m",
            "doorlab.pset.classroom.gradescope",
            "--check",
            "--root",
            str(root),
        ],
        capture_output=True,
        text=True,
    )
    assert check.returncode == 0, check.stderr
    assert "ready to grade" in check.stdout
    assert f"distributions at the versions of {gradescope.CONSTRAINTS_NAME}" in check.stdout

    # A root whose settings name other package files: refused before any grading.
    other = tmp_path / "other"
    shutil.copytree(root / "source", other / "source")
    settings_file = other / "source" / gradescope.SETTINGS_NAME
    settings = json.loads(settings_file.read_text())
    settings["package_sha256"] = "0" * 64
    settings_file.write_text(json.dumps(settings))
    init_folder(other / "submission", solutions=True)
    proc = subprocess.run(
        [str(python), "-I", "-m", "doorlab.pset.classroom.gradescope", "--root", str(other)],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 1
    assert "is not the zip's" in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    assert not (other / "results" / "results.json").exists()

    # An assignment changed after the zip was written (say, points raised by hand in the
    # image): refused too, naming the file.
    shutil.rmtree(other / "source")
    shutil.copytree(root / "source", other / "source")
    path = other / "source" / gradescope.ASSIGNMENT_NAME
    path.write_text(path.read_text().replace("points: 2.0", "points: 20.0", 1))
    proc = subprocess.run(
        [str(python), "-I", "-m", "doorlab.pset.classroom.gradescope", "--root", str(other)],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 1 and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert f"{gradescope.ASSIGNMENT_NAME} is not the zip's" in proc.stderr
    assert not (other / "results" / "results.json").exists()


@pytest.mark.slow
def test_run_autograder_gives_a_correct_submission_full_marks(root):
    _submit(root, lambda d: init_folder(d, solutions=True))
    proc = _run(root, *JOBS)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    results = _results(root)
    assert results["score"] == FULL_MARKS, proc.stdout
    assert [t["name"] for t in results["tests"]] == [t.name for t in TESTS]
    assert "Graded from your submission: " + ", ".join(STUDENT_FILES) in results["output"]
    assert f"doorlab {doorlab.__version__}" in results["output"]
    assert f"Total score: {FULL_MARKS:g} / {FULL_MARKS:g}" in proc.stdout
    # Gradescope's fields (its Autograder Specifications): plain text but the episodes'
    # figures (HTML, the text escaped in it); the zip's (default) visibility; each test's
    # number and status; which zip graded; the total's line.
    assert results["output_format"] == results["test_output_format"] == "text"
    assert results["visibility"] == "visible"
    assert [t["number"] for t in results["tests"]] == [t.number for t in TESTS]
    assert all(t["status"] == "passed" for t in results["tests"])
    formats = {t["number"]: t["output_format"] for t in results["tests"]}
    assert [n for n, f in formats.items() if f == "html"] == ["1.2", "2.4", "3.2"]
    for test in results["tests"]:
        if test["output_format"] == "html":
            assert test["output"].count('<img src="data:image/png;base64,') == 1
            assert test["output"].startswith("<pre>") and test["extra_data"]["text_output"]
    assert results["output"].splitlines()[-1] == f"Total: {FULL_MARKS:g} / {FULL_MARKS:g} points"
    settings = json.loads((root / "source" / gradescope.SETTINGS_NAME).read_text())
    assert results["extra_data"]["autograder"]["digest"] == settings["digest"]


@pytest.mark.slow
def test_run_autograder_gives_the_stubs_zero(root, reference_args):
    _submit(root, init_folder)
    proc = _run(root, *JOBS, *reference_args, "--seed", "7")  # a recorded grading's seed
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    results = _results(root)
    assert results["extra_data"]["seed"]["grading"] == 7
    assert results["score"] == 0
    assert len(results["tests"]) == len(TESTS)
    assert all(t["score"] == 0 for t in results["tests"])


_CHEAT = '''\
import json as _json, os as _os, sys as _sys


def _write_my_own_verdict():
    """At import in a grading job: write a passing result where the job writes its own, and
    leave before the job can overwrite it."""
    argv = _sys.argv
    if len(argv) < 4 or "worker" not in argv[0]:
        return
    job = argv[1]
    if job.startswith("unit:"):
        result = {"passed": True, "output": "all good"}
    else:  # an episode: doorlab's reference figures, passed off as mine
        from doorlab.pset.grading import checks

        result = {"figures": checks.reference_episode(job.partition(":")[2])}
    with open(argv[3], "w") as f:
        f.write(_json.dumps(result))
    _os._exit(0)


_write_my_own_verdict()

'''


def _cheating_submission(folder: Path) -> None:
    """The untouched stubs, a json.py that fakes a pass, and each student file writing its
    own verdict and calling os._exit at import."""
    init_folder(folder)
    (folder / "json.py").write_text(
        "def dumps(*a, **k):\n    return '{\"passed\": true}'\n\n"
        "def loads(*a, **k):\n    return {'passed': True}\n"
    )
    for rel in STUDENT_FILES:
        path = folder / rel
        path.write_text(_CHEAT + path.read_text())


@pytest.mark.slow
def test_run_autograder_gives_a_cheating_submission_zero(root, reference_args):
    _submit(root, _cheating_submission)
    proc = _run(root, *JOBS, *reference_args)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    results = _results(root)
    assert "json.py" in results["output"]  # not used: only the student files are
    assert results["score"] == 0, proc.stdout


@pytest.mark.slow
def test_run_autograder_without_a_submission_says_so(root):
    shutil.rmtree(root / "submission", ignore_errors=True)
    shutil.rmtree(root / "results", ignore_errors=True)
    proc = _run(root, *JOBS)
    assert proc.returncode == 1
    assert "no submission" in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    assert not (root / "results" / "results.json").exists()


# Issue 24: what the submission's code can reach ------------------------------------------


def _attacks(root: Path, key: Path | None):
    clone = Path(doorlab.__file__).resolve().parents[2]

    def make(folder: Path) -> None:
        attack_folder(
            folder,
            roots=[] if key is None else [str(key)],
            wheels=[str(root / "source" / "*.whl"), "/autograder/source/*.whl"],
            clones=[str(clone)],
            socket_path=str(root / "grader.sock"),
            port=9,
            mark=f"doorlab-ag-{os.getpid()}",
        )

    return make


@pytest.mark.slow
def test_run_autograder_gives_issue_24_s_attacks_zero(root, reference_args, tmp_path):
    """As root, with bubblewrap: the stubs trying the issue's attacks (the zip's wheel in
    the autograder's source, a world-readable solved folder, the clone's git, reload,
    dir_fd, /proc, leftovers): 0, and each attack found nothing."""
    key = init_folder(tmp_path / "key", solutions=True)
    _submit(root, _attacks(root, key))
    proc = _run(root, *JOBS, *reference_args)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    results = _results(root)
    assert results["score"] == 0, proc.stdout
    assert results["extra_data"]["sandbox"]["mode"] == "bwrap"
    found = evidence(results)
    assert found["calc_p_Q"]["roots"] == [] and found["calc_p_Q"]["hits"] == []
    assert found["calc_R_WL7_ref"]["wheels"] == []
    assert found["ik"]["reload_has_pointwise_ik"] is False
    assert found["velocity"]["grader_seen"] == []
    assert found["impedance"]["notes_seen"] == []
    for char in ("\x1b", "\x00", "\r"):
        assert char not in proc.stdout and char not in json.dumps(results, ensure_ascii=False)


@pytest.fixture(scope="module")
def fallback_root(zip_path):
    """/autograder where the student's view cannot be built (no bwrap), with a venv of the
    system's Python (the sandbox user must reach it: Gradescope's image has it in /usr)."""
    if os.geteuid() != 0:
        pytest.skip("the fallback switches to another user: as root only")
    python = shutil.which("python3", path="/usr/bin:/bin")
    version = subprocess.run(
        [python or "false", "-c", "import sys; print(sys.version_info[:2])"],
        capture_output=True,
        text=True,
    ).stdout.strip()
    if version != str(sys.version_info[:2]):
        pytest.skip("needs a system python3 of this interpreter's version")
    public = Path(tempfile.mkdtemp(prefix="doorlab_fallback_"))
    os.chmod(public, 0o755)
    yield _install(public / "autograder", zip_path, python)
    shutil.rmtree(public, ignore_errors=True)


@pytest.mark.slow
def test_run_autograder_falls_back_to_another_user_and_hides_the_grader(
    fallback_root, reference_args
):
    """No bubblewrap (a container refusing namespaces looks the same to the grader): the
    attacks run as the sandbox user after the zip's source (the wheel), the results and
    every non-student file of doorlab were made root's alone: 0; the wheel, the reference
    files and the hidden modules stay out of reach; what the code left in /tmp and /dev/shm
    is removed; extra_data.sandbox says what held."""
    root = fallback_root
    package = next((root / "doorlab-venv").glob("lib/python3*/site-packages/doorlab"))
    for compiled in package.glob("pset/grading/__pycache__/checks.*.pyc"):
        compiled.unlink()  # the grading writes it again, after the fallback hid checks.py
    _submit(root, _attacks(root, None))
    proc = _run(root, *JOBS, *reference_args, env_extra={BWRAP_ENV: str(root / "no-bwrap")})
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    results = _results(root)
    assert results["score"] == 0, proc.stdout
    facts = results["extra_data"]["sandbox"]
    assert facts["mode"] == "uid" and facts["policy"] == "autograder"
    assert 0 not in facts["student_uids"] and facts["reference_hidden"]
    assert str(root / "source") in facts["made_unreadable"]
    assert "NOT ISOLATED (autograder)" in proc.stdout
    # What its code left in /tmp and /dev/shm (no private ones without the view) is gone.
    mark = f"doorlab-ag-{os.getpid()}"
    assert [p for d in ("/tmp", "/dev/shm") for p in Path(d).iterdir() if mark in p.name] == []
    found = evidence(results)
    # (Without the view, whatever the machine leaves world-readable is readable: on
    # Gradescope the container holds the autograder only; this machine has other clones.)
    assert found["calc_R_WL7_ref"]["wheels"] == []  # the source folder cannot be listed
    ik = found["ik"]
    assert ik["reload_has_pointwise_ik"] is False
    assert all(v in ("HonestyError", "PermissionError") for k, v in ik.items() if k[0] == "d")
    wheel = next((root / "source").glob("*.whl"))
    code = (
        "import os, sys; os.setgid(65534); os.setuid(65534)\n"
        "for p in sys.argv[1:]:\n"
        "    try:\n        open(p).close(); print('read', p)\n"
        "    except OSError as e:\n        print(type(e).__name__)"
    )
    hidden = [
        wheel,
        package / "control" / "laws.py",
        package / "pset" / "handout" / "templates" / "open_left_door.py.j2",
        # checks.py compiled again by this grading, after the fallback hid its source: a
        # .pyc takes its source's mode.
        *package.glob("control/__pycache__/laws.*.pyc"),
        *package.glob("pset/grading/__pycache__/checks.*.pyc"),
    ]
    assert len(hidden) >= 5
    probe = subprocess.run(
        [sys.executable, "-c", code, *map(str, hidden)], capture_output=True, text=True
    )
    assert probe.stdout.split() == ["PermissionError"] * len(hidden), probe.stdout
