"""One intake for every grading path: what of a submission is graded.

``doorlab pset grade PATH`` and Gradescope's ``run_autograder`` (and a batch of submissions)
take a submission the same way: :func:`graded_copy` writes a fresh stub folder
(``doorlab pset init``'s) in a private temporary folder and copies over it only the files a
student edits (:data:`~doorlab.pset.handout.folder.STUDENT_FILES`), found by their names anywhere in
the submission:

- three files uploaded flat, the whole problem-set folder, or that folder under another;
- a ``.zip`` file in the submission (or the submission itself a ``.zip``): its members are
  listed and only those named like a student file are read (at most
  :data:`SUBMISSION_FILE_LIMIT` bytes each, however large their headers say they are); a
  member is never written under its own name, so none can land outside the folder; members
  with an absolute path or ``..`` are refused; zips inside zips are not opened;
- a single file (a flat upload): taken if it is named like a student file;
- a missing file: its stub is graded (0 points for its tests), and the summary says so;
- none of the student files at all (a notebook alone, a README, a mistyped folder): the
  submission is not graded (:attr:`Intake.refused` says what it holds and what is graded),
  on every path alike: ``doorlab pset grade`` refuses it, ``grade-all`` gives its row the
  status ``not_graded`` and ``run_autograder`` every test 0 with the reason.

If several files match, the one at its place in the folder (``manip_station_sim/robot_plans.py``)
wins, then the shallowest, then the first by name. Symbolic links, special files and files
over the limit are refused with a line saying why. Nothing else is copied: no file of a
submission can stand in for a module that doorlab or Python imports.

The walk is iterative and bounded (:data:`MAX_DEPTH`, :data:`MAX_ENTRIES`,
:data:`MAX_TOTAL_BYTES`): over a bound the submission is not graded (:attr:`Intake.refused`
names the bound), so a folder nested 1,100 deep or 30,000 files cost a message, not a crash.
Names shown to the student are cleaned (no control characters, valid UTF-8) and the list of
unused files is capped (:data:`SHOWN_IGNORED` names and a count).
"""

from __future__ import annotations

import os
import stat
import unicodedata
import zipfile
from collections import deque
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

from doorlab.errors import OutputError
from doorlab.pset.handout.folder import STUDENT_FILES

SUBMISSION_FILE_LIMIT = 1_000_000
"""Largest student file taken from a submission [bytes]; the stubs are ~5 kB."""
MAX_DEPTH = 32
"""Deepest folder (or zip member) looked at, in folders below the submission's top: the
problem-set folder nests 2 deep, 3 under an extra top folder."""
MAX_ENTRIES = 10_000
"""Most files and folders (zip members included) looked at in one submission: the
problem-set folder has 10; 10,000 leaves room for a course's whole repository."""
MAX_TOTAL_BYTES = 200_000_000
"""Largest total size of a submission's files [bytes] (zips counted at their size on disk):
Gradescope itself takes uploads up to 100 MB."""
MAX_ZIPS = 16
"""Most zip files opened in one submission."""
SHOWN_IGNORED = 20
"""Names of unused files listed (the rest are counted)."""
NAME_CHARS = 200
"""Longest file name shown [characters]."""
SKIPPED_DIRS = frozenset({"__MACOSX", "__pycache__", ".git", ".ipynb_checkpoints"})
"""Folders never looked into (macOS resource forks, bytecode, version control)."""


_NOT_SHOWN = ("Cc", "Cf", "Cs", "Co", "Zl", "Zp")
"""Unicode categories a shown name never holds: controls, format characters, surrogates,
private use, line and paragraph separators."""


def shown_name(name: str) -> str:
    """A file name as the student sees it: control and format characters, the line and
    paragraph separators (U+2028, U+2029: :meth:`str.splitlines` breaks on them) and lone
    surrogates (undecodable bytes) replaced by ``?``, cut to :data:`NAME_CHARS`.

    (One line, so stricter than :func:`~doorlab.pset.isolation.safe_text.clean_text`, which every
    text of the results also goes through when they are written.)
    """
    out = []
    for ch in name[: NAME_CHARS + 1]:
        if 0xD800 <= ord(ch) <= 0xDFFF or unicodedata.category(ch) in _NOT_SHOWN:
            out.append("?")
        else:
            out.append(ch)
    text = "".join(out)
    return text if len(text) <= NAME_CHARS else text[:NAME_CHARS] + "..."


@dataclass
class Intake:
    """What a grading took from a submission.

    Attributes:
        taken: Student file (as in the folder) -> where it was found in the submission.
        missing: Student files not found (their stubs are graded).
        rejected: One line per file not taken although named like a student file.
        ignored: The first :data:`SHOWN_IGNORED` other files (by name).
        ignored_count: How many other files there were.
        refused: Why the submission was not graded at all (a bound; none of the student
            files), or None.
        nothing: It held none of the student files (``refused`` says so).
        unreadable: What this machine could not read of it (a folder, a file: the error),
            which the student did not cause: a grading of what was taken would not be the
            submission's (``grade-all`` makes it the grader's ``error`` row).
    """

    taken: dict[str, str] = field(default_factory=dict)
    missing: list[str] = field(default_factory=list)
    rejected: list[str] = field(default_factory=list)
    ignored: list[str] = field(default_factory=list)
    ignored_count: int = 0
    refused: str | None = None
    nothing: bool = False
    unreadable: list[str] = field(default_factory=list)

    def summary(self) -> str:
        """A few lines for the student (the results' top-level ``output``)."""
        if self.refused is not None:
            return f"Not graded: {self.refused}"
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
        if self.ignored_count:
            more = self.ignored_count - len(self.ignored)
            tail = f" and {more} more" if more > 0 else ""
            lines.append(
                f"Not used (only {', '.join(STUDENT_FILES)} are graded; doorlab provides the "
                f"rest): {', '.join(self.ignored)}{tail}."
            )
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """The results' ``extra_data["submission"]``."""
        return {
            "taken": dict(self.taken),
            "missing": list(self.missing),
            "rejected": list(self.rejected),
            "ignored": list(self.ignored),
            "ignored_count": self.ignored_count,
            "refused": self.refused,
            "nothing": self.nothing,
            "unreadable": list(self.unreadable),
        }


class _OverBound(Exception):
    """The walk passed one of the bounds (the message is the student's)."""


@dataclass
class _Candidate:
    """A file named like a student file: where it is and how to read it."""

    shown: PurePosixPath  # its path in the submission (a zip member: under the zip's path)
    read: object  # () -> bytes (at most SUBMISSION_FILE_LIMIT + 1), or a str: why not


@dataclass
class _Walk:
    names: dict[str, str]  # file name -> student file (its place in the folder)
    candidates: dict[str, list[_Candidate]] = field(default_factory=dict)
    ignored: list[str] = field(default_factory=list)
    unreadable: list[str] = field(default_factory=list)
    entries: int = 0
    total_bytes: int = 0
    zips: int = 0

    def count(self, size: int = 0, entries: int = 1) -> None:
        self.entries += entries
        self.total_bytes += size
        if self.entries > MAX_ENTRIES:
            raise _OverBound(
                f"your submission has more than {MAX_ENTRIES:,} files and folders (the most "
                f"the grader looks at); upload only {', '.join(STUDENT_FILES)} (or the "
                "problem-set folder)"
            )
        if self.total_bytes > MAX_TOTAL_BYTES:
            raise _OverBound(
                f"your submission's files add up to more than {MAX_TOTAL_BYTES // 1_000_000} MB "
                f"(the most the grader takes); upload only {', '.join(STUDENT_FILES)} (or the "
                "problem-set folder)"
            )

    def depth(self, parts: int) -> None:
        if parts > MAX_DEPTH:
            raise _OverBound(
                f"your submission nests folders more than {MAX_DEPTH} deep (the most the "
                f"grader looks into); upload only {', '.join(STUDENT_FILES)} (or the "
                "problem-set folder)"
            )

    def add(self, shown: PurePosixPath, read) -> None:
        rel = self.names.get(shown.name)
        if rel is None:
            self.ignored.append(str(shown))
        else:
            self.candidates.setdefault(rel, []).append(_Candidate(shown, read))


def _read_file(path: Path):
    def read() -> bytes:
        flags = os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOFOLLOW", 0)
        fd = os.open(path, flags | getattr(os, "O_CLOEXEC", 0))
        try:
            if not stat.S_ISREG(os.fstat(fd).st_mode):
                raise OSError("not a regular file")
            with os.fdopen(fd, "rb", closefd=False) as f:
                return f.read(SUBMISSION_FILE_LIMIT + 1)
        finally:
            os.close(fd)

    return read


def _walk_folder(top: Path, walk: _Walk) -> None:
    """Every entry under ``top``, breadth first, by name; zips opened as met."""
    queue: deque[tuple[Path, PurePosixPath]] = deque([(top, PurePosixPath())])
    while queue:
        folder, rel = queue.popleft()
        try:
            with os.scandir(folder) as it:
                entries = sorted(it, key=lambda e: e.name)
        except OSError as e:
            walk.unreadable.append(f"{rel or '.'}: {e.strerror or e}")
            continue
        for entry in entries:
            shown = rel / shown_name(entry.name)
            try:
                info = entry.stat(follow_symlinks=False)
            except OSError as e:
                walk.count()
                walk.unreadable.append(f"{shown}: {e.strerror or e}")
                continue
            if stat.S_ISDIR(info.st_mode):
                if entry.name in SKIPPED_DIRS:
                    continue
                walk.count()
                walk.depth(len(shown.parts))
                queue.append((Path(entry.path), shown))
                continue
            regular = stat.S_ISREG(info.st_mode)
            walk.count(info.st_size if regular else 0)
            if stat.S_ISLNK(info.st_mode):
                walk.add(shown, "is a symbolic link")
            elif not regular:
                walk.add(shown, "is not a regular file")
            elif info.st_size > SUBMISSION_FILE_LIMIT and shown.name in walk.names:
                walk.add(shown, f"is over {SUBMISSION_FILE_LIMIT // 1000} kB")
            elif entry.name.lower().endswith(".zip"):
                _walk_zip(Path(entry.path), shown, walk)
            else:
                walk.add(shown, _read_file(Path(entry.path)))


def _member_path(name: str) -> PurePosixPath | None:
    """A zip member's path, or None if it points outside the zip (absolute, ``..``)."""
    name = name.replace("\\", "/")
    path = PurePosixPath(name)
    if path.is_absolute() or ".." in path.parts or (path.parts and ":" in path.parts[0]):
        return None
    return path


def _zip_entries(path: Path) -> int | None:
    """The entry count a zip's end record states (read before the central directory is)."""
    try:
        with open(path, "rb") as f:
            end = zipfile._EndRecData(f)  # noqa: SLF001 - the stdlib's own reader of that record
    except (OSError, AttributeError):
        return None
    return None if end is None else int(end[zipfile._ECD_ENTRIES_TOTAL])


def _walk_zip(path: Path, shown: PurePosixPath, walk: _Walk) -> None:
    """The members of a zip in the submission (never written to disk under their names)."""
    walk.zips += 1
    stated = _zip_entries(path)
    if stated is None:
        walk.ignored.append(f"{shown} (not a zip file that can be read)")
        return
    if walk.zips > MAX_ZIPS:
        walk.ignored.append(f"{shown} (not opened: more than {MAX_ZIPS} zip files)")
        return
    if walk.entries + stated > MAX_ENTRIES:
        walk.count(entries=stated)  # its members would pass the bound: refused as files are
    try:
        archive = zipfile.ZipFile(path)
    except (OSError, zipfile.BadZipFile, ValueError, NotImplementedError):
        walk.ignored.append(f"{shown} (not a zip file that can be read)")
        return
    with archive:
        for info in sorted(archive.infolist(), key=lambda i: i.filename):
            member = _member_path(info.filename)
            walk.count(info.file_size if not info.is_dir() else 0)
            if info.is_dir():
                continue
            if member is None:
                name = shown / shown_name(info.filename.replace("\\", "/").rsplit("/", 1)[-1])
                walk.add(name, f"points outside the zip ({shown_name(info.filename)})")
                continue
            if any(part in SKIPPED_DIRS for part in member.parts[:-1]):
                continue
            parts = PurePosixPath(*(shown_name(p) for p in member.parts))
            walk.depth(len(shown.parts) + len(parts.parts) - 1)
            if info.file_size > SUBMISSION_FILE_LIMIT:
                walk.add(shown / parts, f"is over {SUBMISSION_FILE_LIMIT // 1000} kB")
            elif member.name.lower().endswith(".zip"):
                walk.ignored.append(f"{shown / parts} (a zip inside a zip: not opened)")
            else:
                walk.add(shown / parts, _read_member(path, info.filename))


def _read_member(path: Path, name: str):
    def read() -> bytes:
        with zipfile.ZipFile(path) as archive, archive.open(name) as f:
            return f.read(SUBMISSION_FILE_LIMIT + 1)

    return read


def _preference(rel: str, candidate: _Candidate) -> tuple:
    # The student file's own place first (at any depth), then the shallowest, then by name.
    found = str(candidate.shown)
    return (not (found == rel or found.endswith("/" + rel)), len(candidate.shown.parts), found)


def take_submission(source: str | Path, folder: str | Path) -> Intake:
    """Copies the student files of ``source`` (a folder or a ``.zip``) over the stubs in the
    problem-set ``folder`` (see the module's docstring for the rules).

    Raises:
        OutputError: ``source`` is neither a folder nor a zip file.
    """
    files, intake = take(source)
    for rel, data in files.items():
        (Path(folder) / rel).write_bytes(data)
    return intake


def take(source: str | Path) -> tuple[dict[str, bytes], Intake]:
    """The student files of ``source`` (a folder or a ``.zip``): their bytes by their place in
    the folder (those taken), and what was taken (see the module's docstring for the rules).
    Reads the submission, writes nothing: no temporary folder, so a full disk cannot change
    what is taken.

    Raises:
        OutputError: ``source`` is neither a folder nor a zip file.
    """
    source = Path(source)
    files: dict[str, bytes] = {}
    names = {PurePosixPath(rel).name: rel for rel in STUDENT_FILES}
    walk = _Walk(names)
    intake = Intake()
    try:
        if source.is_dir():
            _walk_folder(source, walk)
        elif source.is_file() and zipfile.is_zipfile(source):
            _walk_zip(source, PurePosixPath(), walk)
        elif source.is_file() and not source.is_symlink():  # a flat upload: one file
            size = source.stat().st_size
            walk.count(size)
            shown = PurePosixPath(shown_name(source.name))
            too_big = size > SUBMISSION_FILE_LIMIT and shown.name in walk.names
            walk.add(
                shown,
                f"is over {SUBMISSION_FILE_LIMIT // 1000} kB" if too_big else _read_file(source),
            )
        else:
            raise OutputError(
                f"{source} is not a folder or a zip file: give the submission's folder (or "
                "its three files' folder) or a .zip"
            )
    except _OverBound as e:
        intake.refused = str(e)
        intake.missing = list(STUDENT_FILES)
        return files, intake
    for rel in STUDENT_FILES:
        for candidate in sorted(walk.candidates.get(rel, []), key=lambda c: _preference(rel, c)):
            where = str(candidate.shown)
            if rel in intake.taken:
                walk.ignored.append(where)
                continue
            if isinstance(candidate.read, str):
                intake.rejected.append(f"Not taken: {where} {candidate.read}.")
                continue
            try:
                data = candidate.read()
            except OSError as e:  # the grader's machine could not read it: not the student's
                intake.unreadable.append(f"{where}: {e.strerror or e}")
                intake.rejected.append(f"Not taken: {where} cannot be read.")
                continue
            except Exception:  # noqa: BLE001 - a broken member: say so, grade the rest
                intake.rejected.append(f"Not taken: {where} cannot be read.")
                continue
            if len(data) > SUBMISSION_FILE_LIMIT:
                intake.rejected.append(
                    f"Not taken: {where} is over {SUBMISSION_FILE_LIMIT // 1000} kB."
                )
                continue
            files[rel] = data
            intake.taken[rel] = where
        if rel not in intake.taken:
            intake.missing.append(rel)
    intake.unreadable = walk.unreadable + intake.unreadable
    ignored = sorted(walk.ignored)
    intake.ignored = ignored[:SHOWN_IGNORED]
    intake.ignored_count = len(ignored)
    if not intake.taken:
        intake.refused = _nothing_to_grade(ignored, intake.rejected)
        intake.nothing = True
    return files, intake


NOTHING_SHOWN = 5
"""Names of a submission with none of the student files listed in its refusal."""


def _nothing_to_grade(ignored: list[str], rejected: list[str]) -> str:
    """Why a submission holding none of the student files is not graded (one line)."""
    held = ", ".join(ignored[:NOTHING_SHOWN]) if ignored else "no file"
    if len(ignored) > NOTHING_SHOWN:
        held += f" and {len(ignored) - NOTHING_SHOWN} more"
    why = f"; {' '.join(rejected)}" if rejected else ""
    return (
        f"your submission holds none of {', '.join(STUDENT_FILES)}, the files graded (it "
        f"holds {held}{why}); the notebook and other files are not graded: submit those "
        "files, or the problem-set folder"
    )


@contextmanager
def graded_copy(source: str | Path) -> Iterator[tuple[Path, Intake]]:
    """A fresh problem-set folder holding the student files of ``source`` over the stubs,
    and what was taken; the folder (in a private temporary folder) is removed when the
    block ends, however it ends.

    Raises:
        OutputError: ``source`` is neither a folder nor a zip file; the temporary folder
            cannot be written.
    """
    from doorlab.pset.handout.folder import init_folder
    from doorlab.runtime.folders import private_folder

    source = Path(source)
    if not source.exists():
        raise OutputError(f"{source} does not exist")
    with private_folder("doorlab_submission_") as tmp:
        folder = init_folder(tmp / "pset")
        yield folder, take_submission(source, folder)
