"""A class's submissions, as a course hands them to ``doorlab pset grade-all``, and its sheet.

:func:`find_submissions` reads a folder of submissions:

- Gradescope's "Export Submissions" (a folder per submission, ``submission_<id>/``, and
  ``submission_metadata.yml``, a YAML mapping keyed by those folder names whose entries name
  the students with Ruby-symbol keys: ``:submitters: [{":name": ..., ":sid": ...,
  ":email": ...}]``, besides ``:created_at:``, ``:score:``, ``:results:``, ``:history:``);
- or any folder of submission folders, ``.zip`` files and flat files (no metadata: no names).

Every upload is one submission and one row: a folder keeps its name, a zip its name without
``.zip`` and a flat file its name, each unless an earlier one (folders first, then by name)
has it: then its whole name, then that name with ``~2``, ``~3``... appended (``hw0/``,
``hw0.zip`` and ``hw0.zip.zip`` are ``hw0``, ``hw0.zip`` and ``hw0.zip.zip``).

Every submission then goes through the one intake (:func:`doorlab.pset.grading.grader.take_files`).
The metadata file is the course's, but its names are the students': it is read within
bounds (:data:`MAX_METADATA_BYTES`, libyaml's safe loader, no Python object but plain data),
only the fields above are taken, each cleaned and cut, and a file that is not such a mapping
is a one-line error before anything is graded.

:func:`sheet_row` turns a submission's results into its row of ``grades.csv``, whose cells are
cleaned of control characters and guarded against spreadsheet formulas (a name starting with
``=``, ``+``, ``-`` or ``@`` gets a leading ``'``).
"""

from __future__ import annotations

import csv
import io
import os
import stat
import unicodedata
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from doorlab.errors import ConfigError
from doorlab.pset.isolation.intake import shown_name
from doorlab.runtime.inputs import read_text_file

METADATA_NAME = "submission_metadata.yml"
"""Gradescope's list of the export's submissions and their students."""
MAX_METADATA_BYTES = 128 << 20
"""Largest metadata file read [bytes]: Gradescope's holds every submission's results and
history (~10-50 kB each): a class of 500 with a few resubmissions each stays below it."""
MAX_SUBMISSIONS = 10_000
"""Most submissions in one class."""
MAX_SUBMITTERS = 20
"""Most students named per submission (a group)."""
FIELD_CHARS = 200
"""Longest name, student id or e-mail address kept [characters]."""
SKIPPED = frozenset({"__MACOSX", "__pycache__", ".git", ".ipynb_checkpoints"})
"""Names in the folder that are never submissions."""
FORMULA_STARTS = ("=", "+", "-", "@", "\t", "\r")
"""What a spreadsheet reads as a formula at the start of a cell: also after spaces, and in
the forms that Unicode's compatibility normalisation (NFKC) makes them (the full-width
U+FF1D, U+FF0B, U+FF0D, U+FF20; the small and superscript signs), and
:data:`FORMULA_LOOKALIKES`."""
FORMULA_LOOKALIKES = frozenset("\u2212\u2796\u2795")
"""Signs a spreadsheet may read as ``-`` or ``+`` that NFKC leaves as they are (the minus
sign U+2212, the heavy minus and plus signs)."""


@dataclass(frozen=True)
class Submission:
    """One submission of the class.

    Attributes:
        id: Its name in the class: the folder's name, the zip's without ``.zip`` or the
            file's, made unique (see the module docstring; ``DIR/<id>/results.json``, the
            sheet's first column).
        path: The folder, zip or file; None when the metadata names it but the folder is missing.
        submitters: The students, ``[{"name", "sid", "email"}]`` (empty without metadata).
        created_at: When it was submitted (the metadata's ``:created_at:``, ISO 8601; ""
            without one): the late policy's time (:mod:`doorlab.pset.classroom.late`).
    """

    id: str
    path: Path | None
    submitters: tuple = field(default_factory=tuple)
    created_at: str = ""


def _text(value: object) -> str:
    if value is None or isinstance(value, (dict, list)):
        return ""
    return shown_name(str(value))[:FIELD_CHARS]


def _key(key: object) -> str:
    """A Ruby-symbol key (``:name``, ``:name:``) as a plain name."""
    return str(key).strip(":") if isinstance(key, str) else ""


def read_metadata(path: Path) -> dict[str, tuple]:
    """The students of each submission of a Gradescope export's ``submission_metadata.yml``:
    folder name -> ``({"name", "sid", "email"}, ...)``.

    Raises:
        ConfigError: As :func:`read_metadata_entries`.
    """
    return {folder: people for folder, (people, _) in read_metadata_entries(path).items()}


def _created_at(value: object) -> str:
    """The metadata's submission time as ISO 8601 text ("" when there is none or it is no
    time)."""
    from doorlab.pset.classroom.late import submission_time

    when = submission_time(value if not isinstance(value, str) else value[:FIELD_CHARS])
    return when.isoformat() if when is not None else ""


def read_metadata_entries(path: Path) -> dict[str, tuple[tuple, str]]:
    """Each submission's students and submission time of a Gradescope export's
    ``submission_metadata.yml``: folder name -> ``(({"name", "sid", "email"}, ...),
    created_at)`` (``created_at``: ISO 8601, "" without one).

    Raises:
        ConfigError: The file cannot be read, is larger than :data:`MAX_METADATA_BYTES`, is
            not YAML, or is not a mapping of submissions (one line naming the file).
    """
    name = f"{METADATA_NAME} {str(path)!r}"
    text = read_text_file(path, what=METADATA_NAME, max_bytes=MAX_METADATA_BYTES)
    loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
    try:
        data = yaml.load(text, Loader=loader)  # noqa: S506 - a safe loader
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" (line {mark.line + 1})" if mark else ""
        raise ConfigError(f"{name} is not valid YAML{where}") from None
    except (RecursionError, MemoryError):
        raise ConfigError(f"{name} nests too deep or is too large to read") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"{name} must map each submission's folder to its entry")
    if len(data) > MAX_SUBMISSIONS:
        raise ConfigError(f"{name} lists more than {MAX_SUBMISSIONS} submissions")
    out = {}
    for folder, entry in data.items():
        entry = {_key(k): v for k, v in entry.items()} if isinstance(entry, dict) else {}
        people = entry.get("submitters")
        people = people if isinstance(people, list) else []
        submitters = []
        for person in people[:MAX_SUBMITTERS]:
            if isinstance(person, dict):
                fields = {_key(k): v for k, v in person.items()}
                submitters.append({k: _text(fields.get(k)) for k in ("name", "sid", "email")})
        out[str(folder)] = (tuple(submitters), _created_at(entry.get("created_at")))
    return out


def find_submissions(folder: Path, *, reserved=()) -> list[Submission]:
    """The submissions in ``folder`` (see the module docstring), sorted by id.

    ``reserved``: names no submission's id may take (the class folder's own files: an
    upload with such a name is renamed as a duplicate is).

    Raises:
        ConfigError: ``folder`` is not a folder; it holds more than :data:`MAX_SUBMISSIONS`
            entries; its metadata cannot be read.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise ConfigError(f"{folder} is not a folder of submissions")
    metadata_path = folder / METADATA_NAME
    metadata = read_metadata_entries(metadata_path) if metadata_path.exists() else {}
    folders: list[tuple[str, Path]] = []
    files: list[tuple[str, Path]] = []
    with os.scandir(folder) as entries:
        for count, entry in enumerate(entries):
            if count >= MAX_SUBMISSIONS + 1:
                raise ConfigError(f"{folder} holds more than {MAX_SUBMISSIONS} entries")
            name = entry.name
            if name.startswith(".") or name in SKIPPED or name == METADATA_NAME:
                continue
            try:
                mode = entry.stat(follow_symlinks=False).st_mode
            except OSError:
                continue
            if stat.S_ISDIR(mode):
                folders.append((name, Path(entry.path)))
            elif stat.S_ISREG(mode):
                files.append((name, Path(entry.path)))
    # Every upload is one submission: each folder keeps its name, then each zip takes its
    # name without .zip and each other file its name, unless an earlier upload has it (in
    # name order, so the same folder gives the same ids): then its whole name, then the
    # name with ~2, ~3... appended. Nothing is overwritten.
    taken = set(reserved)
    found: dict[str, Path] = {}
    for name, path in [*sorted(folders), *sorted(files)]:
        stem = name[:-4] if name.lower().endswith(".zip") and len(name) > 4 else name
        candidates = [stem, name, *(f"{name}~{k}" for k in range(2, len(taken) + 3))]
        chosen = next(c for c in candidates if c not in taken)
        taken.add(chosen)
        found[chosen] = path
    ids = sorted(set(found) | set(metadata))
    return [Submission(i, found.get(i), *metadata.get(i, ((), ""))) for i in ids]


# The sheet ---------------------------------------------------------------------------------

STATUSES = ("graded", "not_graded", "absent", "error")
"""A row's status: graded (results.json written); not graded (the intake refused it: every
test 0, the reason in its results); absent (named in the metadata, no folder); error (the
grader failed, not the student: no results, ``--resume`` grades it again)."""


def columns(test_keys: list[str]) -> list[str]:
    """The sheet's columns."""
    return [
        "submission",
        "names",
        "sids",
        "emails",
        *test_keys,
        "total",
        "max_total",
        "status",
        "missing_files",
        "seed",
        "sandbox",
        "wall_time_s",
        "submitted_at",
        "late_days",
        "late_penalty",
        "extension",
        "adjustment",
        "adjustments",
        "same_files_as",
        "error",
    ]


def _people(submission: Submission, key: str) -> str:
    return "; ".join(p.get(key, "") for p in submission.submitters)


def sheet_row(submission: Submission, results: dict | None, *, error: str = "") -> dict:
    """The submission's row (``results``: its results file's data; None with ``error``, or
    for an absent submission)."""
    from doorlab.pset.rules.verdicts import TESTS

    row = {
        "submission": submission.id,
        "names": _people(submission, "name"),
        "sids": _people(submission, "sid"),
        "emails": _people(submission, "email"),
        "submitted_at": submission.created_at,
    }
    if results is None:
        status = "absent" if submission.path is None and not error else "error"
        return {**row, "status": status, "error": error}
    by_name = {t.get("name"): t for t in results.get("tests", [])}
    for spec in TESTS:
        test = by_name.get(spec.name)
        row[spec.key] = test.get("score") if test else None
    extra = results.get("extra_data") or {}
    seed = extra.get("seed") or {}
    late = extra.get("late") if isinstance(extra.get("late"), dict) else {}
    batch = extra.get("batch") if isinstance(extra.get("batch"), dict) else {}
    adjusted = extra.get("adjusted") if isinstance(extra.get("adjusted"), dict) else {}
    return {
        **row,
        "total": results.get("score"),
        "max_total": extra.get("max_score"),
        "status": "not_graded" if extra.get("not_graded") else "graded",
        "missing_files": ", ".join((extra.get("submission") or {}).get("missing") or []),
        "seed": seed.get("grading") if isinstance(seed, dict) else None,
        "sandbox": (extra.get("sandbox") or {}).get("mode") or "",
        "wall_time_s": batch.get("wall_time_s"),
        "late_days": late.get("days_late"),
        "late_penalty": late.get("penalty_points"),
        "extension": late.get("extension") and f"due {late.get('due')}: {late['extension']}",
        "adjustment": adjusted.get("points"),
        "adjustments": "; ".join(adjusted.get("reasons") or []),
        "same_files_as": batch.get("same_files_as") or "",
        "error": "",
    }


def _cell(value: object) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return f"{value:.3f}" if not value.is_integer() else f"{value:g}"
    if not isinstance(value, str):
        return str(value)
    text = shown_name(value)
    return "'" + text if formula_like(text) else text


def formula_like(text: str) -> bool:
    """Whether a spreadsheet could read ``text`` as a formula (see :data:`FORMULA_STARTS`)."""
    if text.startswith(FORMULA_STARTS):
        return True
    head = text.lstrip()
    if not head:
        return False
    first = unicodedata.normalize("NFKC", head[0])
    return first.lstrip().startswith(FORMULA_STARTS) or head[0] in FORMULA_LOOKALIKES


def sheet_text(rows: list[dict], test_keys: list[str]) -> str:
    """``grades.csv``'s text: a header and the rows, in their order."""
    out = io.StringIO()
    names = columns(test_keys)
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(names)
    for row in rows:
        writer.writerow([_cell(row.get(c)) for c in names])
    return out.getvalue()
