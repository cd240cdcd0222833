"""``doorlab pset autograder OUT.zip``: the problem set's grader as a Gradescope autograder.

The zip follows Gradescope's autograder format (its files at the zip's root, extracted into
``/autograder/source``):

- ``setup.sh``: run once, as root, when Gradescope builds the image: installs what is
  missing of ``python3-venv`` and GLib (pydrake's one system library), creates the sandbox's
  user ``doorlab-student``, makes the virtual environment ``/autograder/doorlab-venv`` and
  installs into it the wheel below with exactly the versions of ``constraints.txt`` (from
  the package index), then runs ``--check``.
- ``run_autograder``: run for every submission: ``python -I -m doorlab.pset.classroom.gradescope``,
  which grades ``/autograder/submission`` through the one intake
  (:func:`doorlab.pset.grading.grader.grade_submission`) with the zip's assignment and writes
  ``/autograder/results/results.json``.
- ``doorlab-<version>-py3-none-any.whl``: the doorlab that wrote the zip
  (:mod:`doorlab.pset.classroom.wheel`).
- ``assignment.yaml``: the course's settings (``--assignment``; default: the defaults).
- ``constraints.txt``: the versions of everything grading runs on, pinned where the zip was
  written (:func:`doorlab.pset.classroom.wheel.constraints_text`).
- ``doorlab_autograder.json``: the zip's settings: doorlab's version, the SHA-256 of its
  package files, of the assignment and of the constraints, and the zip's ``digest`` over all
  of them (checked before every grading, so the zip's doorlab and settings are the ones that
  grade); the tests run at a time; the files a submission may replace.

``DOORLAB_AUTOGRADER_ROOT`` (or ``--root``) replaces ``/autograder``, for tests and rehearsals.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import zipfile
from collections.abc import Sequence
from importlib import metadata
from pathlib import Path

from doorlab.errors import DoorlabError
from doorlab.pset.classroom.wheel import (
    check_zip_destination,
    constraints_text,
    package_digest,
    package_files,  # noqa: F401 - part of this module's API (the tests use it)
    python_version,
    wheel_bytes,
    write_entry,
    write_stored,
    write_zip,
)
from doorlab.pset.handout.folder import STUDENT_FILES

ROOT_ENV = "DOORLAB_AUTOGRADER_ROOT"
"""Environment variable that replaces ``/autograder`` (the scripts and ``--root`` read it)."""
DEFAULT_ROOT = Path("/autograder")
SETTINGS_NAME = "doorlab_autograder.json"
"""The zip's settings file (also how ``--force`` knows a zip is doorlab's own)."""
ASSIGNMENT_NAME = "assignment.yaml"
CONSTRAINTS_NAME = "constraints.txt"
SANDBOX_USER = "doorlab-student"
"""The user setup.sh creates for the student's code (:mod:`doorlab.pset.isolation.sandbox` uses
it)."""
HARDENED = ("source", "results", "submission", "submission_metadata.json")
"""What of Gradescope's ``/autograder`` becomes root's alone before student code runs without
the student's view (the zip with its wheel; earlier results; the submission's metadata, which
names the student)."""


class AutograderError(DoorlabError):
    """The autograder cannot run: a missing root, settings or a doorlab other than the zip's."""


# Writing the zip ---------------------------------------------------------------------------


def _render(name: str, context: dict) -> str:
    from doorlab.pset.handout.folder import _environment

    return _environment().get_template(f"autograder/{name}.j2").render(context)


def _is_ours(path: Path) -> bool:
    try:
        with zipfile.ZipFile(path) as archive:
            return SETTINGS_NAME in archive.namelist()
    except (OSError, zipfile.BadZipFile):
        return False


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def zip_digest(settings: dict) -> str:
    """The zip's digest: SHA-256 over what grades (doorlab's files, the assignment, the
    constraints, the wheel's name, the tests at a time, the student files)."""
    keys = ("doorlab", "package_sha256", "assignment_sha256", "constraints_sha256", "wheel")
    parts = {k: settings.get(k) for k in (*keys, "jobs", "student_files", "python")}
    return _sha256(json.dumps(parts, sort_keys=True).encode())


def write_autograder(
    out: str | Path, *, jobs: int = 1, force: bool = False, assignment: object = None
) -> Path:
    """Writes the Gradescope autograder zip ``out`` (atomically: a temporary file beside it,
    renamed into place).

    Args:
        out: The zip to write (its name must end in ``.zip``).
        jobs: Tests run at a time on Gradescope: 1 fits its default resources (see
            docs/guides/teaching.md for the measured peak memory); 2 halves the time with 2
            CPUs.
        force: Replace an existing zip written by this command.
        assignment: The course's settings (:class:`doorlab.pset.rules.assignment.Assignment`);
            None: the defaults.

    Raises:
        OutputError: ``out`` exists (without ``force``, or is not doorlab's), is a folder,
            is under a file or does not end in ``.zip``; doorlab is not installed.
    """
    from doorlab import __version__
    from doorlab.pset.rules.assignment import Assignment, assignment_yaml

    out = Path(out)
    check_zip_destination(out, force=force, ours=_is_ours, what="an autograder")
    wheel_name, wheel = wheel_bytes()
    assignment_text = assignment_yaml(
        assignment or Assignment(),
        header="The course's grading settings, as this autograder grades with them\n"
        "(doorlab pset autograder --assignment; its digest is in doorlab_autograder.json).",
    ).encode()
    constraints = constraints_text().encode()
    settings = {
        "doorlab": __version__,
        "drake": metadata.version("drake"),
        "python": python_version(),
        "package_sha256": package_digest(),
        "assignment_sha256": _sha256(assignment_text),
        "constraints_sha256": _sha256(constraints),
        "wheel": wheel_name,
        "jobs": jobs,
        "student_files": list(STUDENT_FILES),
    }
    settings["digest"] = zip_digest(settings)
    context = {
        "version": __version__,
        "drake_version": settings["drake"],
        "python": settings["python"],
        "wheel": wheel_name,
        "constraints": CONSTRAINTS_NAME,
        "sandbox_user": SANDBOX_USER,
        "student_files": STUDENT_FILES,
    }

    def write(archive: zipfile.ZipFile) -> None:
        for script in ("setup.sh", "run_autograder"):
            text = _render(script, context).encode()
            write_entry(archive, script, text, executable=True)
        write_entry(archive, SETTINGS_NAME, (json.dumps(settings, indent=2) + "\n").encode())
        write_entry(archive, ASSIGNMENT_NAME, assignment_text)
        write_entry(archive, CONSTRAINTS_NAME, constraints)
        write_stored(archive, wheel_name, wheel)

    return write_zip(out, write)


# Running on Gradescope ---------------------------------------------------------------------


def read_settings(root: Path) -> dict:
    """The zip's settings, after checking that the installed doorlab, the assignment and
    the constraints are the zip's (their SHA-256 against the settings, and its digest).

    Raises:
        AutograderError: No settings under ``root/source``, another doorlab installed, or a
            file of the zip changed since it was written.
    """
    from doorlab import __version__

    source = root / "source"
    path = source / SETTINGS_NAME
    try:
        settings = json.loads(path.read_text())
        if not isinstance(settings, dict):
            raise ValueError("not a JSON object")
    except (OSError, ValueError) as e:
        raise AutograderError(
            f"cannot read {path} ({e}): is {root} a doorlab autograder's root?"
        ) from None
    digest = package_digest()
    if settings.get("doorlab") != __version__ or settings.get("package_sha256") != digest:
        raise AutograderError(
            f"the installed doorlab ({__version__}, files {digest[:12]}) is not the zip's "
            f"({settings.get('doorlab')}, files {str(settings.get('package_sha256'))[:12]}): "
            "rebuild the autograder's image from the zip"
        )
    for name, key in (
        (ASSIGNMENT_NAME, "assignment_sha256"),
        (CONSTRAINTS_NAME, "constraints_sha256"),
    ):
        if key not in settings:  # a zip written before the file existed
            continue
        try:
            data = (source / name).read_bytes()
        except OSError as e:
            raise AutograderError(f"cannot read {source / name}: {e.strerror or e}") from None
        if _sha256(data) != settings[key]:
            raise AutograderError(
                f"{source / name} is not the zip's (its SHA-256 differs from "
                f"{SETTINGS_NAME}'s): rebuild the autograder from the zip"
            )
    if "digest" in settings and settings["digest"] != zip_digest(settings):
        raise AutograderError(f"{path}: its digest does not match its settings: rebuild the zip")
    return settings


def read_assignment(root: Path):
    """The zip's assignment (None for a zip without one: the defaults)."""
    from doorlab.pset.rules.assignment import load_assignment

    path = root / "source" / ASSIGNMENT_NAME
    return load_assignment(path) if path.is_file() else None


def check_installed(root: Path) -> str:
    """Every distribution the zip's constraints pin is installed at exactly that version
    (setup.sh's check); returns what it found.

    Raises:
        AutograderError: A pinned distribution is missing or at another version.
    """
    path = root / "source" / CONSTRAINTS_NAME
    if not path.is_file():
        return "no constraints in this zip"
    wrong = []
    pins = [line.split("==", 1) for line in path.read_text().splitlines() if "==" in line]
    for name, version in pins:
        try:
            installed = metadata.version(name)
        except metadata.PackageNotFoundError:
            installed = None
        if installed != version:
            wrong.append(f"{name} {installed or 'missing'} (pinned {version})")
    if wrong:
        raise AutograderError(
            f"installed versions differ from {CONSTRAINTS_NAME}: {', '.join(wrong[:5])}"
            + (f" and {len(wrong) - 5} more" if len(wrong) > 5 else "")
        )
    return f"{len(pins)} distributions at the versions of {CONSTRAINTS_NAME}"


def check(root: Path) -> str:
    """setup.sh's last step: the installed doorlab, assignment and versions are the zip's,
    and pydrake imports."""
    settings = read_settings(root)
    read_assignment(root)
    versions = check_installed(root)
    import pydrake.all  # noqa: F401  (loads libdrake: a missing system library fails here)

    from doorlab import __version__

    return (
        f"doorlab {__version__} (Drake {metadata.version('drake')}) is ready to grade: "
        f"{versions}; zip digest {settings.get('digest', '?')[:12]}"
    )


def run_autograder(
    root: Path,
    *,
    jobs: int | None = None,
    reference: dict[str, dict] | None = None,
    seed: int | None = None,
) -> dict:
    """Grades ``root/submission`` (the one intake, the zip's assignment) and writes
    ``root/results/results.json``.

    Args:
        root: Gradescope's ``/autograder`` (or a stand-in).
        jobs: Tests run at a time (default: the zip's setting).
        reference: The reference episodes' figures of an earlier grading by this doorlab
            (:func:`doorlab.pset.grading.grader.load_reference`; rehearsals only: saves 3 episodes);
            None (Gradescope) simulates them in this grading.
        seed: A recorded grading's seed (rehearsals, disputes): replays its random inputs.

    Returns:
        The results written (Gradescope's format; the zip's late policy applied from
        ``submission_metadata.json``'s ``created_at`` and the submission's own due date;
        the episode tests' outputs as HTML with their figures: :func:`finalize_for_gradescope`).

    Raises:
        AutograderError: See :func:`read_settings`; no submission folder.
    """
    from doorlab.pset.grading.grader import grade_submission, write_results

    settings = read_settings(root)
    assignment = read_assignment(root)
    submission = root / "submission"
    if not submission.is_dir():
        raise AutograderError(f"{submission} is not a folder: there is no submission to grade")
    results_dir = root / "results"
    results_dir.mkdir(parents=True, exist_ok=True)
    metadata = submission_metadata(root)  # read before the fallback makes it root's alone
    results = grade_submission(
        submission,
        jobs=jobs or int(settings.get("jobs", 1)),
        reference=reference,
        assignment=assignment,
        seed=seed,
        isolation="autograder",  # the view, else another user with HARDENED root's alone
        harden=[root / name for name in HARDENED],
    )
    results["extra_data"]["autograder"] = {"digest": settings.get("digest")}
    results = finalize_for_gradescope(results, assignment, metadata)
    write_results(results, results_dir / "results.json")
    return results


def finalize_for_gradescope(results: dict, assignment, metadata: dict | None) -> dict:
    """The results as Gradescope gets them: the course's late policy from the submission's
    time and its own due date in Gradescope's metadata (an extension,
    :func:`doorlab.pset.classroom.extensions.gradescope_due`), the total's line (the course's
    points, those in tests students do not see), the episode tests' figures as HTML
    (:mod:`doorlab.pset.classroom.gradescope_html`)."""
    from doorlab.pset.classroom.extensions import gradescope_due
    from doorlab.pset.classroom.final_grade import finalize
    from doorlab.pset.classroom.gradescope_html import with_figures
    from doorlab.pset.classroom.late import submission_time as parse_time
    from doorlab.pset.rules.assignment import Assignment

    submitted = parse_time(metadata.get("created_at")) if metadata else None
    results = finalize(
        results, assignment or Assignment(), submitted, own_due=gradescope_due(metadata)
    )
    return with_figures(results)


def submission_metadata(root: Path) -> dict | None:
    """Gradescope's ``submission_metadata.json`` (the submission's time, ``created_at``, and
    its due dates; https://gradescope-autograders.readthedocs.io/en/latest/submission_metadata/),
    None without one. The file is Gradescope's, read within bounds."""
    from doorlab.errors import ConfigError
    from doorlab.runtime.inputs import read_text_file

    path = root / "submission_metadata.json"
    if not path.is_file():
        return None
    try:
        data = json.loads(read_text_file(path, what="submission_metadata.json", max_bytes=64 << 20))
    except (ConfigError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def submission_time(root: Path):
    """The submission's time in Gradescope's ``submission_metadata.json`` (its
    ``created_at``), None without one."""
    from doorlab.pset.classroom.late import submission_time as parse_time

    metadata = submission_metadata(root)
    return parse_time(metadata.get("created_at")) if metadata else None


def main(argv: Sequence[str] | None = None) -> int:
    """``python -I -m doorlab.pset.classroom.gradescope [--root ROOT] [--jobs N] [--reference FILE]
    [--seed N] [--check]``."""
    from doorlab.errors import interrupt_exit_code
    from doorlab.runtime.argtypes import OneLineParser, bounded_int
    from doorlab.runtime.interrupts import install_signal_handlers

    parser = OneLineParser(
        prog="run_autograder", description="Grade a Gradescope submission with doorlab."
    )
    parser.add_argument(
        "--root",
        type=Path,
        default=Path(os.environ.get(ROOT_ENV) or DEFAULT_ROOT),
        help=f"Gradescope's /autograder (default: ${ROOT_ENV} or /autograder)",
    )
    parser.add_argument("--jobs", type=bounded_int(1), default=None, help="tests at a time")
    parser.add_argument(
        "--reference",
        type=Path,
        default=None,
        metavar="RESULTS_JSON",
        help="rehearsals: reuse the reference episodes of an earlier grading's results",
    )
    parser.add_argument(
        "--seed",
        type=bounded_int(0, 2**63 - 1),
        default=None,
        metavar="N",
        help="a recorded grading's seed: replays its random inputs",
    )
    parser.add_argument(
        "--check", action="store_true", help="only check the installation (setup.sh's last step)"
    )
    args = parser.parse_args(argv)
    try:
        install_signal_handlers()
        if args.check:
            print(f"setup.sh: {check(args.root)}")
            return 0
        reference = None
        if args.reference is not None:
            from doorlab.pset.grading.grader import load_reference

            reference = load_reference(args.reference)
        results = run_autograder(args.root, jobs=args.jobs, reference=reference, seed=args.seed)
    except DoorlabError as e:
        print(f"run_autograder: error: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as e:
        print("run_autograder: interrupted", file=sys.stderr)
        return interrupt_exit_code(e)
    from doorlab.pset.grading.grader import pretty_format_json_results

    path = args.root / "results" / "results.json"
    print(pretty_format_json_results(path))
    print(f"run_autograder: wrote {path} in {results['execution_time']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
