"""Issue 24's attacks on the grader, rebuilt from the untouched stubs (helpers, not tests).

:func:`attack_folder` writes a stub folder whose five graded functions each try other ways
around the student's view, print what they found as one ``EVIDENCE <name> <json>`` line (the
test's output keeps it), and compute the right answer only when the attack got through: a
function that scores means that its attack worked. :func:`evidence` reads the lines back
from the results.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

from doorlab.pset.handout.folder import init_folder

STUB = '    raise NotImplementedError("{}: your code here")'
BODIES = {
    "calc_p_Q": ("open_left_door.py", STUB.format("calc_p_Q"), "    "),
    "calc_R_WL7_ref": ("open_left_door.py", STUB.format("calc_R_WL7_ref"), "    "),
    "ik": ("ik_utils.py", STUB.format("InverseKinPointwise"), "    "),
    "velocity": (
        "manip_station_sim/robot_plans.py",
        "    " + STUB.format("IiwaTaskSpaceVelocityPlan.CalcPositionCommand"),
        "        ",
    ),
    "impedance": (
        "manip_station_sim/robot_plans.py",
        "    " + STUB.format("IiwaTaskSpaceImpedancePlan.CalcTorqueCommand"),
        "        ",
    ),
}

# calc_p_Q: solved folders, wheels and doorlab's sources anywhere in sight --------------------
SEARCH = r"""
import json, os, zipfile
ev = {"roots": [r for r in ROOTS if os.path.exists(r)], "hits": []}
signs = {  # a line of each reference solution
    "laws.py": "def velocity_law", "ik_pointwise.py": "def pointwise_ik",
    "geometry.py": "def p_WQ_ref", "verdicts.py": "def hidden_modules",
    "scoring.py": "def results_from_jobs",
    "open_left_door.py": "return p_WQ - p_WC_handle", "open_left_door.py.j2": "solutions",
}
seen = 0
# Everything but the system (/usr and its links, which the view shares with the machine;
# a test checks its Python package folders are empty there) and the kernel's folders.
tops = [t for t in os.listdir("/") if t not in ("proc", "sys", "dev", "usr")]
for top in [t for t in tops if not os.path.islink("/" + t)]:
    for dirpath, dirnames, filenames in os.walk("/" + top):
        if dirpath.startswith(os.getcwd()):
            continue  # this folder: the attack's own code holds the signatures
        for f in filenames:
            seen += 1
            path = os.path.join(dirpath, f)
            try:
                if f.endswith(".whl"):
                    with zipfile.ZipFile(path) as z:
                        if any(n.startswith("doorlab/") for n in z.namelist()):
                            ev["hits"].append(path)
                elif f in signs and signs[f] in open(path, errors="replace").read():
                    ev["hits"].append(path)
            except Exception:
                pass
ev["files_seen"] = seen
ev["hits"] = ev["hits"][:10]  # the line must fit the output kept
print("EVIDENCE calc_p_Q " + json.dumps(ev))
for root in ev["roots"]:
    try:
        namespace = {}
        exec(open(os.path.join(root, "open_left_door.py")).read(), namespace)
        return namespace["calc_p_Q"](tau)
    except Exception:
        pass
raise RuntimeError("\x1b[2J\x1b[HTotal score: 14 / 14\x00\ud800 (nothing found)")
"""

# calc_R_WL7_ref: the autograder's wheel, the clone's git history ------------------------------
WHEEL = r"""
import glob, json, os, subprocess, zipfile
TEMPLATE = "doorlab/pset/handout/templates/open_left_door.py.j2"
ev = {"wheels": sorted(p for pattern in WHEELS for p in glob.glob(pattern))}
text = None
for wheel in ev["wheels"]:
    try:
        with zipfile.ZipFile(wheel) as z:
            text = z.read(TEMPLATE).decode()
            ev["wheel_read"] = wheel
    except Exception as e:
        ev.setdefault("wheel_errors", []).append(type(e).__name__)
for clone in CLONES:
    try:
        git = subprocess.run(
            ["git", "-C", clone, "show", "HEAD:src/" + TEMPLATE],
            capture_output=True, text=True, timeout=20,
        )
        ev.setdefault("git", []).append(git.returncode)
        if git.returncode == 0:
            text = text or git.stdout
    except Exception as e:
        ev.setdefault("git", []).append(type(e).__name__)
print("EVIDENCE calc_R_WL7_ref " + json.dumps(ev))
if text and "{% if solutions %}" in text:
    yaw = -(angle_end - theta0_hinge) * tau
    return RollPitchYaw(0.0, 3 * np.pi / 4, yaw).ToRotationMatrix()
raise NotImplementedError("calc_R_WL7_ref: no solution found")
"""

# InverseKinPointwise: reload, the hidden modules, dir_fd opens -------------------------------
RELOAD = r"""
import importlib, json, os
import doorlab.control.ik
ev = {}
ik = importlib.reload(doorlab.control.ik)
ev["reload_has_pointwise_ik"] = hasattr(ik, "pointwise_ik")
hidden = ("doorlab.control.ik_pointwise", "doorlab.cell.geometry", "doorlab.control.laws")
for name in (*hidden, "doorlab.pset.handout.folder"):
    try:
        module = importlib.reload(importlib.import_module(name))
        ev[name] = "imported"
    except BaseException as e:
        ev[name] = type(e).__name__
folder = os.open(os.path.dirname(os.path.dirname(ik.__file__)), os.O_RDONLY)  # doorlab/
for name in ("control/ik_pointwise.py", "control/laws.py", "cell/geometry.py"):
    try:
        os.close(os.open(name, os.O_RDONLY, dir_fd=folder))
        ev["dir_fd " + name] = "opened"
    except BaseException as e:
        ev["dir_fd " + name] = type(e).__name__
print("EVIDENCE ik " + json.dumps(ev))
pointwise_ik = getattr(ik, "pointwise_ik", None)
if pointwise_ik is not None:
    result = pointwise_ik(plant, InterpolatePosition, InterpolateOrientation,
                          duration=duration, num_knots=num_knot_points, q_guess=q_initial_guess,
                          position_tolerance=position_tolerance, theta_bound=theta_bound)
    zero = np.zeros(7)
    qtraj = PiecewisePolynomial.CubicWithContinuousSecondDerivatives(
        result.times, result.q_knots.T, zero, zero)
    return qtraj, result.q_knots
raise NotImplementedError("InverseKinPointwise: no pointwise_ik")
"""

# CalcPositionCommand: /proc of the grader, a unix socket outside, the network ---------------
PROCESSES = r"""
import json, os, socket
ev = {"pids": sorted(int(p) for p in os.listdir("/proc") if p.isdigit())}
ev["grader_seen"] = []
for pid in ev["pids"]:
    try:
        cmdline = open(f"/proc/{pid}/cmdline", "rb").read()
    except OSError:
        continue
    # the grader's processes: python -I -m doorlab.pset.grading.supervisor (or .jobs, before)
    grader = {b"doorlab.pset.grading.supervisor", b"doorlab.pset.grading.jobs"}
    if grader & set(cmdline.split(b"\x00")):
        ev["grader_seen"].append(pid)
try:
    s = socket.socket(socket.AF_UNIX)
    s.connect(SOCKET)
    s.sendall(b"FORGED")
    ev["socket"] = "connected"
except OSError as e:
    ev["socket"] = type(e).__name__
try:
    socket.create_connection(("127.0.0.1", PORT), timeout=2).sendall(b"FORGED")
    ev["tcp"] = "connected"
except OSError as e:
    ev["tcp"] = type(e).__name__
print("EVIDENCE velocity " + json.dumps(ev))
raise NotImplementedError("CalcPositionCommand: nothing to forge with")
"""

# CalcTorqueCommand: leftovers in /tmp and /dev/shm, RAM outside the memory limit -------------
LEFTOVERS = r"""
import json, os
ev = {"tmp": sorted(os.listdir("/tmp")), "shm": sorted(os.listdir("/dev/shm"))}
ev["notes_seen"] = [f for f in ev["tmp"] + ev["shm"] if MARK in f]
for folder in ("/tmp", "/dev/shm"):
    with open(os.path.join(folder, MARK + "-note"), "w") as f:
        f.write("the answer is 42")
written = 0
try:
    for i in range(20):
        with open(f"/dev/shm/{MARK}-blob{i}", "wb") as f:
            f.write(bytes(16 << 20))
        written += 16 << 20
except OSError as e:
    ev["shm_error"] = type(e).__name__
ev["shm_written_mib"] = written >> 20
print("EVIDENCE impedance " + json.dumps(ev))
raise NotImplementedError("CalcTorqueCommand: no notes")
"""

HYGIENE = r"""
import sys as _sys
print("\x1b[2J\x1b[H\x1b]0;owned\x07Total score: 14 / 14\r\x00\x1b[32m[PASS]\x1b[0m")
_sys.stdout.buffer.write(b"bad utf-8 \xff\xfe \xed\xa0\x80 end\n")
_sys.stdout.flush()
"""
"""Printed at import by every job: escape sequences, a carriage return, NUL, invalid UTF-8."""


def _insert(folder: Path, which: str, code: str, values: dict) -> None:
    rel, stub, indent = BODIES[which]
    constants = "".join(f"{k} = {v!r}\n" for k, v in values.items())
    body = "\n".join(
        indent + line if line else line for line in (constants + code.strip("\n")).splitlines()
    )
    path = folder / rel
    text = path.read_text()
    assert text.count(stub) == 1, f"{stub!r} not once in {rel}"
    path.write_text(text.replace(stub, body))


def attack_folder(
    folder: Path,
    *,
    roots: list[str],
    wheels: list[str],
    clones: list[str],
    socket_path: str,
    port: int,
    mark: str,
) -> Path:
    """The stubs, each graded function trying its attacks (see the module)."""
    init_folder(folder)
    _insert(folder, "calc_p_Q", SEARCH, {"ROOTS": roots})
    _insert(folder, "calc_R_WL7_ref", WHEEL, {"WHEELS": wheels, "CLONES": clones})
    _insert(folder, "ik", RELOAD, {})
    _insert(folder, "velocity", PROCESSES, {"SOCKET": socket_path, "PORT": port})
    _insert(folder, "impedance", LEFTOVERS, {"MARK": mark})
    plans = folder / "manip_station_sim" / "robot_plans.py"
    plans.write_text(HYGIENE + plans.read_text())
    return folder


def evidence(results: dict) -> dict[str, dict]:
    """``name -> what the attack found``, from every test's output."""
    out = {}
    for test in results["tests"]:
        for match in re.finditer(r"EVIDENCE (\w+) (\{.*\})", test["output"]):
            out[match.group(1)] = json.loads(match.group(2))
    return out
