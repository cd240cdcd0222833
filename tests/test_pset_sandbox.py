"""The grader against hostile submissions: each attack of issue 17, rebuilt from the untouched
stubs, scores 0; nothing a submission does crashes the grader or outlives it; the sandbox's
limits hold; a correct folder with innocent helper files still scores full marks.

Gradings reuse the session's reference episodes (``pset_fixtures.reference``). Attacks that
act in one function are put one per student function, so one grading of the five unit tests
tries five of them; attacks that act at import run against a unit test and an episode (the
two kinds of job), or the whole grading where the issue found them global.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pset_fixtures
import pytest

from doorlab.cli.parser import main
from doorlab.pset.grading.grader import TESTS, grade, write_results
from doorlab.pset.handout.folder import init_folder
from doorlab.pset.isolation import sandbox

UNIT = {t.name.split(": ", 1)[1]: t.name for t in TESTS if "unit test" in t.name}
UNITS = list(UNIT.values())
EPISODE_VELOCITY = next(t.name for t in TESTS if "velocity plan, doors open" in t.name)
ATTACKED = [UNIT["calc_p_Q"], EPISODE_VELOCITY]
"""A unit test and an episode: the two kinds of job an attack at import runs in."""
STUDENT_FILES = ("open_left_door.py", "ik_utils.py", "manip_station_sim/robot_plans.py")
FULL_MARKS = sum(t.max_score for t in TESTS)
AS_ROOT = os.geteuid() == 0

FORGED = {
    "passed": True,
    "output": "forged",
    "score": FULL_MARKS,
    "values": [[0.0, 0.0, 0.0]] * 7,
    "figures": {
        "status": "ok",
        "max_radial_error_m": 0.0,
        "max_orientation_error_rad": 0.0,
        "q_end_angle_rad": 0.87,
        "door_opening_at_arc_end_rad": 0.54,
        "handle_held": True,
    },
}
"""What a forger would like the grader to read."""


@pytest.fixture(scope="module")
def reference() -> dict:
    return pset_fixtures.reference()


def _stubs(tmp_path: Path, name: str = "stubs") -> Path:
    folder = tmp_path / name
    init_folder(folder)
    return folder


def _prepend(folder: Path, code: str, files=STUDENT_FILES) -> None:
    for rel in files:
        path = folder / rel
        path.write_text(code + "\n" + path.read_text())


def _replace(folder: Path, rel: str, old: str, new: str) -> None:
    path = folder / rel
    text = path.read_text()
    assert text.count(old) == 1, f"{old!r} not found once in {rel}"
    path.write_text(text.replace(old, new))


def _stub_body(function: str) -> str:
    return f'    raise NotImplementedError("{function}: your code here")'


_BODIES = {
    "calc_p_Q": ("open_left_door.py", _stub_body("calc_p_Q")),
    "calc_R_WL7_ref": ("open_left_door.py", _stub_body("calc_R_WL7_ref")),
    "ik": ("ik_utils.py", _stub_body("InverseKinPointwise")),
    "velocity": (
        "manip_station_sim/robot_plans.py",
        "        " + _stub_body("IiwaTaskSpaceVelocityPlan.CalcPositionCommand").strip(),
    ),
    "impedance": (
        "manip_station_sim/robot_plans.py",
        "        " + _stub_body("IiwaTaskSpaceImpedancePlan.CalcTorqueCommand").strip(),
    ),
}


def _in_function(folder: Path, which: str, body: str) -> None:
    """Replaces the stub's ``raise NotImplementedError`` of ``which`` by ``body`` (indented
    four spaces, as in a function; eight in a method)."""
    rel, stub = _BODIES[which]
    indent = "        " if rel.endswith("robot_plans.py") else "    "
    code = "\n".join(indent + line if line else line for line in body.strip("\n").splitlines())
    _replace(folder, rel, stub, code)


def _by_name(results: dict) -> dict[str, dict]:
    return {t["name"]: t for t in results["tests"]}


def _pretty(results: dict) -> str:
    return "\n".join(f"{t['name']}: {t['score']}\n{t['output']}" for t in results["tests"])


def _marked_processes(marker: str) -> list[int]:
    """Live processes whose command line holds ``marker``."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes()
            state = (entry / "stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if marker.encode() in cmdline and state != "Z":
            found.append(int(entry.name))
    return found


# Where verdicts are computed: nothing of the folder in the grader's processes ------------


HOSTILE_JSON = f"""
# A student's json.py: if the grader ever imported it, every result would be full marks.
FORGED = {json.dumps(FORGED)!r}
def dumps(obj, *args, **kwargs):
    return FORGED
def dump(obj, fp, *args, **kwargs):
    fp.write(FORGED)
def loads(text, *args, **kwargs):
    return {FORGED!r}
def load(fp, *args, **kwargs):
    return loads(fp.read())
class JSONDecodeError(ValueError):
    pass
"""


@pytest.mark.slow
def test_a_json_py_in_the_folder_changes_nothing_through_test_pset_5a(tmp_path, reference):
    """The folder's own grader script (`python3 test_pset_5a.py`, the notebook's last cell)
    with a forging json.py next to it: 0, and the script does not import it."""
    folder = _stubs(tmp_path)
    (folder / "json.py").write_text(HOSTILE_JSON)
    earlier = tmp_path / "earlier.json"
    earlier.write_text(json.dumps({"extra_data": {"reference": reference}}))
    out = tmp_path / "results.json"
    env = dict(os.environ, PYTHONPATH=str(folder))  # as the notebook's kernel may set it
    proc = subprocess.run(
        [sys.executable, "test_pset_5a.py", str(out), "--reference", str(earlier)],
        cwd=folder,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    results = json.loads(out.read_text())
    assert results["score"] == 0, _pretty(results)
    assert len(results["tests"]) == len(TESTS)
    assert "forged" not in out.read_text()


@pytest.mark.slow
def test_a_doorlab_package_in_the_folder_shadows_nothing(tmp_path, reference):
    """doorlab/pset/isolation/worker.py, doorlab/pset/grading/jobs.py and the other modules
    of a grading (and their packages) in the submission, each writing full
    marks wherever it can: 0 (a unit test and an episode: every job starts the same way)."""
    folder = _stubs(tmp_path)
    forge = f"""
import os, sys
FORGED = {json.dumps(FORGED)!r}
for path in sys.argv[1:]:
    try:
        open(path, "w").write(FORGED)
    except OSError:
        pass
print(FORGED)
sys.stdout.flush()
os._exit(0)
"""
    subpackages = ("rules", "handout", "isolation", "grading", "classroom")
    packages = ("doorlab", "doorlab/pset", *(f"doorlab/pset/{p}" for p in subpackages))
    for rel in (f"{p}/__init__.py" for p in packages):
        (folder / rel).parent.mkdir(parents=True, exist_ok=True)
        (folder / rel).write_text(forge)
    for rel in (
        "isolation/worker",
        "grading/jobs",
        "grading/checks",
        "grading/grader",
        "isolation/channel",
        "isolation/handle",
        "handout/station_api",
    ):
        (folder / "doorlab" / "pset" / f"{rel}.py").write_text(forge)
    results = grade(folder, only=ATTACKED, reference=reference)
    assert results["score"] == 0, _pretty(results)
    for t in results["tests"]:
        assert "NotImplementedError" in t["output"], t


@pytest.mark.slow
def test_forging_from_inside_the_student_process_scores_zero(tmp_path):
    """One forgery per function: write results to every file and descriptor then
    os._exit(0); an atexit hook doing the same; patching json, doorlab.pset.grading.checks and the
    worker; reading the grader's locals through sys._getframe; numpy.all patched."""
    folder = _stubs(tmp_path)
    forge = f"""
import os, sys, json
FORGED = {json.dumps(FORGED)!r}.encode()
for fd in range(3, 64):
    for frame in (FORGED, len(FORGED).to_bytes(4, "little") + b"\\x01" + FORGED):
        try:
            os.write(fd, frame)
        except OSError:
            pass
for path in sys.argv[1:]:
    try:
        open(path, "wb").write(FORGED)
    except OSError:
        pass
"""
    _in_function(folder, "calc_p_Q", forge + "os._exit(0)\n")
    _in_function(
        folder,
        "calc_R_WL7_ref",
        "import atexit\ndef _forge():\n"
        + "\n".join("    " + line for line in forge.strip().splitlines())
        + "\natexit.register(_forge)\nraise NotImplementedError('stub')\n",
    )
    _in_function(
        folder,
        "ik",
        f"""
import json
FORGED = {json.dumps(FORGED)!r}
json.dumps = lambda *args, **kwargs: FORGED
json.loads = lambda *args, **kwargs: {FORGED!r}
try:
    import doorlab.pset.grading.checks as checks
    checks.check_ik = lambda *args: {{"passed": True}}
except ImportError:
    pass
import doorlab.pset.isolation.worker as worker
worker.Server.op_ik = lambda self, request: {FORGED!r}
worker._error = lambda *args: {FORGED!r}
raise NotImplementedError("stub")
""",
    )
    _in_function(
        folder,
        "velocity",
        """
import sys
frame = sys._getframe()
while frame is not None:
    for name in ("expected", "accepted", "candidates", "reference"):
        if name in frame.f_locals:
            value = frame.f_locals[name]
            return value[0] if isinstance(value, list) else value
    frame = frame.f_back
return q_iiwa
""",
    )
    _in_function(
        folder,
        "impedance",
        """
for name in ("all", "allclose", "array_equal", "isclose", "any"):
    setattr(np, name, lambda *args, **kwargs: True)
return np.zeros(7)
""",
    )
    results = grade(folder, only=UNITS)
    assert results["score"] == 0, _pretty(results)
    tests = _by_name(results)
    assert "exit code 0" in tests[UNIT["calc_p_Q"]]["output"]
    for t in results["tests"]:
        assert "forged" not in t["output"]


# Every way a student process can end, and garbage ---------------------------------------


@pytest.mark.slow
def test_every_way_out_is_that_tests_failure_only(tmp_path, reference):
    """os._exit(3), SIGABRT, killing its parent and itself, garbage on the channel, a
    segfault: each fails its own test with the cause in its message; the episode that does
    work is unharmed."""
    folder = init_folder(tmp_path / "endings", solutions=True)
    _replace(
        folder,
        "open_left_door.py",
        "    return p_WQ - p_WC_handle",
        "    import os\n    os._exit(3)",
    )
    _replace(
        folder,
        "open_left_door.py",
        "    return RollPitchYaw(0.0, 3 * np.pi / 4, yaw).ToRotationMatrix()",
        "    __import__('os').abort()",
    )
    _replace(
        folder,
        "ik_utils.py",
        "    times = np.linspace(0.0, duration, num_knot_points)",
        "    import os, signal\n"
        "    try:\n"
        "        os.kill(os.getppid(), signal.SIGKILL)\n"
        "    except OSError:\n"
        "        pass\n"
        "    os.kill(os.getpid(), signal.SIGKILL)\n"
        "    times = np.linspace(0.0, duration, num_knot_points)",
    )
    _replace(
        folder,
        "manip_station_sim/robot_plans.py",
        "        return q_iiwa + q_dot_des * control_period",
        "        import os\n"
        "        for fd in range(3, 64):\n"
        "            try:\n"
        "                os.write(fd, os.urandom(256))\n"
        "            except OSError:\n"
        "                pass\n"
        "        return q_iiwa + q_dot_des * control_period",
    )
    _replace(
        folder,
        "manip_station_sim/robot_plans.py",
        "        return self.Jv_WL7q.T @ F",
        "        import ctypes\n        ctypes.string_at(0)\n        return self.Jv_WL7q.T @ F",
    )
    results = grade(folder, only=UNITS, reference=reference)
    assert results["score"] == 0, _pretty(results)
    tests = _by_name(results)
    assert "exit code 3" in tests[UNIT["calc_p_Q"]]["output"]
    assert "SIGABRT" in tests[UNIT["calc_R_WL7_ref"]]["output"]
    # As root the student's user cannot kill the grader's process, so it kills itself; as
    # an ordinary user it kills the test's trusted process: the supervisor says so.
    ik = tests[UNIT["InverseKinPointwise"]]["output"]
    assert "SIGKILL" in ik or "killed by signal 9" in ik
    vel = tests[UNIT["IiwaTaskSpaceVelocityPlan.CalcPositionCommand"]]["output"]
    assert "not an answer" in vel or "closed the grader's channel" in vel
    assert "SIGSEGV" in tests[UNIT["IiwaTaskSpaceImpedancePlan.CalcTorqueCommand"]]["output"]


@pytest.mark.slow
def test_wrong_shapes_and_garbage_in_an_episode_fail_it_without_crashing(tmp_path, reference):
    """A plan that answers 50 ticks, then returns 3 values and writes garbage on the
    channel; the worker patched to answer malformed objects: the episode and the unit test
    fail with a message, the results are complete."""
    folder = init_folder(tmp_path / "shapes", solutions=True)
    (folder / "manip_station_sim" / "robot_plans.py").write_text(
        (folder / "manip_station_sim" / "robot_plans.py").read_text()
        + """

import itertools
import os

_ticks = itertools.count()
_original = IiwaTaskSpaceVelocityPlan.CalcPositionCommand


def _after_50_ticks(self, q_iiwa, *args):
    if next(_ticks) < 52:
        return _original(self, q_iiwa, *args)
    for fd in range(3, 64):
        try:
            os.write(fd, b"\\xff" * 7)
        except OSError:
            pass
    return np.zeros(3)


IiwaTaskSpaceVelocityPlan.CalcPositionCommand = _after_50_ticks
"""
    )
    _prepend(
        folder,
        "import doorlab.pset.isolation.channel as _c\n"
        "_send = _c.Channel.send_json\n"
        "def _wrong(self, obj, *args, **kwargs):\n"
        "    _send(self, {'values': [[1.0, 2.0]] * 7, 'figures': {}, 'passed': True})\n"
        "_c.Channel.send_json = _wrong\n",
        files=("open_left_door.py",),
    )
    results = grade(folder, only=ATTACKED, reference=reference)
    assert [t["name"] for t in results["tests"]] == [UNIT["calc_p_Q"], EPISODE_VELOCITY]
    assert results["score"] == 0, _pretty(results)
    tests = _by_name(results)
    assert "answered something invalid" in tests[UNIT["calc_p_Q"]]["output"]
    episode = tests[EPISODE_VELOCITY]["output"]
    assert "did not finish" in episode and "your code" in episode


# What outlives a test -------------------------------------------------------------------


@pytest.mark.slow
def test_detached_and_pipe_holding_processes_are_dead_when_grading_returns(tmp_path, reference):
    """At import, the student's code starts a double-forked, setsid'd process that waits,
    then rewrites the results file with full marks (a file it could write: world-writable),
    and a child that keeps the process's stdout and stderr open and sleeps. Each test ends
    when its answer is in (no time limit hit); both processes are dead when grading returns;
    the results file stays as the grader wrote it."""
    folder = _stubs(tmp_path)
    marker = f"doorlab-left-behind-{os.getpid()}-{time.time_ns()}"
    public = Path(tempfile.mkdtemp(prefix="doorlab_detached_"))
    os.chmod(public, 0o777)
    target = public / "test_results.json"
    writer = (
        f"import os, time; os.setsid(); time.sleep(3); "
        f"open({str(target)!r}, 'w').write({json.dumps(FORGED)!r})  # {marker}"
    )
    _prepend(
        folder,
        "import os as _os, subprocess as _sp, sys as _sys\n"
        f"_sp.Popen([_sys.executable, '-c', 'import time; time.sleep(600)  # {marker}'])\n"
        "if _os.fork() == 0:\n"
        f"    _sp.Popen([_sys.executable, '-c', {writer!r}], start_new_session=True)\n"
        "    _os._exit(0)\n",
    )
    try:
        results = grade(folder, only=ATTACKED, reference=reference)
        write_results(results, target)
        os.chmod(target, 0o666)
        assert _marked_processes(marker) == []
        written = target.read_text()
        time.sleep(4)
        assert target.read_text() == written
        assert json.loads(written)["score"] == 0
        for t in results["tests"]:
            assert "time limit" not in t["output"], t
            assert "NotImplementedError" in t["output"], t
    finally:
        shutil.rmtree(public, ignore_errors=True)


# Limits -----------------------------------------------------------------------------------


@pytest.mark.slow
def test_memory_file_output_and_time_limits_hold_and_results_stay_small(tmp_path, reference):
    """3 GiB of memory, a 1 GiB file, 300 MiB on stderr and a 20 MB exception message, one
    per function, graded in a separate process: each its own test's failure with the limit
    named; the results file stays under 1 MB and no grading process grew past 1 GiB (the
    300 MiB were never held). (Hangs: test_pset's endless loop.)"""
    folder = _stubs(tmp_path)
    _in_function(folder, "calc_p_Q", "blob = bytearray(3 << 30)\nreturn blob")
    _in_function(
        folder,
        "calc_R_WL7_ref",
        "with open('big.bin', 'wb') as f:\n"
        "    for _ in range(1024):\n"
        "        f.write(bytes(1 << 20))\n",
    )
    _in_function(
        folder,
        "ik",
        "import sys\nline = 'x' * (1 << 20)\nfor _ in range(300):\n    sys.stderr.write(line)\n",
    )
    _in_function(folder, "velocity", "raise RuntimeError('y' * 20_000_000)")
    earlier = tmp_path / "earlier.json"
    earlier.write_text(json.dumps({"extra_data": {"reference": reference}}))
    out = tmp_path / "results.json"
    script = (
        "import resource, sys\n"
        "from doorlab.pset.grading.grader import grade, load_reference, write_results, TESTS\n"
        "units = [t.name for t in TESTS if 'unit test' in t.name][:4]\n"
        "r = grade(sys.argv[1], only=units, reference=load_reference(sys.argv[2]))\n"
        "write_results(r, sys.argv[3])\n"
        "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", script, str(folder), str(earlier), str(out)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    max_rss_kib = int(proc.stdout.split()[-1])
    assert max_rss_kib < (1 << 20), max_rss_kib
    assert out.stat().st_size < 1_000_000
    results = json.loads(out.read_text())
    assert results["score"] == 0, _pretty(results)
    tests = _by_name(results)
    assert "out of memory" in tests[UNIT["calc_p_Q"]]["output"]
    assert "file-size limit" in tests[UNIT["calc_R_WL7_ref"]]["output"]
    assert "output limit" in tests[UNIT["InverseKinPointwise"]]["output"]
    message = tests[UNIT["IiwaTaskSpaceVelocityPlan.CalcPositionCommand"]]["output"]
    assert message.startswith("RuntimeError: yyy") and len(message) < 5000


# The honesty boundary ---------------------------------------------------------------------


@pytest.mark.slow
def test_doorlab_reference_solutions_are_out_of_reach(tmp_path):
    """Each function takes doorlab's solution another way: rendering the --solutions files,
    reading the templates, doorlab's pointwise IK, doorlab.control.laws, importlib on
    doorlab.control.plans (the error caught): each test fails and says so."""
    folder = _stubs(tmp_path)
    _in_function(
        folder,
        "calc_p_Q",
        """
from doorlab.pset.handout.folder import render_folder
namespace = {}
exec(render_folder(True)["open_left_door.py"], namespace)
return namespace["calc_p_Q"](tau)
""",
    )
    _in_function(
        folder,
        "calc_R_WL7_ref",
        """
from importlib.resources import files
text = files("doorlab.pset.handout").joinpath("templates", "open_left_door.py.j2").read_text()
import jinja2
namespace = {}
exec(jinja2.Template(text).render(solutions=True), namespace)
return namespace["calc_R_WL7_ref"](tau)
""",
    )
    _in_function(
        folder,
        "ik",
        """
from doorlab.control.ik_pointwise import pointwise_ik
result = pointwise_ik(plant, InterpolatePosition, InterpolateOrientation,
                      duration=duration, num_knots=num_knot_points,
                      q_guess=q_initial_guess, position_tolerance=position_tolerance,
                      theta_bound=theta_bound)
zero = np.zeros(7)
qtraj = PiecewisePolynomial.CubicWithContinuousSecondDerivatives(
    result.times, result.q_knots.T, zero, zero)
return qtraj, result.q_knots
""",
    )
    _in_function(
        folder,
        "velocity",
        """
from doorlab.control.laws import velocity_law
return velocity_law(q_iiwa, self.Jv_WL7q, err_xyz, R_L7L7r, control_period)
""",
    )
    _in_function(
        folder,
        "impedance",
        """
import importlib
try:
    plans = importlib.import_module("doorlab.control.plans")
except ImportError:
    return np.zeros(7)
return plans.impedance_law(self.Jv_WL7q, err_xyz)
""",
    )
    results = grade(folder, only=UNITS)
    assert results["score"] == 0, _pretty(results)
    tests = _by_name(results)
    # The templates are not in the student's view at all; importing the modules is also
    # refused by name (the honesty guard, the second line), so the message says what.
    assert "FileNotFoundError" in tests[UNIT["calc_R_WL7_ref"]]["output"]
    for name, module in (
        ("calc_p_Q", "doorlab.pset.handout.folder"),
        ("InverseKinPointwise", "doorlab.control.ik_pointwise"),
        ("IiwaTaskSpaceVelocityPlan.CalcPositionCommand", "doorlab.control.laws"),
        ("IiwaTaskSpaceImpedancePlan.CalcTorqueCommand", "doorlab.control.plans"),
    ):
        output = tests[UNIT[name]]["output"]
        assert "doorlab's reference solutions" in output and module in output, output


# A correct folder with innocent helpers ----------------------------------------------------


@pytest.mark.slow
def test_a_correct_folder_with_helpers_named_like_the_grader_s_modules_scores_full(
    tmp_path, reference
):
    """json.py, copy.py and numpy.py helpers (each imported by nothing) in a correct folder:
    14/14 through `doorlab pset grade`; the student's code ran in its view (no network, no
    reference file, its own processes, nothing on its path writable, a 64 MiB /tmp), as
    another user when the grader is root."""
    folder = init_folder(tmp_path / "helpers", solutions=True)
    for name in ("json", "copy", "numpy"):
        (folder / f"{name}.py").write_text(f'"""My notes on {name}."""\nraise SystemExit(1)\n')
    earlier = tmp_path / "earlier.json"
    earlier.write_text(json.dumps({"extra_data": {"reference": reference}}))
    assert main(["pset", "grade", str(folder), "--reference", str(earlier)]) == 0
    results = json.loads((folder / "test_results.json").read_text())
    assert results["score"] == FULL_MARKS, _pretty(results)
    facts = results["extra_data"]["sandbox"]
    assert facts["mode"] == "bwrap" and facts["isolated"]
    assert facts["network_isolated"] and facts["reference_hidden"] and facts["pid_namespace"]
    assert facts["python_path_read_only"] and facts["tmpfs_bytes"] <= 64 << 20
    if AS_ROOT:
        assert facts["student_uids"] and 0 not in facts["student_uids"]


# The sandbox itself -----------------------------------------------------------------------


def _student_argv(tmp_path: Path, code: str) -> tuple[list[str], Path]:
    """``code`` as a student process runs: in the student's view (bwrap), as the sandbox
    user when the grader is root; (argv, its scratch folder)."""
    from doorlab.pset.isolation import bwrap_root

    site = tmp_path / "site"
    if not site.exists():
        bwrap_root.build_site(site)
    plan = bwrap_root.plan_view(site, bwrap_root.find_bwrap())
    identity = sandbox.sandbox_identity()
    drop = None if identity is None else (identity.uid, identity.gid)
    work = tmp_path / "work"
    work.mkdir(exist_ok=True)
    if drop is not None:
        os.chown(work, *drop)
    argv = bwrap_root.bwrap_argv(plan, work, None, as_root=drop is not None)
    argv += [plan.python, "-I", "-S", "-c", bwrap_root.boot_code(plan, drop) + "\n" + code]
    return argv, work


def _run_sandboxed(tmp_path: Path, code: str, **limits) -> tuple[int, str]:
    """``code`` in a student process's view, under the sandbox's limits; its exit code
    (bwrap's: 128 + N for a death by signal N) and output."""
    os.chmod(tmp_path, 0o711)
    argv, work = _student_argv(tmp_path, code)
    proc = sandbox.spawn(
        argv,
        cwd=work,
        env={"PATH": "/usr/bin:/bin", "HOME": "/pset"},
        limits=sandbox.Limits(cpu_seconds=limits.pop("cpu_seconds", 30), **limits),
        identity=sandbox.sandbox_identity(),
        switch_user=False,
    )
    collector = sandbox.OutputCollector(proc.stdout)
    code_ = proc.wait(timeout=60)
    collector.join(10)
    return code_, collector.text()


@pytest.mark.slow
def test_sandbox_limits_memory_files_and_processes(tmp_path):
    code, out = _run_sandboxed(
        tmp_path,
        "import os, threading, time\n"
        "try:\n    bytearray(3 << 30); print('memory: allowed')\n"
        "except MemoryError:\n    print('memory: refused')\n"
        "threads = []\n"
        "try:\n"
        "    for _ in range(500):\n"
        "        t = threading.Thread(target=time.sleep, args=(2,)); t.start(); threads.append(t)\n"
        "    print('threads: 500')\n"
        "except RuntimeError:\n    print('threads: refused at', len(threads))\n"
        "import signal; signal.signal(signal.SIGXFSZ, signal.SIG_IGN)\n"
        "try:\n"
        "    with open('big', 'wb') as f:\n        f.write(bytes(64 << 20))\n"
        "    print('file: allowed')\n"
        "except OSError:\n    print('file: refused at', os.path.getsize('big'))\n",
    )
    assert code == 0, out
    assert "memory: refused" in out
    assert "file: refused at 33554432" in out
    if AS_ROOT:  # as an ordinary user the limit counts that user's other processes too
        assert "threads: refused at" in out, out


def test_sandbox_limits_cpu_time(tmp_path):
    """A busy loop past its CPU limit (1 s here) gets SIGXCPU (the grader's wall-clock
    deadline usually ends a hang first; this catches CPU spent where no answer is awaited)."""
    code, out = _run_sandboxed(tmp_path, "while True:\n    pass", cpu_seconds=1)
    assert code == 128 + signal.SIGXCPU, out  # bwrap's way of saying "killed by SIGXCPU"


def test_kill_descendants_catches_setsid_and_double_forks(tmp_path):
    """A process started by spawn (without a view, as --insecure runs student code; in the
    view its PID namespace dies with it) starts a child that leaves its session and a
    grandchild orphaned by a double fork: as the subreaper, kill_descendants finds and kills
    both."""
    marker = f"doorlab-escape-{os.getpid()}-{time.time_ns()}"
    script = f"""
import os, subprocess, sys, time
from doorlab.pset.isolation import sandbox
sandbox.become_subreaper()
code = '''
import os, subprocess, sys, time
leaver = "import os, time; os.setsid(); time.sleep(300)  # {marker}"
subprocess.Popen([sys.executable, "-c", leaver])
if os.fork() == 0:
    if os.fork() == 0:
        os.setsid()
        os.execv(sys.executable, [sys.executable, "-c", "import time; time.sleep(300)  # {marker}"])
    os._exit(0)
time.sleep(1)
'''
proc = sandbox.spawn([sys.executable, "-I", "-c", code], cwd="/", env={{"PATH": "/usr/bin"}},
                     limits=sandbox.Limits(cpu_seconds=30), identity=None)
proc.wait()
time.sleep(0.5)
def alive():
    return len([p for p, _, state in sandbox.descendants(os.getpid()) if state not in "ZX"])
print("alive before", alive())
print("killed", sandbox.kill_descendants())
print("alive after", alive(), "in all", len(sandbox.descendants(os.getpid())))
"""
    proc = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "alive before 2" in proc.stdout, proc.stdout
    assert "alive after 0 in all 0" in proc.stdout
    assert _marked_processes(marker) == []


def test_output_collector_keeps_both_ends_and_stops_at_the_limit():
    read_fd, write_fd = os.pipe()
    stopped = []
    collector = sandbox.OutputCollector(
        os.fdopen(read_fd, "rb", buffering=0),
        limit=8 << 20,
        kept=100,
        on_overflow=lambda: stopped.append(True),
    )
    with os.fdopen(write_fd, "wb") as w:
        w.write(b"start" + b"." * (20 << 20) + b"end")
    collector.join(10)
    text = collector.text()
    assert collector.total == (20 << 20) + 8 and collector.overflowed and stopped == [True]
    assert text.startswith("start") and text.endswith("end") and len(text) < 400


def test_output_written_before_an_answer_is_kept_whether_the_thread_ran_or_not():
    """What the student's process printed (and flushed) before its answer is in the pipe when
    the answer arrives: drain() takes it at once, even when the collector's thread has not been
    scheduled (here it never runs: a starved trusted process on a loaded machine, where the
    feedback once showed an error without the lines printed before it)."""
    import threading

    class Starved(sandbox.OutputCollector):
        def __init__(self, *args, **kwargs):
            self.release = threading.Event()
            super().__init__(*args, **kwargs)

        def _run(self) -> None:
            self.release.wait()

    read_fd, write_fd = os.pipe()
    collector = Starved(os.fdopen(read_fd, "rb", buffering=0))
    try:
        os.write(write_fd, b"EVIDENCE printed before the answer\n")
        assert collector.text() == ""  # the thread has not read it
        collector.drain()
        assert collector.text() == "EVIDENCE printed before the answer\n"
        collector.drain()  # nothing more: nothing taken twice
        assert collector.total == len("EVIDENCE printed before the answer\n")
    finally:
        os.close(write_fd)
        collector.release.set()


def test_a_grader_environment_the_student_user_cannot_read_is_named_as_such():
    """A student process that died before its greeting because the user it runs as could not
    import the grader's packages (a venv under /root, mode 700: seen in a clone there) is
    reported as that, not as the student's code ending its process; any other module, or no
    traceback, leaves the usual cause."""
    from doorlab.pset.isolation.handle import _import_failure

    died = (
        'File ".../doorlab/pset/isolation/worker.py", line 39, in _preload\n    import numpy\n'
        "ModuleNotFoundError: No module named 'numpy'\n"
    )
    why = _import_failure(died)
    assert why is not None and "could not import numpy" in why and "/root" in why
    no_doorlab = "Error while finding module specification for 'doorlab.pset.isolation.worker' "
    no_doorlab += "(ModuleNotFoundError: No module named 'doorlab')"
    assert "could not import doorlab" in _import_failure(no_doorlab)
    assert _import_failure("ModuleNotFoundError: No module named 'my_helpers'") is None
    assert _import_failure("Killed\n") is None


@pytest.mark.skipif(os.geteuid() != 0, reason="as root: another user's IPC objects")
def test_the_separate_user_fallback_removes_its_ipc_objects(tmp_path):
    """Issue 31: where the separate-user fallback gets no IPC namespace of its own (a
    container that refuses unshare), what the student's user left in System V IPC (a shared
    memory segment, a semaphore set, a message queue) is removed after the test; another
    user's objects and older ones stay."""
    import ctypes

    from doorlab.pset.isolation.handle import remove_ipc_leftovers

    uid = 64123
    code = (
        "import ctypes, os\n"
        f"os.setgid({uid}); os.setuid({uid})\n"
        "libc = ctypes.CDLL(None, use_errno=True)\n"
        "print(libc.shmget(0, 4096, 0o1600), libc.semget(0, 1, 0o1600), libc.msgget(0, 0o1600))"
    )
    since = time.time()
    made = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    ids = [int(x) for x in made.stdout.split()]
    assert all(i >= 0 for i in ids), made.stdout
    libc = ctypes.CDLL(None, use_errno=True)
    mine = libc.shmget(0, 4096, 0o1600)  # root's, made now: not the student's user's
    try:
        removed = remove_ipc_leftovers(uid, since)
        assert sorted(removed) == sorted(
            [f"System V shm {ids[0]}", f"System V sem {ids[1]}", f"System V msg {ids[2]}"]
        ), removed
        listed = {k: Path(f"/proc/sysvipc/{k}").read_text() for k in ("shm", "sem", "msg")}
        assert f" {mine} " in listed["shm"]
        assert remove_ipc_leftovers(uid, since) == []
    finally:
        libc.shmctl(mine, 0, None)
