"""The student's process: runs the submission's functions and answers the grader in numbers.

Started by :class:`doorlab.pset.isolation.handle.StudentProcess` with ``RFD WFD CONFIG`` (the
channel's descriptors, the honesty guard's table as JSON) in a scratch copy of the submission, under
the limits of :mod:`doorlab.pset.isolation.sandbox`, in the student's view
(:mod:`doorlab.pset.isolation.bwrap_root`: bubblewrap, where only doorlab's student side exists) or,
without one, as ``python -I -B -m doorlab.pset.isolation.worker``. Before any of the student's code
runs it imports everything the problem set's files need (so a helper named ``json.py``, ``copy.py``
or ``numpy.py`` in the folder shadows nothing), notes what it can see (:func:`observe`: the grader
reports it), installs the honesty guard (:mod:`doorlab.pset.isolation.guard`), says hello, and only
then puts the folder on ``sys.path``. Then it serves requests (JSON frames; per-tick array frames)
until the grader closes the channel.

Nothing this process says is trusted: the student's code can replace any of it. It only
answers the grader's questions (the student's outputs for inputs the grader chose); every
verdict is computed on the grader's side.
"""

from __future__ import annotations

import importlib
import json
import os
import sys
import traceback
from pathlib import Path

TRACEBACK_LINES = 12
"""Lines of a student's traceback kept."""
MESSAGE_CHARS = 500
"""Characters of an exception's message kept."""


def _preload() -> None:
    """What the problem set's files import, loaded before the folder is on sys.path."""
    import copy  # noqa: F401
    import struct  # noqa: F401

    import numpy  # noqa: F401
    import pydrake.math  # noqa: F401
    import pydrake.multibody.inverse_kinematics  # noqa: F401
    import pydrake.multibody.plant  # noqa: F401
    import pydrake.solvers  # noqa: F401
    import pydrake.trajectories  # noqa: F401

    import doorlab.cell.door_model  # noqa: F401
    import doorlab.cell.frames  # noqa: F401
    import doorlab.constants  # noqa: F401
    import doorlab.control.ik  # noqa: F401
    import doorlab.pset.handout.station_api  # noqa: F401
    import doorlab.pset.handout.task_helpers  # noqa: F401


class AnswerError(Exception):
    """The student's function returned something that is not the expected kind of value."""


def _relative(filename: object, folder: Path) -> str | None:
    """``filename`` relative to the student's folder (None: not one of its files)."""
    try:
        path = Path(str(filename)).resolve()
    except (OSError, ValueError):
        return None
    return str(path.relative_to(folder)) if path.is_relative_to(folder) else None


def import_failure(name: str, e: BaseException, folder: Path) -> str:
    """One line saying which of the student's files did not import, where, and that every
    test using it fails for that reason (not the test's own check)."""
    where = None
    if isinstance(e, SyntaxError):  # the file itself: no frame of it in the traceback
        where = (_relative(e.filename, folder), e.lineno)
    if where is None or where[0] is None:
        frames = [
            (rel, f.lineno)
            for f in traceback.extract_tb(e.__traceback__)
            if (rel := _relative(f.filename, folder)) is not None
        ]
        where = frames[-1] if frames else (name.replace(".", "/") + ".py", None)
    rel, line = where
    try:
        text = (e.msg if isinstance(e, SyntaxError) else str(e)).strip().splitlines()
    except BaseException:  # noqa: BLE001 - a student's __str__ may raise anything
        text = []
    detail = f"{type(e).__name__}: {text[0][:200]}" if text else type(e).__name__
    at = f" at line {line}" if line else ""
    return (
        f"your file {rel} did not import ({detail}{at}), so every test that uses {rel} "
        f'fails until it does: python3 -c "import {name}" in your folder shows the error'
    )


def _vector(value, size: int, what: str):
    import numpy as np

    try:
        array = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise AnswerError(
            f"{what} returned {type(value).__name__}, expected a ({size},) array"
        ) from None
    if array.shape != (size,):
        raise AnswerError(f"{what} returned shape {np.shape(value)}, expected ({size},)")
    return array


def _trajectory(qtraj) -> dict:
    """A PiecewisePolynomial as numbers: breaks and each segment's coefficients."""
    from pydrake.trajectories import PiecewisePolynomial

    from doorlab.pset.isolation.channel import MAX_DEGREE, MAX_SEGMENTS

    if not isinstance(qtraj, PiecewisePolynomial):
        raise AnswerError(f"qtraj must be a PiecewisePolynomial, got {type(qtraj).__name__}")
    if qtraj.rows() != 7 or qtraj.cols() != 1:
        raise AnswerError(f"qtraj must have 7 rows and 1 column, has {qtraj.rows()}x{qtraj.cols()}")
    n = qtraj.get_number_of_segments()
    if n > MAX_SEGMENTS:
        raise AnswerError(f"qtraj has {n} segments (at most {MAX_SEGMENTS} are accepted)")
    segments = []
    for i in range(n):
        degree = qtraj.getSegmentPolynomialDegree(i)
        if degree > MAX_DEGREE:
            raise AnswerError(f"qtraj's segment {i} has degree {degree} (at most {MAX_DEGREE})")
        rows = []
        for r in range(7):
            c = list(qtraj.getPolynomial(i, r, 0).GetCoefficients())
            rows.append([float(x) for x in c] + [0.0] * (degree + 1 - len(c)))
        segments.append(rows)
    return {"breaks": [float(t) for t in qtraj.get_segment_times()], "coefficients": segments}


def _tabulated_helpers(table: dict):
    """calc_p_Q and calc_R_WL7_ref interpolated from the grader's table of doorlab's values
    (:func:`doorlab.pset.grading.episodes.reference_helper_table`): the episode's inputs, as
    numbers."""
    import numpy as np
    from pydrake.common.eigen_geometry import Quaternion
    from pydrake.math import RotationMatrix
    from pydrake.trajectories import PiecewisePolynomial, PiecewiseQuaternionSlerp

    taus = [float(t) for t in table["taus"]]
    position = PiecewisePolynomial.FirstOrderHold(taus, np.array(table["p_Q"], dtype=float).T)
    quaternions = [Quaternion(np.array(q, dtype=float)) for q in table["quaternions"]]
    orientation = PiecewiseQuaternionSlerp(taus, quaternions)

    def calc_p_Q(tau):
        return position.value(min(max(float(tau), 0.0), 1.0)).ravel()

    def calc_R_WL7_ref(tau):
        return RotationMatrix(orientation.orientation(min(max(float(tau), 0.0), 1.0)))

    return calc_p_Q, calc_R_WL7_ref


class Server:
    """Answers the grader's requests with the student's functions."""

    def __init__(self, folder: Path):
        self.folder = folder
        self.plan = None

    def module(self, name: str):
        """The student's module ``name``; a file that does not import is one line saying so
        (not Python's import machinery's traceback)."""
        try:
            return importlib.import_module(name)
        except MemoryError:  # the limit's own message (doorlab.pset.isolation.handle)
            raise
        except Exception as e:  # noqa: BLE001 - a student's file may raise anything
            raise AnswerError(import_failure(name, e, self.folder)) from None

    def _plan_class(self, kind: str):
        plans = self.module("manip_station_sim.robot_plans")
        return {
            "velocity": plans.IiwaTaskSpaceVelocityPlan,
            "impedance": plans.IiwaTaskSpaceImpedancePlan,
        }[kind]

    # Unit tests -------------------------------------------------------------------------

    def op_p_Q(self, request: dict) -> dict:
        calc_p_Q = self.module("open_left_door").calc_p_Q
        return {
            "values": [_vector(calc_p_Q(float(t)), 3, "calc_p_Q").tolist() for t in request["taus"]]
        }

    def op_R_WL7_ref(self, request: dict) -> dict:
        from pydrake.math import RotationMatrix

        calc_R_WL7_ref = self.module("open_left_door").calc_R_WL7_ref
        values = []
        for t in request["taus"]:
            R = calc_R_WL7_ref(float(t))
            if isinstance(R, RotationMatrix):
                values.append({"matrix": R.matrix().tolist()})
            else:
                values.append({"type": type(R).__name__})
        return {"values": values}

    def op_law(self, request: dict) -> dict:
        import numpy as np
        from pydrake.math import RotationMatrix

        cls = self._plan_class(request["kind"])
        method = "CalcPositionCommand" if request["kind"] == "velocity" else "CalcTorqueCommand"
        values = []
        for case in request["cases"]:
            p_Q_end = np.array(case["p_Q_end"], dtype=float)
            R_end = RotationMatrix(np.array(case["R_ref_end"], dtype=float))
            plan = cls(
                calc_p_Q=lambda s, p=p_Q_end: p * s,
                calc_R_WL7_ref=lambda s, R=R_end: R,
                duration=float(case["duration"]),
                p_L7Q=np.array(case["p_L7Q"], dtype=float),
            )
            plan.UpdatePwq0(np.array(case["p_WQ_0"], dtype=float))
            q, q_cmd, v, tau, t_plan, dt = case["args"]
            args = (
                np.array(q, dtype=float),
                np.array(q_cmd, dtype=float),
                np.array(v, dtype=float),
                np.array(tau, dtype=float),
                float(t_plan),
                float(dt),
            )
            values.append(_vector(getattr(plan, method)(*args), 7, method).tolist())
        return {"values": values}

    def op_ik(self, request: dict) -> dict:
        import numpy as np

        from doorlab.pset.handout.task_helpers import interpolate_arc, interpolate_yaw

        a, b = float(request["a"]), float(request["b"])
        offset = np.array(request["offset"], dtype=float)

        def position(tau):
            return interpolate_arc(a + (b - a) * tau) + offset

        def orientation(tau):
            return interpolate_yaw(a + (b - a) * tau)

        kwargs = {
            "InterpolatePosition": position,
            "InterpolateOrientation": orientation,
            "p_L7Q": np.array(request["p_L7Q"], dtype=float),
            "duration": float(request["duration"]),
            "num_knot_points": int(request["num_knot_points"]),
            "q_initial_guess": np.array(request["q_initial_guess"], dtype=float),
            "position_tolerance": float(request["position_tolerance"]),
        }
        if request.get("theta_bound") is not None:
            kwargs["theta_bound"] = float(request["theta_bound"])
        result = self.module("ik_utils").InverseKinPointwise(**kwargs)
        try:
            qtraj, q_knots = result
        except (TypeError, ValueError):
            raise AnswerError(
                f"InverseKinPointwise must return (qtraj, q_knots), got {type(result).__name__}"
            ) from None
        try:
            knots = np.asarray(q_knots, dtype=float).tolist()
        except (TypeError, ValueError):
            raise AnswerError(f"q_knots is {type(q_knots).__name__}, not an array") from None
        return {"q_knots": knots, "qtraj": _trajectory(qtraj)}

    # Episodes ---------------------------------------------------------------------------

    def op_plan(self, request: dict) -> dict:
        import numpy as np

        if request.get("reference_helpers") is not None:  # the assignment's default
            calc_p_Q, calc_R_WL7_ref = _tabulated_helpers(request["reference_helpers"])
        else:
            old = self.module("open_left_door")
            calc_p_Q, calc_R_WL7_ref = old.calc_p_Q, old.calc_R_WL7_ref
        cls = self._plan_class(request["kind"])

        def make():
            return cls(
                calc_p_Q=calc_p_Q,
                calc_R_WL7_ref=calc_R_WL7_ref,
                duration=float(request["duration"]),
                p_L7Q=np.array(request["p_L7Q"], dtype=float),
            )

        # Fail fast (before the grader simulates 11 s) if the student's plan cannot run.
        probe = make()
        q = np.array(request["q_start"], dtype=float)
        args = (q, q.copy(), np.zeros(7), np.zeros(7), 0.5, 0.005)
        _vector(probe.CalcPositionCommand(*args), 7, "CalcPositionCommand")
        _vector(probe.CalcTorqueCommand(*args), 7, "CalcTorqueCommand")
        self.plan = make()
        return {"ok": True}

    def tick(self, values) -> list:
        import numpy as np

        q, q_cmd, v, tau = (values[i : i + 7].copy() for i in (0, 7, 14, 21))
        args = (q, q_cmd, v, tau, float(values[28]), float(values[29]))
        q_ref = _vector(self.plan.CalcPositionCommand(*args), 7, "CalcPositionCommand")
        tau_ff = _vector(self.plan.CalcTorqueCommand(*args), 7, "CalcTorqueCommand")
        return np.concatenate([q_ref, tau_ff])


def _error(e: BaseException, folder: Path) -> dict:
    if isinstance(e, AnswerError):
        return {"invalid": str(e)[:MESSAGE_CHARS]}
    frames = traceback.extract_tb(e.__traceback__)
    mine = []
    for f in frames:
        try:
            path = Path(f.filename).resolve()
        except (OSError, ValueError):
            continue
        if path.is_relative_to(folder):
            # Named as in the student's folder, not as in the grader's scratch copy.
            f.filename = str(path.relative_to(folder))
            mine.append(f)
    shown = traceback.format_list(mine or frames[-3:])
    lines = [line[:300] for line in "".join(shown).rstrip().splitlines()[-TRACEBACK_LINES:]]
    try:
        text = str(e)
    except BaseException:  # noqa: BLE001 - a student's __str__ may raise anything
        text = ""
    first = text.strip().splitlines()[0][:MESSAGE_CHARS] if text.strip() else ""
    return {"error": {"type": type(e).__name__, "message": first, "traceback": "\n".join(lines)}}


def network_isolated() -> bool:
    """True when this process's network namespace has no interface but loopback and no
    route (a fresh namespace: nothing reachable)."""
    try:
        devices = Path("/proc/net/dev").read_text().splitlines()[2:]
        routes = Path("/proc/net/route").read_text().splitlines()[1:]
    except OSError:
        return False
    names = [line.split(":", 1)[0].strip() for line in devices]
    return names == ["lo"] and not routes


def _can_make_user_namespace() -> bool:
    """Whether a child of this process can make a user namespace (the view's filter refuses)."""
    import ctypes

    pid = os.fork()
    if pid == 0:
        code = 1
        try:
            code = 0 if ctypes.CDLL(None).unshare(0x10000000) == 0 else 1  # CLONE_NEWUSER
        finally:
            os._exit(code)
    return os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1]) == 0


def observe(config: dict) -> dict:
    """What this process can see and do, before any of the student's code runs (the grader
    reports it as ``extra_data.sandbox``, judged on its own side)."""
    import importlib.util

    readable = [p for p in config.get("paths", []) if os.access(p, os.R_OK)]
    for name in config.get("modules", {}):
        try:
            spec = importlib.util.find_spec(name)
        except (ImportError, ValueError):
            continue
        if spec is not None and spec.origin and os.access(spec.origin, os.R_OK):
            readable.append(spec.origin)
    writable = [p for p in sys.path if p and os.path.isdir(p) and os.access(p, os.W_OK)]
    try:
        init = Path("/proc/1/comm").read_text().strip()
    except OSError:
        init = ""
    sizes = {}
    for where in ("/tmp", "/dev/shm"):
        try:
            st = os.statvfs(where)
            sizes[where] = st.f_blocks * st.f_frsize
        except OSError:
            pass
    return {
        "uid": os.getuid(),
        "network_isolated": network_isolated(),
        "user_namespaces_refused": not _can_make_user_namespace(),
        "reference_hidden": not readable,
        "reference_readable": readable[:5],
        "python_path_writable": writable[:5],
        # PID 1 of the view: bwrap's init, or the view's first process
        # (doorlab.pset.isolation.zygote).
        "pid_namespace": init in ("bwrap", "doorlab-view"),
        "tmpfs_bytes": sizes,
    }


def serve(rfd: int, wfd: int, config: dict) -> int:
    """Says hello, then answers requests until the channel closes."""
    _preload()
    import numpy as np

    from doorlab.pset.isolation.channel import KIND_ARRAY, Channel, ChannelClosed, parse_json
    from doorlab.pset.isolation.guard import Guard

    facts = observe(config)
    guard = Guard(config.get("modules", {}), config.get("paths", []))
    guard.install()
    channel = Channel(rfd, wfd)
    channel.send_json({"hello": facts})
    folder = Path.cwd().resolve()
    sys.path.insert(0, str(folder))
    server = Server(folder)
    while True:
        try:
            kind, body = channel.receive()
        except ChannelClosed:
            return 0
        try:
            if kind == KIND_ARRAY:
                answer = server.tick(np.frombuffer(body, dtype="<f8").astype(float))
            else:
                request = parse_json(body)
                answer = getattr(server, "op_" + request["op"])(request)
        except BaseException as e:  # noqa: BLE001 - a student's code may raise anything
            answer = _error(e, folder)
        if guard.violation is not None:
            answer = {"honesty": guard.violation}
        _flush()  # what the student's code printed reaches the grader with the answer
        if isinstance(answer, dict):
            channel.send_json(answer, allow_nan=True)
        else:
            channel.send_array(answer)


def _flush() -> None:
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except BaseException:  # noqa: BLE001 - the student's code may have replaced them
            pass


def main(argv: list[str]) -> int:
    """``RFD WFD [CONFIG_JSON]``."""
    rfd, wfd = int(argv[0]), int(argv[1])
    config = json.loads(argv[2]) if len(argv) > 2 else {}
    return serve(rfd, wfd, config if isinstance(config, dict) else {})


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
