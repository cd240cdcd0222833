"""``doorlab pset handout OUT.zip``: what students get, in one zip that installs on its own.

The zip holds one folder, ``pset5/``: the problem-set folder with the stubs (``doorlab pset
init``'s files) and the students' wheel of this doorlab
(:func:`doorlab.pset.classroom.wheel.student_wheel_bytes`: the doorlab that grades them, built from
the same files without the answer key, with the stub folder and the practice table its
self-check grades against: :mod:`doorlab.pset.handout.edition`).
The folder's README installs it with ``pip install "./doorlab-<version>-py3-none-any.whl[pset]"``
(the other packages from the package index) and says what to submit; its points and margins
are the assignment's (``--assignment``), and ``course.yaml`` carries what students may see of
it, which the folder's self-check grades with (:mod:`doorlab.pset.handout.course`). Written
atomically; the zip's comment marks it as doorlab's, so ``--force`` replaces only a handout
doorlab wrote.
"""

from __future__ import annotations

import zipfile
from pathlib import Path

from doorlab.pset.classroom.wheel import (
    check_zip_destination,
    student_wheel_bytes,
    write_entry,
    write_stored,
    write_zip,
)
from doorlab.pset.handout.folder import render_folder

FOLDER = "pset5"
"""The folder the zip unpacks to."""
COMMENT = b"doorlab pset handout"
"""The start of the zip's comment: how ``--force`` knows a handout is doorlab's."""


def _is_ours(path: Path) -> bool:
    try:
        with zipfile.ZipFile(path) as archive:
            return archive.comment.startswith(COMMENT)
    except (OSError, zipfile.BadZipFile):
        return False


def write_handout(
    out: str | Path,
    *,
    force: bool = False,
    assignment: object = None,
    reference: dict | None = None,
) -> Path:
    """Writes the students' zip ``out``: ``pset5/`` with the stubs, the notebook, the README
    and the students' wheel of this doorlab (no answer key).

    Args:
        out: The zip to write (its name must end in ``.zip``).
        force: Replace a handout zip doorlab wrote.
        assignment: The course's settings (the README's points and margins, the practice
            draws' random seed); None: defaults.
        reference: The reference episodes' figures of an earlier grading (for the practice
            table); None: simulated now (a few seconds).

    Raises:
        OutputError: ``out`` exists (without ``force``, or is not doorlab's handout), is a
            folder, is under a file or does not end in ``.zip``; doorlab is not installed.
        GradingError: The reference episodes could not be simulated.
    """
    from doorlab import __version__
    from doorlab.pset.grading.answer_key import practice_table

    out = Path(out)
    check_zip_destination(out, force=force, ours=_is_ours, what="a handout")
    files = render_folder(solutions=False, assignment=assignment, course=True)
    if reference is None:
        from doorlab.pset.grading.grader import grade_reference

        reference = grade_reference()
    wheel_name, wheel = student_wheel_bytes(practice_table(assignment, reference), files)

    def write(archive: zipfile.ZipFile) -> None:
        archive.comment = COMMENT + f" (doorlab {__version__})".encode()
        for rel in sorted(files):
            write_entry(archive, f"{FOLDER}/{rel}", files[rel].encode())
        write_stored(archive, f"{FOLDER}/{wheel_name}", wheel)

    return write_zip(out, write)
