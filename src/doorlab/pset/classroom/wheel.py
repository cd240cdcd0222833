"""The doorlab that grades, packed: its wheel, the versions of what it runs on, and zips
written atomically (the autograder zip and the students' handout carry them).

Two wheels come from the one installed package: the instructor's (:func:`wheel_bytes`, the
whole package: the autograder zip's) and the students' (:func:`student_wheel_bytes`, the
handout's): the same files but the answer key (:data:`STUDENT_WHEEL_LEAVES_OUT`), with the
handout's stub folder and practice table added (:mod:`doorlab.pset.handout.edition`).

The wheel is packed from the installed package's own files, not built from a source tree:
a teacher who installed doorlab from a wheel has no source tree, and building one needs
setuptools >= 68 and ``wheel`` in the environment (a fresh venv has neither offline: ``pip
wheel --no-deps --no-build-isolation .`` fails there with "invalid command 'bdist_wheel'").
A wheel is a zip of the package and four metadata files (PEP 427), so it is written here.

The constraints (:func:`constraints_text`) pin, at the version installed here, every
distribution the installed doorlab needs to grade: its requirements without extras,
followed transitively with their markers evaluated in this environment, and pip. An image
built from them installs exactly this environment's versions.
"""

from __future__ import annotations

import base64
import hashlib
import io
import json
import os
import platform
import tempfile
import zipfile
from collections.abc import Callable, Iterable
from importlib import metadata
from pathlib import Path, PurePosixPath

from doorlab.errors import OutputError

ZIP_TIME = (1980, 1, 1, 0, 0, 0)
"""Every entry's timestamp, so the same doorlab writes the same bytes."""
_SKIPPED_DIRS = {"__MACOSX", "__pycache__", ".git", ".ipynb_checkpoints"}


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


def write_entry(archive: zipfile.ZipFile, name: str, data: bytes, *, executable=False) -> None:
    info = zipfile.ZipInfo(name, date_time=ZIP_TIME)
    info.external_attr = (0o100755 if executable else 0o100644) << 16
    info.compress_type = zipfile.ZIP_DEFLATED
    archive.writestr(info, data)


def wheel_bytes() -> tuple[str, bytes]:
    """The installed doorlab as a pure-Python wheel: (file name, contents)."""
    package_dir = _package_dir()
    files = [
        (str(rel), (package_dir.parent / rel).read_bytes()) for rel in package_files(package_dir)
    ]
    return _pack(files)


# The students' doorlab ---------------------------------------------------------------------

STUDENT_WHEEL_LEAVES_OUT = {
    "doorlab/control/ik_pointwise.py": "doorlab's pointwise IK (task 1's reference solution)",
    "doorlab/control/laws.py": "doorlab's control laws (tasks 2 and 3's reference solutions)",
    "doorlab/control/plans.py": "doorlab's task-space plans (tasks 2 and 3's reference)",
    "doorlab/control/adaptive.py": "doorlab's adaptive plan (built on the reference laws)",
    "doorlab/control/diffik.py": "doorlab's diffik plan (built on the reference laws)",
    "doorlab/control/osc.py": "doorlab's osc plan (built on the reference laws and plans)",
    "doorlab/episode/controllers.py": "doorlab's controllers (they run the references)",
    "doorlab/studies/": "the studies (they run the reference controllers)",
    "doorlab/report/": "the report (doorlab's answers to the notebook's questions)",
    "doorlab/templates/": "the report's and the sweep's pages",
    "doorlab/sweep/": "the sweeps (they run the reference controllers)",
    "doorlab/bench/": "the benchmark card (it runs the reference controllers)",
    "doorlab/pset/grading/answer_key.py": "the grader's answer key (its expected answers)",
    "doorlab/pset/handout/templates/": "the problem set's templates (the solutions' text)",
    "doorlab/pset/classroom/gradescope.py": (
        "the Gradescope autograder (it packs the instructor's doorlab)"
    ),
    "doorlab/pset/classroom/handout_zip.py": "the handout's writer (it needs the answer key)",
}
"""What the students' doorlab (the handout's wheel) leaves out of the package, and why: every
module that holds or runs a reference solution or an expected answer, and the solutions'
text. What is left runs the notebook (the station, the plans' base, the episodes, the
plots) and grades against the handout's practice table (:mod:`doorlab.pset.handout.edition`)."""


def _left_out(rel: str) -> bool:
    return any(
        rel == p or (p.endswith("/") and rel.startswith(p)) for p in STUDENT_WHEEL_LEAVES_OUT
    )


def student_wheel_bytes(practice: dict, stubs: dict[str, str]) -> tuple[str, bytes]:
    """The students' doorlab as a wheel: the installed package's files but
    :data:`STUDENT_WHEEL_LEAVES_OUT`, with ``doorlab/pset/handout/students/`` added (the handout's
    stub folder ``stubs``, the ``practice`` table: :mod:`doorlab.pset.handout.edition`); (file name,
    contents). The same name as the instructor's wheel: students install it as the handout's
    README says."""
    from doorlab.pset.handout import edition

    package_dir = _package_dir()
    files = [
        (str(rel), (package_dir.parent / rel).read_bytes())
        for rel in package_files(package_dir)
        if not _left_out(str(rel))
    ]
    folder = f"doorlab/pset/handout/{edition.FOLDER}"
    files.append((f"{folder}/{edition.PRACTICE}", json.dumps(practice, sort_keys=True).encode()))
    for rel, text in sorted(stubs.items()):
        files.append((f"{folder}/{edition.STUBS}/{rel}", text.encode()))
    return _pack(sorted(files), students=True)


def _pack(files: list[tuple[str, bytes]], *, students: bool = False) -> tuple[str, bytes]:
    """A wheel of ``files`` (package paths, contents) and the installed doorlab's metadata."""
    dist = _distribution()
    version = dist.version
    info_dir = f"doorlab-{version}.dist-info"
    files = list(files)
    files.append((f"{info_dir}/METADATA", dist.read_text("METADATA").encode()))
    for extra in ("entry_points.txt", "top_level.txt"):
        text = dist.read_text(extra)
        if text:
            files.append((f"{info_dir}/{extra}", text.encode()))
    edition = " (the students' build)" if students else ""
    wheel = (
        "Wheel-Version: 1.0\n"
        f"Generator: doorlab {version} (doorlab.pset.classroom.wheel){edition}\n"
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
            write_entry(archive, name, data)
    return f"doorlab-{version}-py3-none-any.whl", buffer.getvalue()


# The versions grading runs on -------------------------------------------------------------


def _requirements(dist_name: str, extras: Iterable[str]) -> list:
    from packaging.requirements import Requirement

    out = []
    for text in metadata.requires(dist_name) or []:
        req = Requirement(text)
        wanted = {""} | set(extras)
        if req.marker is None or any(req.marker.evaluate({"extra": e}) for e in wanted):
            out.append(req)
    return out


def pinned_distributions() -> dict[str, str]:
    """{name: version} of every distribution the installed doorlab needs without extras
    (transitively, markers evaluated here), and of pip.

    Raises:
        OutputError: A requirement is not installed here (the environment is broken).
    """
    from packaging.utils import canonicalize_name

    pins: dict[str, str] = {}
    todo = [(r.name, tuple(r.extras)) for r in _requirements("doorlab", ())]
    todo.append(("pip", ()))
    while todo:
        name, extras = todo.pop()
        try:
            dist = metadata.distribution(name)
        except metadata.PackageNotFoundError:
            raise OutputError(
                f"doorlab needs {name}, which is not installed here: reinstall doorlab "
                "(pip install doorlab) before packing it"
            ) from None
        key = canonicalize_name(dist.metadata["Name"])
        if key in pins:
            continue
        pins[key] = dist.version
        todo += [(r.name, tuple(r.extras)) for r in _requirements(name, extras)]
    return dict(sorted(pins.items()))


def python_version() -> str:
    """This interpreter's ``major.minor``."""
    return ".".join(platform.python_version_tuple()[:2])


def constraints_text() -> str:
    """A pip constraints file pinning :func:`pinned_distributions` (``-c FILE``)."""
    lines = [
        "# The versions doorlab graded with where this file was written (Python "
        f"{python_version()}):",
        "# pip install -c THIS_FILE installs exactly them.",
    ]
    lines += [f"{name}=={version}" for name, version in pinned_distributions().items()]
    return "\n".join(lines) + "\n"


# Writing a zip -----------------------------------------------------------------------------


def check_zip_destination(
    out: Path, *, force: bool, ours: Callable[[Path], bool], what: str
) -> None:
    """Raises OutputError unless the zip ``out`` may be written: a name ending in ``.zip``,
    not a folder, not under a file; an existing one only with ``force`` and only if
    ``ours(out)`` (doorlab wrote it)."""
    if out.suffix.lower() != ".zip":
        raise OutputError(f"{out}: the {what} is a zip file; give a name ending in .zip")
    for parent in out.parents:
        if parent.exists() and not parent.is_dir():
            raise OutputError(f"{out}: {parent} is a file, not a folder")
    if out.is_dir():
        raise OutputError(f"{out} is a folder, not a zip file")
    if out.exists():
        if not force:
            raise OutputError(f"{out} already exists; use --force to replace it")
        if not ours(out):
            raise OutputError(
                f"{out} is not {what} zip written by doorlab; not replacing it (move it away first)"
            )


def write_zip(out: Path, write: Callable[[zipfile.ZipFile], None]) -> Path:
    """Writes the zip ``out`` atomically: ``write(archive)`` fills a temporary file beside
    it, renamed into place; any way out (an error, Ctrl-C, SIGTERM) leaves no partial file
    and the old ``out`` as it was.

    Raises:
        OutputError: ``out`` cannot be written.
    """
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp_name = tempfile.mkstemp(prefix=f".{out.name}.", suffix=".partial", dir=out.parent)
    except OSError as e:
        raise OutputError(f"cannot write {out}: {e.strerror or e}") from None
    tmp = Path(tmp_name)
    try:
        with os.fdopen(fd, "wb") as f, zipfile.ZipFile(f, "w") as archive:
            write(archive)
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


def write_stored(archive: zipfile.ZipFile, name: str, data: bytes) -> None:
    """An entry stored as is (a wheel is compressed already)."""
    info = zipfile.ZipInfo(name, date_time=ZIP_TIME)
    info.external_attr = 0o100644 << 16
    archive.writestr(info, data)
