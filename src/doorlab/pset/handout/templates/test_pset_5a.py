"""The problem set's grader: ``python3 test_pset_5a.py test_results.json``.

Writes Gradescope-format JSON and prints a summary; the tests and their thresholds are
described in README.md (the grader itself is doorlab.pset.grading.grader). With your course's
course.yaml (it comes with the handout) it grades as the course does: its points, margins and
random seed, the tests it lets you run. It runs in Python's isolated mode and imports nothing
from this folder: your code is graded in a separate, sandboxed process.
"""

import os
import sys

_HERE = os.path.dirname(os.path.abspath(__file__))


def pretty_format_json_results(path):
    """A readable summary of a results file (for the notebook's last cell)."""
    from doorlab.pset.grading.grader import pretty_format_json_results as summary

    return summary(path)


def _doorlab_python():
    """The interpreter of the ``doorlab`` command on PATH, if there is one."""
    import shutil

    command = shutil.which("doorlab")
    if command is None:
        return None
    try:
        with open(command, "rb") as f:
            first = f.readline().decode("utf-8", "replace").strip()
    except OSError:
        return None
    if not first.startswith("#!"):
        return None
    return first[2:].strip() or None


def _main():
    # Nothing from this folder may shadow the standard library here (json.py, copy.py...).
    sys.path[:] = [p for p in sys.path if os.path.abspath(p or os.curdir) != _HERE]
    import subprocess

    probe = "import importlib.util, sys; sys.exit(importlib.util.find_spec('doorlab') is None)"
    if subprocess.run([sys.executable, "-I", "-c", probe], check=False).returncode != 0:
        other = _doorlab_python()
        hint = (
            f"run it with {other} test_pset_5a.py"
            if other
            else (
                f'install doorlab into it: {sys.executable} -m pip install "./{{ wheel }}[pset]" '
                "(in this folder; the wheel comes with your course's handout), or run the "
                "grader with the Python that has doorlab"
            )
        )
        print(f"test_pset_5a.py: {sys.executable} has no doorlab; {hint}", file=sys.stderr)
        return 2
    # --self-check: your own folder, graded in the grader's sandbox where this machine has
    # one (bubblewrap), else as you (the results say which).
    argv = [sys.executable, "-I", "-m", "doorlab.pset.grading.grader", _HERE, *sys.argv[1:]]
    argv.append("--self-check")
    course = os.path.join(_HERE, "course.yaml")  # the course's settings (the handout's)
    if os.path.isfile(course):
        argv += ["--course", course]
    os.execv(sys.executable, argv)


if __name__ == "__main__":
    sys.exit(_main())
