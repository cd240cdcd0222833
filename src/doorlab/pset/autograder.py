"""``doorlab pset autograder OUT.zip``: the problem set's grader as a Gradescope autograder.

The zip follows Gradescope's autograder format (its files at the zip's root, extracted into
``/autograder/source``):

- ``setup.sh``: run once, as root, when Gradescope builds the image (Ubuntu 22.04 or newer):
  installs what is missing of ``python3-venv`` and GLib (pydrake's one system library), makes
  the virtual environment ``/autograder/doorlab-venv`` and installs into it the wheel below,
  with doorlab's dependencies from PyPI, then runs ``--check``.
- ``run_autograder``: run for every submission: ``python -I -m doorlab.pset.autograder``, which
  copies the files a student edits (:data:`doorlab.pset.folder.STUDENT_FILES`) from
  ``/autograder/submission`` into a fresh stub folder (``doorlab pset init``'s), grades it and
  writes ``/autograder/results/results.json``.
- ``doorlab-<version>-py3-none-any.whl``: the doorlab that wrote the zip.
- ``doorlab_autograder.json``: the zip's settings: doorlab's version and the SHA-256 of its
  package files (checked before every grading, so the zip's doorlab is the one that grades),
  the tests run at a time, the files a submission may replace.

``DOORLAB_AUTOGRADER_ROOT`` (or ``--root``) replaces ``/autograder``, for tests and rehearsals.

The wheel is packed from the installed package's own files, not built from a source tree:
a teacher who installed doorlab from a wheel has no source tree, and building one needs
setuptools >= 68 and ``wheel`` in the environment (a fresh venv has neither offline: ``pip
wheel --no-deps --no-build-isolation .`` fails there with "invalid command 'bdist_wheel'").
A wheel is a zip of the package and four metadata files (PEP 427), so it is written here.
"""

from __future__ import annotations

import base64
import hashlib
import io
import json
import os
import sys
import tempfile
import zipfile
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path, PurePosixPath

from doorlab.errors import DoorlabError, OutputError
from doorlab.pset.folder import STUDENT_FILES
from doorlab.pset.safe_text import clean_text

ROOT_ENV = "DOORLAB_AUTOGRADER_ROOT"
"""Environment variable that replaces ``/autograder`` (the scripts and ``--root`` read it)."""
DEFAULT_ROOT = Path("/autograder")
SETTINGS_NAME = "doorlab_autograder.json"
"""The zip's settings file (also how ``--force`` knows a zip is doorlab's own)."""
SUBMISSION_FILE_LIMIT = 1_000_000
"""Largest student file taken from a submission [bytes]; the stubs are ~5 kB."""
_ZIP_TIME = (1980, 1, 1, 0, 0, 0)
"""Every entry's timestamp, so the same doorlab writes the same bytes."""
_SKIPPED_DIRS = {"__MACOSX", "__pycache__", ".git", ".ipynb_checkpoints"}
HARDENED = ("source", "results", "submission", "submission_metadata.json")
"""What of Gradescope's ``/autograder`` becomes root's alone before student code runs without
the student's view (the zip with its wheel; earlier results; the submission's metadata, which
names the student)."""


class AutograderError(DoorlabError):
    """The autograder cannot run: a missing root, settings or a doorlab other than the zip's."""


# The package and its wheel -----------------------------------------------------------------


def _package_dir() -> Path:
    import doorlab

    return Path(doorlab.__file__).resolve().parent


def package_files(package_dir: Path | None = None) -> list[PurePosixPath]:
    """Every file of the doorlab package (paths relative to its parent, sorted), without
    bytecode caches and hidden files."""
    package_dir = package_dir or _package_dir()
    out = []
    for dirpath, dirnames, filenames in os.walk(package_dir):
        dirnames[:] = sorted(d for d in dirnames if d not in _SKIPPED_DIRS and d[0] != ".")
        for name in filenames:
            if name[0] == "." or name.endswith((".pyc", ".pyo")):
                continue
            rel = Path(dirpath, name).relative_to(package_dir.parent)
            out.append(PurePosixPath(rel.as_posix()))
    return sorted(out)


def package_digest(package_dir: Path | None = None) -> str:
    """SHA-256 (hex) over the package's files, their paths and contents."""
    package_dir = package_dir or _package_dir()
    h = hashlib.sha256()
    for rel in package_files(package_dir):
        data = (package_dir.parent / rel).read_bytes()
        h.update(f"{rel}\0{len(data)}\0".encode())
        h.update(data)
    return h.hexdigest()


def _distribution() -> metadata.Distribution:
    from doorlab import __version__

    try:
        dist = metadata.distribution("doorlab")
    except metadata.PackageNotFoundError:
        raise OutputError(
            "doorlab is imported but not installed (no package metadata): install it with "
            "pip install -e . (or pip install doorlab) first"
        ) from None
    if dist.version != __version__:
        raise OutputError(
            f"the imported doorlab is {__version__} but the installed one is {dist.version}: "
            "run the doorlab of the environment it is installed in"
        )
    return dist


def _record_hash(data: bytes) -> str:
    digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=")
    return "sha256=" + digest.decode()


def _write_entry(archive: zipfile.ZipFile, name: str, data: bytes, *, executable=False) -> None:
    info = zipfile.ZipInfo(name, date_time=_ZIP_TIME)
    info.external_attr = (0o100755 if executable else 0o100644) << 16
    info.compress_type = zipfile.ZIP_DEFLATED
    archive.writestr(info, data)


def wheel_bytes() -> tuple[str, bytes]:
    """The installed doorlab as a pure-Python wheel: (file name, contents)."""
    dist = _distribution()
    version = dist.version
    package_dir = _package_dir()
    info_dir = f"doorlab-{version}.dist-info"
    files: list[tuple[str, bytes]] = [
        (str(rel), (package_dir.parent / rel).read_bytes()) for rel in package_files(package_dir)
    ]
    files.append((f"{info_dir}/METADATA", dist.read_text("METADATA").encode()))
    for extra in ("entry_points.txt", "top_level.txt"):
        text = dist.read_text(extra)
        if text:
            files.append((f"{info_dir}/{extra}", text.encode()))
    wheel = (
        "Wheel-Version: 1.0\n"
        f"Generator: doorlab {version} (doorlab.pset.autograder)\n"
        "Root-Is-Purelib: true\n"
        "Tag: py3-none-any\n"
    )
    files.append((f"{info_dir}/WHEEL", wheel.encode()))
    record = "".join(f"{name},{_record_hash(data)},{len(data)}\n" for name, data in files)
    record += f"{info_dir}/RECORD,,\n"
    files.append((f"{info_dir}/RECORD", record.encode()))
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        for name, data in files:
            _write_entry(archive, name, data)
    return f"doorlab-{version}-py3-none-any.whl", buffer.getvalue()


# Writing the zip ---------------------------------------------------------------------------


def _render(name: str, context: dict) -> str:
    from doorlab.pset.folder import _environment

    return _environment().get_template(f"autograder/{name}.j2").render(context)


def _check_out(out: Path, *, force: bool) -> None:
    if out.suffix.lower() != ".zip":
        raise OutputError(f"{out}: the autograder is a zip file; give a name ending in .zip")
    for parent in out.parents:
        if parent.exists() and not parent.is_dir():
            raise OutputError(f"{out}: {parent} is a file, not a folder")
    if out.is_dir():
        raise OutputError(f"{out} is a folder, not a zip file")
    if out.exists():
        if not force:
            raise OutputError(f"{out} already exists; use --force to replace it")
        if not _is_ours(out):
            raise OutputError(
                f"{out} is not an autograder zip written by doorlab; not replacing it "
                "(move it away first)"
            )


def _is_ours(path: Path) -> bool:
    try:
        with zipfile.ZipFile(path) as archive:
            return SETTINGS_NAME in archive.namelist()
    except (OSError, zipfile.BadZipFile):
        return False


def write_autograder(out: str | Path, *, jobs: int = 1, force: bool = False) -> Path:
    """Writes the Gradescope autograder zip ``out`` (atomically: a temporary file beside it,
    renamed into place).

    Args:
        out: The zip to write (its name must end in ``.zip``).
        jobs: Tests run at a time on Gradescope: 1 fits its default resources (a grading
            peaks at ~380 MiB with 1, ~610 MiB with 2); 2 halves the time with 2 CPUs.
        force: Replace an existing zip written by this command.

    Raises:
        OutputError: ``out`` exists (without ``force``, or is not doorlab's), is a folder,
            is under a file or does not end in ``.zip``; doorlab is not installed.
    """
    from doorlab import __version__

    out = Path(out)
    _check_out(out, force=force)
    wheel_name, wheel = wheel_bytes()
    settings = {
        "doorlab": __version__,
        "drake": metadata.version("drake"),
        "package_sha256": package_digest(),
        "wheel": wheel_name,
        "jobs": jobs,
        "student_files": list(STUDENT_FILES),
    }
    context = {
        "version": __version__,
        "drake_version": settings["drake"],
        "wheel": wheel_name,
        "student_files": STUDENT_FILES,
    }
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp_name = tempfile.mkstemp(prefix=f".{out.name}.", suffix=".partial", dir=out.parent)
    except OSError as e:
        raise OutputError(f"cannot write {out}: {e.strerror or e}") from None
    tmp = Path(tmp_name)
    try:
        with os.fdopen(fd, "wb") as f, zipfile.ZipFile(f, "w") as archive:
            for script in ("setup.sh", "run_autograder"):
                text = _render(script, context).encode()
                _write_entry(archive, script, text, executable=True)
            _write_entry(archive, SETTINGS_NAME, (json.dumps(settings, indent=2) + "\n").encode())
            info = zipfile.ZipInfo(wheel_name, date_time=_ZIP_TIME)
            info.external_attr = 0o100644 << 16  # stored: a wheel is compressed already
            archive.writestr(info, wheel)
        umask = os.umask(0)
        os.umask(umask)
        tmp.chmod(0o666 & ~umask)  # mkstemp makes it private; the zip is not
        tmp.replace(out)
    except OSError as e:
        tmp.unlink(missing_ok=True)
        raise OutputError(f"cannot write {out}: {e.strerror or e}") from None
    except BaseException:  # Ctrl-C, SIGTERM (doorlab.errors.Interrupted): no partial file
        tmp.unlink(missing_ok=True)
        raise
    return out


# Running on Gradescope ---------------------------------------------------------------------


@dataclass
class Submission:
    """What ``run_autograder`` took from a submission.

    Attributes:
        taken: Student file (as in the folder) -> its path in the submission (POSIX).
        missing: Student files not found (their stubs are graded).
        rejected: One line per file not taken although named like a student file.
        ignored: Every other file of the submission (POSIX paths).
    """

    taken: dict[str, str] = field(default_factory=dict)
    missing: list[str] = field(default_factory=list)
    rejected: list[str] = field(default_factory=list)
    ignored: list[str] = field(default_factory=list)

    def summary(self) -> str:
        """A few lines for the student (the results' top-level ``output``)."""
        lines = []
        if self.taken:
            moved = [
                rel if src == rel else f"{rel} (from {src})" for rel, src in self.taken.items()
            ]
            lines.append("Graded from your submission: " + ", ".join(moved) + ".")
        if self.missing:
            lines.append(
                "Not in your submission, so the stub was graded (0 points for its tests): "
                + ", ".join(self.missing)
                + "."
            )
        lines += self.rejected
        if self.ignored:
            shown = ", ".join(self.ignored[:8])
            more = f" and {len(self.ignored) - 8} more" if len(self.ignored) > 8 else ""
            lines.append(
                f"Not used (only {', '.join(STUDENT_FILES)} are graded; doorlab provides the "
                f"rest): {shown}{more}."
            )
        return "\n".join(lines)


def _walk(submission: Path) -> Iterator[tuple[PurePosixPath, Path]]:
    for dirpath, dirnames, filenames in os.walk(submission, followlinks=False):
        dirnames[:] = sorted(d for d in dirnames if d not in _SKIPPED_DIRS)
        for name in sorted(filenames):
            path = Path(dirpath, name)
            yield PurePosixPath(path.relative_to(submission).as_posix()), path


def _preference(rel: str, found: PurePosixPath) -> tuple:
    # The student file's own place first (at any depth), then the shallowest, then by name.
    return (not str(found).endswith(rel), len(found.parts), str(found))


def collect_submission(submission: Path, folder: Path) -> Submission:
    """Copies the student files of ``submission`` into the problem-set ``folder``.

    A student file is found by its name anywhere in the submission (a flat upload, the whole
    folder, or the folder inside another); if several match, the one at the file's own place
    in the folder (``manip_station_sim/robot_plans.py``) wins, then the shallowest. Symbolic
    links and files over :data:`SUBMISSION_FILE_LIMIT` are not taken. Nothing else is copied,
    so no file of a submission can stand in for a module that doorlab or Python imports.
    """
    by_name: dict[str, list[PurePosixPath]] = {PurePosixPath(rel).name: [] for rel in STUDENT_FILES}
    paths: dict[PurePosixPath, Path] = {}
    result = Submission()
    for rel, path in _walk(submission):
        paths[rel] = path
        if rel.name in by_name:
            by_name[rel.name].append(rel)
        else:
            result.ignored.append(str(rel))
    for rel in STUDENT_FILES:
        candidates = sorted(by_name[PurePosixPath(rel).name], key=lambda f: _preference(rel, f))
        for found in candidates:
            path = paths[found]
            if rel in result.taken:
                result.ignored.append(str(found))
            elif path.is_symlink() or not path.is_file():
                result.rejected.append(f"Not taken: {found} is a symbolic link or not a file.")
            elif path.stat().st_size > SUBMISSION_FILE_LIMIT:
                result.rejected.append(
                    f"Not taken: {found} is over {SUBMISSION_FILE_LIMIT // 1000} kB."
                )
            else:
                (folder / rel).write_bytes(path.read_bytes())
                result.taken[rel] = str(found)
        if rel not in result.taken:
            result.missing.append(rel)
    result.ignored.sort()
    return result


def _grade(folder: Path, jobs: int, reference: dict[str, dict] | None, root: Path) -> dict:
    """The one call into the grader (its public entry point), kept here alone: in the
    student's view where the container allows it, else as another user once the zip's
    source (its wheel), the results and the submission's metadata are root's alone
    (:mod:`doorlab.pset.isolation`, policy ``"autograder"``)."""
    from doorlab.pset.grader import grade

    harden = [root / name for name in HARDENED]
    return grade(folder, jobs=jobs, reference=reference, isolation="autograder", harden=harden)


def read_settings(root: Path) -> dict:
    """The zip's settings, after checking that the installed doorlab is the zip's.

    Raises:
        AutograderError: No settings under ``root/source``, or another doorlab installed.
    """
    from doorlab import __version__

    path = root / "source" / SETTINGS_NAME
    try:
        settings = json.loads(path.read_text())
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
    return settings


def check(root: Path) -> str:
    """setup.sh's last step: the installed doorlab is the zip's and pydrake imports."""
    read_settings(root)
    import pydrake.all  # noqa: F401  (loads libdrake: a missing system library fails here)

    from doorlab import __version__

    return f"doorlab {__version__} (Drake {metadata.version('drake')}) is ready to grade"


def run_autograder(
    root: Path, *, jobs: int | None = None, reference: dict[str, dict] | None = None
) -> dict:
    """Grades ``root/submission`` and writes ``root/results/results.json``.

    Args:
        root: Gradescope's ``/autograder`` (or a stand-in).
        jobs: Tests run at a time (default: the zip's setting).
        reference: The reference episodes' figures of an earlier grading by this doorlab
            (:func:`doorlab.pset.grader.load_reference`; rehearsals only: saves 3 episodes);
            None (Gradescope) simulates them in this grading.

    Returns:
        The results written (Gradescope's format).

    Raises:
        AutograderError: See :func:`read_settings`; no submission folder.
    """
    from doorlab import __version__
    from doorlab.pset.folder import init_folder
    from doorlab.pset.grader import write_results

    settings = read_settings(root)
    submission = root / "submission"
    if not submission.is_dir():
        raise AutograderError(f"{submission} is not a folder: there is no submission to grade")
    results_dir = root / "results"
    results_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="doorlab_autograder_") as tmp:
        folder = init_folder(Path(tmp) / "pset")  # the stubs; the student's files go over them
        taken = collect_submission(submission, folder)
        results = _grade(folder, jobs or int(settings.get("jobs", 1)), reference, root)
    header = f"Graded by doorlab {__version__} (Drake {metadata.version('drake')})."
    results["output"] = clean_text("\n".join(filter(None, [header, taken.summary()])))
    results.setdefault("extra_data", {})["submission"] = {
        "taken": taken.taken,
        "missing": taken.missing,
        "rejected": taken.rejected,
        "ignored": taken.ignored,
    }
    write_results(results, results_dir / "results.json")
    return results


def main(argv: Sequence[str] | None = None) -> int:
    """``python -I -m doorlab.pset.autograder [--root ROOT] [--jobs N] [--reference FILE]
    [--check]``."""
    from doorlab.argtypes import OneLineParser, bounded_int
    from doorlab.errors import interrupt_exit_code
    from doorlab.interrupts import install_signal_handlers

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
            from doorlab.pset.grader import load_reference

            reference = load_reference(args.reference)
        results = run_autograder(args.root, jobs=args.jobs, reference=reference)
    except DoorlabError as e:
        print(f"run_autograder: error: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as e:
        print("run_autograder: interrupted", file=sys.stderr)
        return interrupt_exit_code(e)
    from doorlab.pset.grader import pretty_format_json_results

    path = args.root / "results" / "results.json"
    print(clean_text(results["output"]))
    print(pretty_format_json_results(path))
    print(f"run_autograder: wrote {path} in {results['execution_time']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
