"""``doorlab pset handout OUT.zip``: what students get, in one zip that installs on its own.

The zip holds one folder, ``pset5/``: the problem-set folder with the stubs (``doorlab pset
init``'s files) and the wheel of this doorlab (:func:`doorlab.pset.wheel.wheel_bytes`, the
same the autograder zip carries, so the doorlab students run is the one that grades them).
The folder's README installs it with ``pip install "./doorlab-<version>-py3-none-any.whl[pset]"``
(the other packages from the package index) and says what to submit; its points and margins
are the assignment's (``--assignment``), and ``course.yaml`` carries what students may see of
it, which the folder's self-check grades with (:mod:`doorlab.pset.course`). Written
atomically; the zip's comment marks it as doorlab's, so ``--force`` replaces only a handout
doorlab wrote.
"""

from __future__ import annotations

import zipfile
from pathlib import Path

from doorlab.pset.folder import render_folder
from doorlab.pset.wheel import (
    check_zip_destination,
    wheel_bytes,
    write_entry,
    write_stored,
    write_zip,
)

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


def write_handout(out: str | Path, *, force: bool = False, assignment: object = None) -> Path:
    """Writes the students' zip ``out``: ``pset5/`` with the stubs, the notebook, the README
    and this doorlab's wheel.

    Args:
        out: The zip to write (its name must end in ``.zip``).
        force: Replace a handout zip doorlab wrote.
        assignment: The course's settings (the README's points and margins); None: defaults.

    Raises:
        OutputError: ``out`` exists (without ``force``, or is not doorlab's handout), is a
            folder, is under a file or does not end in ``.zip``; doorlab is not installed.
    """
    from doorlab import __version__

    out = Path(out)
    check_zip_destination(out, force=force, ours=_is_ours, what="a handout")
    wheel_name, wheel = wheel_bytes()
    files = render_folder(solutions=False, assignment=assignment, course=True)

    def write(archive: zipfile.ZipFile) -> None:
        archive.comment = COMMENT + f" (doorlab {__version__})".encode()
        for rel in sorted(files):
            write_entry(archive, f"{FOLDER}/{rel}", files[rel].encode())
        write_stored(archive, f"{FOLDER}/{wheel_name}", wheel)

    return write_zip(out, write)
