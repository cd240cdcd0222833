"""Issue 24: the student's code sees nothing but its own folder.

The student's view (bubblewrap: a minimal read-only root) holds only what it is given; the
reference solutions are whole modules outside it, listed in one table; where the view cannot
be built the grader refuses (or, asked to, grades and says so); text from student code
cannot draw on the instructor's terminal. Each attack of the issue is rebuilt from the
untouched stubs (``pset_attacks``): one grading tries them all, each in another function, and
each function's printed evidence shows what its attack found. Tests that change user run as
root only (a raw uid, no account is created); the autograder's side is in
``test_pset_autograder.py``.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import pset_fixtures
import pytest
import readable_site
from pset_attacks import _insert, attack_folder, evidence

import doorlab
from doorlab.cli.parser import main
from doorlab.pset.classroom.gradescope import wheel_bytes
from doorlab.pset.grading.grader import TESTS, grade
from doorlab.pset.handout.folder import STUDENT_FUNCTIONS, init_folder
from doorlab.pset.isolation import bwrap_root, choice, seccomp
from doorlab.pset.isolation.safe_text import clean_text
from doorlab.pset.rules.verdicts import REFERENCE_SOLUTIONS, hidden_modules

AS_ROOT = os.geteuid() == 0
FULL_MARKS = sum(t.max_score for t in TESTS)
UNIT = {t.name.split(": ", 1)[1]: t.name for t in TESTS if "unit test" in t.name}
TEST_UID = 64123
"""An ordinary user for the tests that change user (a raw uid: no account is needed)."""
CONTROL = [chr(c) for c in (*range(0, 9), *range(11, 32), 0x7F, 0x9B)]


def _public_dir(prefix: str) -> Path:
    """A temporary folder every user can reach (pytest's are its owner's alone)."""
    folder = Path(tempfile.mkdtemp(prefix=prefix))
    os.chmod(folder, 0o755)
    return folder


@pytest.fixture(scope="module")
def public(tmp_path_factory):
    folder = _public_dir("doorlab_isolation_")
    yield folder
    shutil.rmtree(folder, ignore_errors=True)


@pytest.fixture(scope="module")
def reference_file(public) -> Path:
    path = public / "reference.json"
    path.write_text(json.dumps({"extra_data": {"reference": pset_fixtures.reference()}}))
    os.chmod(path, 0o644)
    return path


def _pretty(results: dict) -> str:
    return "\n".join(f"{t['name']}: {t['score']}\n{t['output']}" for t in results["tests"])


# One table, whole modules out of sight ------------------------------------------------------


def test_every_graded_function_s_reference_is_in_the_table_and_off_the_student_side():
    """Each graded function has its reference modules in verdicts' table; the objects that
    are doorlab's reference (the pointwise IK, the arc, the laws, the plans, the solutions'
    templates and renderer) live in those modules; none is on the student side."""
    from doorlab.cell import geometry
    from doorlab.control import ik_pointwise, laws, plans
    from doorlab.pset.handout import folder

    assert set(REFERENCE_SOLUTIONS) == set(STUDENT_FUNCTIONS)
    hidden = hidden_modules()
    reference_objects = {
        "ik_utils.InverseKinPointwise": [ik_pointwise.pointwise_ik],
        "open_left_door.calc_p_Q": [geometry.DoorGeometry.p_WQ_ref],
        "open_left_door.calc_R_WL7_ref": [geometry.DoorGeometry.R_WL7_ref],
        "IiwaTaskSpaceVelocityPlan.CalcPositionCommand": [
            laws.velocity_law,
            plans.TaskSpaceVelocityPlan,
        ],
        "IiwaTaskSpaceImpedancePlan.CalcTorqueCommand": [
            laws.impedance_law,
            plans.TaskSpaceImpedancePlan,
        ],
    }
    for function, objects in reference_objects.items():
        for obj in objects:
            assert obj.__module__ in REFERENCE_SOLUTIONS[function], (function, obj)
    for modules in REFERENCE_SOLUTIONS.values():
        assert set(modules) <= set(hidden)
    assert folder.render_folder.__module__ in hidden  # the --solutions files
    assert not set(hidden) & set(bwrap_root.STUDENT_MODULES)
    # The student side's files are exactly its modules and the models: no template, and
    # none of the hidden modules' files.
    files = bwrap_root.student_files()
    assert not any("templates" in f for f in files)
    for name in hidden:
        assert name.replace(".", "/") + ".py" not in files
    # What the folder's provided helpers give is the handout's own arc, equal to the
    # reference arc it is kept apart from.
    from doorlab.pset.handout import task_helpers

    g = geometry.default_door_geometry()
    for tau in (0.0, 0.2, 0.57, 1.0, 1.3):
        assert abs(task_helpers.interpolate_arc(tau) - g.p_WQ_ref(tau)).max() < 1e-12
        R = task_helpers.interpolate_yaw(tau).matrix() - g.R_WL7_ref(tau).matrix()
        assert abs(R).max() < 1e-12


def _in_view(tmp: Path, code: str, *args: str) -> subprocess.CompletedProcess:
    """``code`` in a student process's view (as root: as the sandbox user), this test's
    way (no limits, no channel)."""
    site = bwrap_root.build_site(tmp / "site")
    plan = bwrap_root.plan_view(site, bwrap_root.find_bwrap())
    identity = choice.sandbox.sandbox_identity()
    drop = None if identity is None else (identity.uid, identity.gid)
    scratch = tmp / "scratch"
    scratch.mkdir()
    if drop is not None:
        os.chown(scratch, *drop)
    seccomp_fd = seccomp.filter_descriptor()
    try:
        argv = bwrap_root.bwrap_argv(
            plan, scratch, None, as_root=drop is not None, seccomp_fd=seccomp_fd
        )
        argv += [
            plan.python,
            "-I",
            "-S",
            "-B",
            "-c",
            bwrap_root.boot_code(plan, drop) + "\n" + code,
        ]
        return subprocess.run(
            [*argv, *args],
            capture_output=True,
            text=True,
            timeout=120,
            env={"PATH": "/usr/bin"},
            pass_fds=(seccomp_fd,),
        )
    finally:
        os.close(seccomp_fd)


@pytest.fixture
def work(tmp_path) -> Path:
    os.chmod(tmp_path, 0o711)
    return tmp_path


def test_the_view_holds_only_what_it_is_given(work):
    """In the view: the student side imports only itself; no other folder of the machine
    (/home, /root's contents, the clone, the grader's temporary folders, /srv); the Python
    package folders of the system are empty; nothing on sys.path is writable; only its own
    processes; as root, another user."""
    clone = Path(doorlab.__file__).resolve().parents[2]
    probe = r"""
import json, os, sys
import doorlab.pset.isolation.worker as worker
worker._preload()
out = {"modules": sorted(m for m in sys.modules if m.startswith("doorlab"))}
out["root"] = sorted(os.listdir("/"))
out["exists"] = {p: os.path.exists(p) for p in sys.argv[1:]}
out["usr_packages"] = {}
for base in ("/usr/lib/python3/dist-packages", "/usr/local/lib"):
    for dirpath, dirnames, filenames in os.walk(base):
        if dirpath.endswith(("-packages",)) and (dirnames or filenames):
            out["usr_packages"][dirpath] = len(dirnames) + len(filenames)
out["writable"] = [p for p in sys.path if p and os.access(p, os.W_OK)]
out["pids"] = [p for p in os.listdir("/proc") if p.isdigit()]
out["uid"] = os.getuid()
print("VIEW " + json.dumps(out))
"""
    outside = [
        "/home",
        "/srv",
        "/root/.bashrc",
        str(clone / "src" / "doorlab" / "control" / "laws.py"),
        str(clone / ".git"),
        str(work),
        tempfile.gettempdir() + "/" + os.listdir(tempfile.gettempdir())[0],
        str(Path(doorlab.__file__).resolve().parent / "control" / "laws.py"),
    ]
    proc = _in_view(work, probe, *outside)
    assert proc.returncode == 0, proc.stderr[-3000:]
    facts = json.loads(proc.stdout.split("VIEW ", 1)[1])
    assert set(facts["modules"]) <= set(bwrap_root.STUDENT_MODULES), facts["modules"]
    assert facts["exists"] == {p: False for p in outside}, facts["exists"]
    assert {"home", "srv"}.isdisjoint(facts["root"])
    assert facts["usr_packages"] == {}
    assert facts["writable"] == []
    assert len(facts["pids"]) <= 2  # bwrap's init and this process
    if AS_ROOT:
        assert facts["uid"] == choice.sandbox.sandbox_identity().uid != 0


NAMESPACES = r"""
import ctypes, errno, json, os
libc = ctypes.CDLL(None, use_errno=True)
out = {}
for name, flag in FLAGS.items():
    pid = os.fork()
    if pid == 0:  # each try in a child of its own: a namespace made would stay with it
        ok = libc.unshare(flag) == 0
        os._exit(0 if ok else 100 + ctypes.get_errno())
    code = os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1])
    out[name] = "made" if code == 0 else errno.errorcode.get(code - 100, code)
out["keyctl"] = libc.syscall(250, 0, -4, 0, 0, 0) if os.uname().machine == "x86_64" else -1
print("VIEW " + json.dumps(out))
"""


def test_inside_the_view_no_namespace_nor_keyring_can_be_made(work):
    """Issue 31: the view's system-call filter refuses unshare(CLONE_NEWUSER) (and every other
    namespace) and the kernel's keyrings (shared by every process of the sandbox user, so by
    two gradings at once); fork and threads still work."""
    code = f"FLAGS = {seccomp.NAMESPACE_FLAGS!r}\n" + NAMESPACES
    proc = _in_view(work, code + "import threading; threading.Thread(target=print).start()")
    assert proc.returncode == 0, proc.stderr[-3000:]
    facts = json.loads(proc.stdout.split("VIEW ", 1)[1].splitlines()[0])
    assert facts.pop("keyctl") == -1  # KEYCTL_GET_KEYRING_ID of the user's keyring: EPERM
    assert facts == dict.fromkeys(seccomp.NAMESPACE_FLAGS, "EPERM"), facts


SOCKETS = r"""
import ctypes, errno, json, os, socket
libc = ctypes.CDLL(None, use_errno=True)
out = {}
for name, family, kind in FAMILIES:
    try:
        socket.socket(family, kind).close()
        out[name] = "made"
    except OSError as e:
        out[name] = errno.errorcode.get(e.errno, e.errno)
if os.uname().machine == "x86_64":  # socket(2) of a family with its upper 32 bits set
    libc.syscall.restype = ctypes.c_long
    for name, family in (("AF_VSOCK", 40), ("AF_UNIX", 1)):
        name, family = f"{name}, upper bits set", family + (1 << 32)
        fd = libc.syscall(41, ctypes.c_long(family), 1, 0)
        out[name] = "made" if fd >= 0 else errno.errorcode[ctypes.get_errno()]
a, b = socket.socketpair()
a.close(), b.close()
out["socketpair AF_UNIX"] = "made"
pair = libc.socketpair(40, 1, 0, (ctypes.c_int * 2)())
out["socketpair AF_VSOCK"] = "made" if pair == 0 else errno.errorcode[ctypes.get_errno()]
for call, number, args in (("modify_ldt", 154, (0, 0, 0)), ("personality", 135, (0xFFFFFFFF,))):
    result = libc.syscall(number, *args) if os.uname().machine == "x86_64" else -1
    out[call] = "allowed" if result != -1 else errno.errorcode[ctypes.get_errno()]
print("VIEW " + json.dumps(out))
"""
"""Sockets of each family, modify_ldt and personality (x86-64 numbers), in the view."""
FAMILIES = [
    ("AF_UNIX", 1, 1),
    ("AF_INET", 2, 1),
    ("AF_INET6", 10, 1),
    ("AF_NETLINK", 16, 3),
    ("AF_PACKET", 17, 3),
    ("AF_VSOCK", 40, 1),
    ("AF_ALG", 38, 5),
    ("AF_UNSPEC", 0, 1),
    ("AF_APPLETALK", 5, 2),
]


def test_inside_the_view_only_unix_and_ip_sockets_and_no_ldt_nor_personality(work):
    """Issue 43: the filter refuses every socket family but Unix, IPv4 and IPv6 (the view's
    loopback): no netlink, packet, vsock (a virtual machine's host) or crypto socket; and
    modify_ldt and personality."""
    code = f"FAMILIES = {FAMILIES!r}\n" + SOCKETS
    proc = _in_view(work, code)
    assert proc.returncode == 0, proc.stderr[-3000:]
    facts = json.loads(proc.stdout.split("VIEW ", 1)[1].splitlines()[0])
    made = {"AF_UNIX", "AF_INET", "AF_INET6", "socketpair AF_UNIX"}
    refused = {k: v for k, v in facts.items() if k not in made and k not in seccomp.REFUSED}
    assert {k: facts[k] for k in made} == dict.fromkeys(made, "made"), facts
    # A family's upper 32 bits, which the kernel drops, are no way around it (refused).
    assert refused == dict.fromkeys(refused, "EAFNOSUPPORT"), facts
    if os.uname().machine == "x86_64":
        assert (facts["modify_ldt"], facts["personality"]) == ("EPERM", "EPERM"), facts


RECORDED_RULES = [
    *[("EPERM", name, ()) for name in (
        "unshare", "setns", "mount", "umount2", "pivot_root", "fsopen", "fsmount", "fsconfig",
        "fspick", "move_mount", "open_tree", "mount_setattr", "add_key", "request_key",
        "keyctl", "bpf", "perf_event_open", "userfaultfd", "io_uring_setup", "io_uring_enter",
        "io_uring_register", "ptrace", "process_vm_writev", "open_by_handle_at",
        "name_to_handle_at", "init_module", "finit_module", "delete_module", "kexec_load",
        "kexec_file_load", "syslog", "acct", "quotactl", "swapon", "swapoff", "reboot",
        "modify_ldt", "personality",
    )],
    *[("EPERM", "clone", (0, "&==", flag)) for flag in (
        0x00020000, 0x02000000, 0x04000000, 0x08000000, 0x10000000, 0x20000000, 0x40000000,
    )],
    ("ENOSYS", "clone3", ()),
    *[("EAFNOSUPPORT", call, condition) for call in ("socket", "socketpair") for condition in (
        *[(0, "==", n) for n in (0, 3, 4, 5, 6, 7, 8, 9)], (0, ">=", 11),
    )],
]  # fmt: skip
"""The filter's rules as reviewed for issue 43 (x86-64: clone's flags are its first argument)."""


def test_the_filter_s_rules_are_the_recorded_ones():
    """The system-call filter is built from one list of rules, which is the recorded one:
    a rule added, dropped or loosened is a deliberate change of this list too."""
    if os.uname().machine in seccomp.CLONE_FLAGS_ARGUMENT:
        pytest.skip("recorded for clone's flags in its first argument")
    assert seccomp.rule_list() == RECORDED_RULES
    assert seccomp.filter_bytes()  # libseccomp takes every rule


# No isolation, no grade -------------------------------------------------------------------

FAKE_BWRAP = """#!/bin/sh
case "$1" in --help) echo "usage: bwrap --size BYTES"; exit 0;; esac
echo "bwrap: No permissions to create new namespace, likely because the kernel does not \
allow non-privileged user namespaces." >&2
exit 1
"""
"""bwrap where the kernel refuses user namespaces (what it says then)."""


def _fake_bwrap(folder: Path) -> Path:
    path = folder / "bwrap"
    path.write_text(FAKE_BWRAP)
    os.chmod(path, 0o755)
    return path


@pytest.mark.slow
def test_without_bwrap_or_namespaces_pset_grade_refuses_before_any_student_code(
    work, capsys, monkeypatch
):
    """No bwrap, then a bwrap that cannot make namespaces: one line each, naming what is
    missing and how to get it; exit 1; no results; the folder's code never ran."""
    folder = init_folder(work / "stubs")
    marker = _public_dir("doorlab_ran_")
    os.chmod(marker, 0o777)
    (folder / "open_left_door.py").write_text(
        f"open({str(marker / 'ran')!r}, 'w').write('ran')\n"
        + (folder / "open_left_door.py").read_text()
    )
    try:
        for bwrap, expected in (
            (str(work / "no-such-bwrap"), "bubblewrap (bwrap) is not installed"),
            (str(_fake_bwrap(work)), "non-privileged user namespaces"),
        ):
            monkeypatch.setenv(bwrap_root.BWRAP_ENV, bwrap)
            assert main(["pset", "grade", str(folder)]) == 1
            err = capsys.readouterr().err
            assert len(err.strip().splitlines()) == 1, err
            assert expected in err and "apt-get install bubblewrap" in err
            assert "--insecure" in err
            assert not (folder / "test_results.json").exists()
            assert not (marker / "ran").exists()
    finally:
        shutil.rmtree(marker, ignore_errors=True)


# The attacks, through `doorlab pset grade` ----------------------------------------------


class _Listener:
    """A unix socket and a TCP port outside the view, counting what reaches them."""

    def __init__(self, folder: Path):
        self.path = str(folder / "grader.sock")
        self.unix = socket.socket(socket.AF_UNIX)
        self.unix.bind(self.path)
        os.chmod(self.path, 0o777)
        self.tcp = socket.create_server(("127.0.0.1", 0))
        self.port = self.tcp.getsockname()[1]
        self.received: list[bytes] = []
        for s in (self.unix, self.tcp):
            s.listen(8)
            s.settimeout(0.2)
        self._stop = False
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop:
            for s in (self.unix, self.tcp):
                try:
                    conn, _ = s.accept()
                except OSError:
                    continue
                conn.settimeout(1)
                try:
                    self.received.append(conn.recv(100) or b"(connected)")
                except OSError:
                    self.received.append(b"(connected)")
                conn.close()

    def close(self) -> None:
        self._stop = True
        self._thread.join(5)
        self.unix.close()
        self.tcp.close()


def _strings(value):
    """Every string in a JSON value (keys too)."""
    if isinstance(value, str):
        yield value
    elif isinstance(value, dict):
        for k, v in value.items():
            yield k
            yield from _strings(v)
    elif isinstance(value, list):
        for v in value:
            yield from _strings(v)


def _leftovers(mark: str) -> list[str]:
    return [
        str(p) for folder in ("/tmp", "/dev/shm") for p in Path(folder).iterdir() if mark in p.name
    ]


@pytest.mark.slow
def test_issue_24_attacks_from_the_stubs_score_zero_through_pset_grade(
    public, reference_file, capfd
):
    """The stubs, each function trying the issue's attacks: a world-readable solved folder,
    doorlab's wheel and sources anywhere on the machine, the clone's git history, reload of
    doorlab.control.ik and the hidden modules, dir_fd opens, /proc of the grader, a unix socket and
    a TCP port outside, notes in /tmp and /dev/shm and 320 MiB of shared memory; escape
    sequences, NUL, a carriage return, invalid UTF-8 and a lone surrogate in the output.
    0 / 14; each attack found nothing; nothing left in /tmp or /dev/shm; neither the results
    nor the terminal holds a control character."""
    key = init_folder(public / "key", solutions=True)
    subprocess.run(["chmod", "-R", "a+rX", str(key)], check=True)
    name, data = wheel_bytes()
    (public / name).write_bytes(data)
    os.chmod(public / name, 0o644)
    clone = Path(doorlab.__file__).resolve().parents[2]
    mark = f"doorlab-note-{os.getpid()}-{time.time_ns()}"
    listener = _Listener(public)
    folder = attack_folder(
        public / "attacks",
        roots=[str(key)],
        wheels=[str(public / "*.whl")],
        clones=[str(clone)],
        socket_path=listener.path,
        port=listener.port,
        mark=mark,
    )
    try:
        capfd.readouterr()
        code = main(["pset", "grade", str(folder), "--reference", str(reference_file)])
        terminal = capfd.readouterr().out
    finally:
        listener.close()
    assert code == 0
    raw = (folder / "test_results.json").read_text()
    results = json.loads(raw)
    assert results["score"] == 0, _pretty(results)
    assert results["extra_data"]["sandbox"]["mode"] == "bwrap"
    found = evidence(results)
    assert set(found) == {"calc_p_Q", "calc_R_WL7_ref", "ik", "velocity", "impedance"}, found
    assert found["calc_p_Q"]["roots"] == [] and found["calc_p_Q"]["hits"] == []
    assert found["calc_R_WL7_ref"]["wheels"] == []
    assert all(code != 0 for code in found["calc_R_WL7_ref"]["git"])
    ik = found["ik"]
    assert ik["reload_has_pointwise_ik"] is False
    assert all(v != "imported" for k, v in ik.items() if k.startswith("doorlab."))
    assert all(v != "opened" for k, v in ik.items() if k.startswith("dir_fd"))
    velocity = found["velocity"]
    assert velocity["grader_seen"] == [] and len(velocity["pids"]) <= 2
    assert velocity["socket"] != "connected" and velocity["tcp"] != "connected"
    assert listener.received == []
    impedance = found["impedance"]
    assert impedance["notes_seen"] == [] and impedance["shm_written_mib"] <= 64
    assert _leftovers(mark) == []
    # Text hygiene: every string of the results and the terminal (the student's text is
    # there, without what drew it: escape sequences, NUL, carriage returns, bad UTF-8).
    assert "Total score: 14 / 14" in raw
    for text in [*_strings(results), terminal]:
        text.encode("utf-8")  # no lone surrogate
        assert not [c for c in CONTROL if c in text], text[:500]
    assert terminal.rstrip().splitlines()[-2] == f"Total score: 0 / {FULL_MARKS:g}"


def _batch_folders(public: Path, secret: str, mark: str) -> tuple[Path, Path]:
    victim = init_folder(public / "victim", solutions=True)
    path = victim / "open_left_door.py"
    path.write_text(f"# {secret}\n" + path.read_text())
    (victim / "test_results.json").write_text(json.dumps({"output": secret}))
    attacker = init_folder(public / "attacker")
    half = len(secret) // 2  # the whole secret is nowhere in the attacker's own code
    search = f"""
import json, os
SECRET = {secret[:half]!r} + {secret[half:]!r}
ev = {{"hits": [], "notes": [f for d in ("/tmp", "/dev/shm") for f in os.listdir(d)
                          if {mark!r} in f]}}
for top in [t for t in os.listdir("/") if t not in ("sys", "dev", "usr")]:
    if os.path.islink("/" + top):
        continue
    for dirpath, dirnames, filenames in os.walk("/" + top):
        for f in filenames:
            path = os.path.join(dirpath, f)
            try:
                if os.path.getsize(path) < 200_000:
                    if SECRET in open(path, errors="replace").read():
                        ev["hits"].append(path)
            except OSError:
                pass
print("EVIDENCE batch " + json.dumps(ev))
raise NotImplementedError("calc_p_Q: found " + " ".join(ev["hits"]))
"""
    body = "\n".join("    " + line if line else line for line in search.strip().splitlines())
    stub = '    raise NotImplementedError("calc_p_Q: your code here")'
    path = attacker / "open_left_door.py"
    path.write_text(path.read_text().replace(stub, body))
    return victim, attacker


@pytest.mark.slow
def test_one_submission_never_sees_another_graded_beside_it(public, reference_file):
    """Two folders graded at the same time: the attacker's code reads every file of its
    view and /proc for the victim's secret (in its code and its results file): its results
    hold no trace of it, and the victim's calc_p_Q passes. The attacker also finds none of
    the notes the previous test's submission left in /tmp and /dev/shm."""
    secret = f"victim-secret-{time.time_ns()}"
    victim, attacker = _batch_folders(public, secret, "doorlab-note-")
    only = [UNIT["calc_p_Q"]]
    reference = pset_fixtures.reference()
    results: dict[str, dict] = {}

    def run(name: str, folder: Path) -> None:
        results[name] = grade(folder, only=only, reference=reference)

    threads = [threading.Thread(target=run, args=a) for a in (("v", victim), ("a", attacker))]
    for t in threads:
        t.start()
    for t in threads:
        t.join(300)
    assert results["v"]["score"] == 1.0, _pretty(results["v"])
    assert results["a"]["score"] == 0.0
    assert secret not in json.dumps(results["a"])
    found = evidence(results["a"])["batch"]
    assert found == {"hits": [], "notes": []}, found


# One view per grading, a fresh process per test ----------------------------------------------

LEAVE_BEHIND = r"""
import ctypes, json, os, signal, subprocess, sys
ev = {"pids": sorted(int(p) for p in os.listdir("/proc") if p.isdigit())}
for what in ("/proc/1/fd", "/proc/1/mem", "/proc/1/environ"):
    try:
        if what.endswith("fd"):
            ev[what] = os.listdir(what)
        else:
            with open(what, "rb") as f:
                f.read(16)
            ev[what] = "read"
    except OSError as e:
        ev[what] = type(e).__name__
libc = ctypes.CDLL(None, use_errno=True)
ev["ptrace"] = libc.ptrace(16, 1, 0, 0)  # PTRACE_ATTACH to the view's first process
for sig in (signal.SIGKILL, signal.SIGTERM, signal.SIGINT, signal.SIGSTOP):
    try:
        os.kill(1, sig)
    except OSError as e:
        ev[sig.name] = type(e).__name__
subprocess.Popen([sys.executable, "-c", "import time; time.sleep(600)"], start_new_session=True,
                 stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL)
for folder in ("/tmp", "/dev/shm", "/pset"):
    try:
        with open(os.path.join(folder, "note-" + MARK), "w") as f:
            f.write("the answer is 42")
        ev.setdefault("notes", []).append(folder)
    except OSError:
        pass
libc.shmget(4242, 4096, 0o1666)  # IPC_CREAT | 0666: a System V segment left in the view
if os.uname().machine == "x86_64":  # a note in the user's keyring (add_key: 248)
    ev["key"] = libc.syscall(248, b"user", MARK.encode(), b"42", 2, -4)
print("EVIDENCE leave " + json.dumps(ev))
raise NotImplementedError("calc_R_WL7_ref: left notes for the next test")
"""
LOOK_BACK = r"""
import json, os
ev = {"pids": sorted(int(p) for p in os.listdir("/proc") if p.isdigit()), "me": os.getpid()}
ev["files"] = sorted(os.listdir("/tmp") + os.listdir("/dev/shm"))
ev["shm"] = open("/proc/sysvipc/shm").read().splitlines()[1:]
try:
    ev["pset"] = os.listdir("/pset")
except OSError as e:
    ev["pset"] = type(e).__name__
if os.uname().machine == "x86_64":  # keyctl(KEYCTL_SEARCH, the user's keyring, ...): 250
    ctypes = __import__("ctypes")
    libc = ctypes.CDLL(None, use_errno=True)
    ev["key"] = libc.syscall(250, 10, -4, b"user", MARK.encode(), 0)
print("EVIDENCE look " + json.dumps(ev))
raise NotImplementedError("calc_p_Q: nothing found")
"""


@pytest.mark.slow
def test_each_test_gets_a_fresh_view_whose_first_process_is_out_of_reach(
    public, reference_file, tmp_path
):
    """Two unit tests of one grading share a view, one after the other. The first cannot
    read, trace or signal the view's first process (it forks the next test all the same), and
    leaves a detached process, notes in /tmp, /dev/shm and /pset and a System V segment (a
    key in the sandbox user's keyring is refused: the view's filter); the second sees none of
    it: only the first process and itself."""
    folder = init_folder(public / "leave_behind")
    mark = f"doorlab-{os.getpid()}-{time.time_ns()}"
    _insert(folder, "calc_R_WL7_ref", LEAVE_BEHIND, {"MARK": mark})
    _insert(folder, "calc_p_Q", LOOK_BACK, {"MARK": mark})
    reference = json.loads(reference_file.read_text())["extra_data"]["reference"]
    only = [UNIT["calc_R_WL7_ref"], UNIT["calc_p_Q"]]
    results = grade(folder, only=only, reference=reference, jobs=1)  # one view, in this order
    assert results["score"] == 0, _pretty(results)
    found = evidence(results)
    leave, look = found["leave"], found["look"]
    assert leave["pids"] == [1, max(leave["pids"])]  # the first process and this one
    for what in ("/proc/1/fd", "/proc/1/mem", "/proc/1/environ"):
        assert leave[what] == "PermissionError", (what, leave[what])
    assert leave["ptrace"] == -1
    # /pset is the view's own tmpfs (issue 43), emptied before each test as /tmp is.
    assert leave["notes"] == ["/tmp", "/dev/shm", "/pset"]
    assert look["pids"] == [1, look["me"]], look  # no detached process of the earlier test
    # What the view itself holds there: the read-only way to a venv made under /tmp (a clone
    # in /tmp/ci); usually nothing.
    plan = bwrap_root.plan_view(bwrap_root.build_site(tmp_path / "site"), bwrap_root.find_bwrap())
    assert look["files"] == sorted(Path(top).name for top in plan.private_tops), look
    assert look["shm"] == [], look
    if "key" in leave:  # the keyring is the user's, kept by the kernel: the filter refuses it
        assert leave["key"] == -1 and look["key"] == -1, (leave, look)
    assert look["pset"] == ["unit_calc_p_Q"], look  # its own folder, no note
    for t in results["tests"]:
        assert "NotImplementedError" in t["output"], t


# --insecure ---------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def system_venv(public) -> Path:
    """A venv of the system's Python (reachable by every user, unlike a pyenv in /root)
    whose doorlab and dependencies are this environment's (a path file; root's, read-only
    to others)."""
    python = shutil.which("python3", path="/usr/bin:/bin")
    if python is None:
        pytest.skip("needs the system's python3 (/usr/bin/python3)")
    version = subprocess.run(
        [python, "-c", "import sys; print(sys.version_info[:2])"], capture_output=True, text=True
    ).stdout.strip()
    if version != str(sys.version_info[:2]):
        pytest.skip(f"the system's python3 is {version}, not this interpreter's version")
    venv = public / "system-venv"
    return _venv_with_doorlab(python, venv)


def _venv_with_doorlab(python: str, venv: Path) -> Path:
    subprocess.run([python, "-m", "venv", "--without-pip", str(venv)], check=True)
    where = "import sysconfig; print(sysconfig.get_path('purelib'))"
    purelib = subprocess.run(
        [str(venv / "bin" / "python"), "-c", where],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    # doorlab's source and this environment's packages, where the other user can read them
    # (a copy where the checkout is in a folder only its owner can read).
    paths = [readable_site.readable_source(), *readable_site.readable_site_packages()]
    Path(purelib, "doorlab_tests.pth").write_text("\n".join(paths))
    return venv


def _cli(
    python: Path, *args: str, env: dict, user: int | None = None
) -> subprocess.CompletedProcess:
    code = "import sys; from doorlab.cli.parser import main; sys.exit(main(sys.argv[1:]))"
    return subprocess.run(
        [str(python), "-I", "-c", code, *args],
        capture_output=True,
        text=True,
        timeout=600,
        env=env,
        cwd="/",
        user=user,
        group=user,
        extra_groups=[] if user is not None else None,
    )


@pytest.mark.slow
@pytest.mark.skipif(not AS_ROOT, reason="as root: the separate user without a view")
def test_insecure_grades_without_the_view_as_another_user_and_says_so(
    public, system_venv, reference_file
):
    """No bwrap, --insecure, as root: student code runs as the sandbox user; the honesty
    guard (the second line) still catches doorlab.control.laws and a dir_fd open of laws.py; the
    results and the summary's first line say it ran without the minimal root."""
    folder = init_folder(public / "insecure")
    path = folder / "manip_station_sim" / "robot_plans.py"
    stub = (
        '        raise NotImplementedError("IiwaTaskSpaceVelocityPlan.CalcPositionCommand: '
        'your code here")'
    )
    path.write_text(
        path.read_text().replace(
            stub,
            "        from doorlab.control.laws import velocity_law\n"
            "        return velocity_law(q_iiwa, self.Jv_WL7q, err_xyz, R_L7L7r, control_period)",
        )
    )
    env = {"PATH": "/usr/bin:/bin", bwrap_root.BWRAP_ENV: str(public / "no-bwrap")}
    proc = _cli(
        system_venv / "bin" / "python",
        *("pset", "grade", str(folder), "--insecure", "--reference", str(reference_file)),
        env=env,
    )
    assert proc.returncode == 0, proc.stderr[-3000:] + proc.stdout[-3000:]
    results = json.loads((folder / "test_results.json").read_text())
    assert results["score"] == 0
    facts = results["extra_data"]["sandbox"]
    assert facts["mode"] == "uid" and facts["isolated"] is False
    assert "not installed" in facts["why_no_minimal_root"]
    assert 0 not in facts["student_uids"]
    assert proc.stdout.startswith("NOT ISOLATED (insecure)"), proc.stdout[:300]
    velocity = next(t for t in results["tests"] if "CalcPositionCommand" in t["name"])
    assert "doorlab.control.laws" in velocity["output"], velocity["output"]


# As an ordinary user ------------------------------------------------------------------------


def _user_can_bwrap(public: Path) -> bool:
    proc = subprocess.run(
        ["bwrap", "--unshare-all", "--unshare-user", "--ro-bind", "/", "/", "/usr/bin/true"],
        user=TEST_UID,
        group=TEST_UID,
        extra_groups=[],
        capture_output=True,
        cwd="/",
    )
    return proc.returncode == 0


@pytest.fixture(scope="module")
def user_venv(public, system_venv) -> Path:
    """The ordinary user's own venv (theirs to write, as a user's venv is)."""
    if not AS_ROOT:
        pytest.skip("changes user: runs as root")
    if shutil.which("bwrap") is None or not _user_can_bwrap(public):
        pytest.skip("bwrap cannot make user namespaces for an ordinary user here")
    venv = _venv_with_doorlab("/usr/bin/python3", public / "user-venv")
    subprocess.run(["chown", "-R", f"{TEST_UID}:{TEST_UID}", str(venv)], check=True)
    return venv


def _tree(folder: Path) -> dict[str, tuple]:
    return {
        str(p.relative_to(folder)): (p.stat().st_mtime_ns, p.stat().st_size)
        for p in [folder, *folder.rglob("*")]
    }


PTH_ATTACK = r"""
import os, sys
written = []
for folder in [*sys.path, *TARGETS]:
    if folder in ("", os.getcwd()):
        continue  # its own scratch copy: writable, thrown away after the test
    try:
        with open(os.path.join(folder, "zz_forge.pth"), "w") as f:
            f.write("import os; os.environ['FORGED'] = '1'\n")
        written.append(folder)
    except OSError as e:
        pass
import ctypes
libc = ctypes.CDLL(None, use_errno=True)
userns = "made" if libc.unshare(0x10000000) == 0 else os.strerror(ctypes.get_errno())
print("EVIDENCE pth " + __import__("json").dumps({"written": written, "userns": userns}))
raise NotImplementedError("calc_p_Q: no .pth written")
"""


@pytest.mark.slow
def test_as_an_ordinary_user_the_venv_is_never_writable_from_the_student_s_view(
    public, user_venv, reference_file
):
    """An ordinary user (with user namespaces) grades stubs whose calc_p_Q writes a .pth
    file into every folder on its path and into the user's venv, then tries a user
    namespace of its own: nothing is written, no namespace made, the venv is unchanged, and
    the next grading of the stubs scores 0."""
    purelib = next((user_venv / "lib").glob("python3*/site-packages"))
    folder = init_folder(public / "user-stubs")
    path = folder / "open_left_door.py"
    targets = [str(purelib), str(Path(doorlab.__file__).resolve().parent)]
    body = f"TARGETS = {targets!r}\n" + PTH_ATTACK
    body = "\n".join("    " + line if line else line for line in body.strip().splitlines())
    path.write_text(
        path.read_text().replace('    raise NotImplementedError("calc_p_Q: your code here")', body)
    )
    subprocess.run(["chown", "-R", f"{TEST_UID}:{TEST_UID}", str(folder)], check=True)
    before = _tree(user_venv)
    env = {"PATH": "/usr/bin:/bin", "HOME": str(folder)}
    python = user_venv / "bin" / "python"
    args = ("pset", "grade", str(folder), "--reference", str(reference_file))
    proc = _cli(python, *args, env=env, user=TEST_UID)
    assert proc.returncode == 0, proc.stderr[-3000:] + proc.stdout[-3000:]
    results = json.loads((folder / "test_results.json").read_text())
    assert results["score"] == 0
    facts = results["extra_data"]["sandbox"]
    assert facts["mode"] == "bwrap" and facts["student_uids"] == [TEST_UID]
    assert facts["python_path_read_only"] and facts["reference_hidden"], facts["seen"]
    found = evidence(results)["pth"]
    assert found["written"] == [] and found["userns"] != "made", found  # --disable-userns
    assert _tree(user_venv) == before
    again = init_folder(public / "user-stubs-again")
    subprocess.run(["chown", "-R", f"{TEST_UID}:{TEST_UID}", str(again)], check=True)
    code = (
        "import json, sys; from doorlab.pset.grading.grader import grade, load_reference, TESTS\n"
        "units = [t.name for t in TESTS if 'unit test' in t.name]\n"
        "r = grade(sys.argv[1], only=units, reference=load_reference(sys.argv[2]))\n"
        "print(json.dumps(r['score']))"
    )
    proc = subprocess.run(
        [str(python), "-I", "-c", code, str(again), str(reference_file)],
        capture_output=True,
        text=True,
        timeout=600,
        env=env,
        cwd="/",
        user=TEST_UID,
        group=TEST_UID,
        extra_groups=[],
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert json.loads(proc.stdout.strip().splitlines()[-1]) == 0


@pytest.mark.slow
def test_as_an_ordinary_user_without_namespaces_the_grader_refuses(public, user_venv):
    """bwrap refusing namespaces (the kernel's answer without unprivileged user
    namespaces): `pset grade` stops with one line; --insecure too, since the student's code
    would run as that user, who can write doorlab's installation (the user's venv)."""
    folder = init_folder(public / "user-refused")
    subprocess.run(["chown", "-R", f"{TEST_UID}:{TEST_UID}", str(folder)], check=True)
    fake = _fake_bwrap(public)
    env = {"PATH": "/usr/bin:/bin", "HOME": str(folder), bwrap_root.BWRAP_ENV: str(fake)}
    python = user_venv / "bin" / "python"
    for extra, expected in (((), "--insecure grades"), (("--insecure",), "is writable")):
        proc = _cli(python, "pset", "grade", str(folder), *extra, env=env, user=TEST_UID)
        assert proc.returncode == 1, proc.stdout[-2000:]
        assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr
        assert "user namespaces" in proc.stderr and expected in proc.stderr, proc.stderr
        assert not (folder / "test_results.json").exists()


@pytest.mark.slow
def test_a_student_s_self_check_without_namespaces_grades_and_says_so(
    public, user_venv, reference_file
):
    """The folder's test_pset_5a.py (the notebook's last cell) on a student's machine where
    bwrap cannot make namespaces: it grades anyway (their own code, nobody to protect), the
    summary's first line and the results say it ran without the minimal root."""
    folder = init_folder(public / "self-check")  # the stubs: quick to grade
    subprocess.run(["chown", "-R", f"{TEST_UID}:{TEST_UID}", str(folder)], check=True)
    env = {
        "PATH": "/usr/bin:/bin",
        "HOME": str(folder),
        bwrap_root.BWRAP_ENV: str(_fake_bwrap(public)),
    }
    proc = subprocess.run(
        [str(user_venv / "bin" / "python"), "test_pset_5a.py", "out.json"]
        + ["--reference", str(reference_file)],
        capture_output=True,
        text=True,
        timeout=600,
        env=env,
        cwd=folder,
        user=TEST_UID,
        group=TEST_UID,
        extra_groups=[],
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.startswith("NOT ISOLATED (self-check)"), proc.stdout[:300]
    results = json.loads((folder / "out.json").read_text())
    assert results["score"] == 0 and len(results["tests"]) == len(TESTS)
    facts = results["extra_data"]["sandbox"]
    assert facts["mode"] == "none" and "user namespaces" in facts["why_no_minimal_root"]


# Text from student code ---------------------------------------------------------------------


def test_clean_text_leaves_words_and_removes_what_draws_on_a_terminal():
    assert clean_text("calc_p_Q(0.5) = [1.0, 2.0]\n\ttab") == "calc_p_Q(0.5) = [1.0, 2.0]\n\ttab"
    assert clean_text("é ü 中文 ✓") == "é ü 中文 ✓"
    dirty = "a\x1b[31mred\x1b[0m\x1b]0;title\x07\x1b[2J\x1b[1;1H\rb\x00c\x08\x9b1md\u202ee\ud800f"
    assert clean_text(dirty) == "ared" + "bcde\ufffdf"
    assert clean_text("line\r\nnext") == "line\nnext"
    assert clean_text(b"\xff ok") == "\ufffd ok"
    assert clean_text("x" * 10, 4) == "xxx\u2026" and clean_text("abc", 4) == "abc"


def test_the_guard_catches_dir_fd_opens_of_hidden_files(tmp_path):
    """The second line, alone (a fresh process: an audit hook stays for good): opening a
    hidden file through a directory descriptor, or relative to the working directory,
    fails and is recorded; other files open."""
    hidden = tmp_path / "laws.py"
    hidden.write_text("SOLUTION = 1\n")
    (tmp_path / "notes.txt").write_text("mine")
    code = f"""
import os, sys
from doorlab.pset.isolation.guard import Guard, HonestyError
guard = Guard({{"doorlab.control.laws": "the laws"}}, [{str(hidden)!r}])
guard.install()
fd = os.open({str(tmp_path)!r}, os.O_RDONLY)
for name in ("laws.py", "notes.txt"):
    try:
        os.close(os.open(name, os.O_RDONLY, dir_fd=fd)); print(name, "opened")
    except HonestyError:
        print(name, "refused")
os.chdir({str(tmp_path)!r})
try:
    open("laws.py").read(); print("relative opened")
except HonestyError:
    print("relative refused")
print("violation", guard.violation is not None)
"""
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == (
        "laws.py refused notes.txt opened relative refused violation True".split()
    )


def test_bwrap_without_size_puts_tmp_and_shm_in_the_job_s_folder(work):
    """bwrap older than 0.7 (Ubuntu 22.04's 0.6) has no --size: /tmp and /dev/shm become two
    folders of the job (on disk, removed with it) instead of unbounded RAM."""
    plan = bwrap_root.plan_view(bwrap_root.build_site(work / "site"), "/usr/bin/bwrap")
    old = bwrap_root.View(**{**plan.__dict__, "sized_tmpfs": False})
    dirs = bwrap_root.job_tmp_dirs(old, work / "tmp_job", None)
    argv = bwrap_root.bwrap_argv(old, work / "scratch", dirs, as_root=False)
    assert "--size" not in argv
    assert argv[argv.index("/tmp") - 1] == str(dirs[0])
    assert argv[argv.index("/dev/shm") - 1] == str(dirs[1])
    assert bwrap_root.job_tmp_dirs(plan, work / "unused", None) is None


def test_signals_reach_the_student_s_message_through_bwrap(work):
    """bwrap reports a death by signal N as exit code 128 + N: the student's message names
    the signal (SIGXCPU: the CPU limit)."""
    proc = _in_view(work, "import os, signal; os.kill(os.getpid(), signal.SIGXCPU)")
    assert proc.returncode == 128 + signal.SIGXCPU
