"""This environment's packages where every user can read them.

Tests that run code as another user (the grader's fallback user, an ordinary user) give that
user this environment's packages and doorlab's source through a path file. A checkout in a
folder only its owner can read (a home: ``/root`` is 0700, Ubuntu's homes 0750) keeps its
``.venv`` and ``src`` from them: there :func:`readable` makes, once per process, a copy that
every user can reach, in a world-readable temporary folder removed at exit. The third-party
packages are hard links where the file system allows (no space, about a second for the
gigabyte of Drake and its dependencies); doorlab's source is copied (a few MB), so nothing a
test does to it reaches the checkout.
"""

from __future__ import annotations

import atexit
import os
import shutil
import stat
import tempfile
from pathlib import Path

_COPIES: dict[str, str] = {}
_ROOT: list[Path] = []


def everyone_reaches(path: str | os.PathLike) -> bool:
    """Whether every user can list ``path`` (a folder) and pass through each folder above it."""
    path = Path(path).resolve()
    for folder in [path, *path.parents]:
        mode = folder.stat().st_mode
        if not mode & stat.S_IXOTH or (folder == path and not mode & stat.S_IROTH):
            return False
    return True


def _copies_root() -> Path:
    if not _ROOT:
        root = Path(tempfile.mkdtemp(prefix="doorlab_readable_"))
        os.chmod(root, 0o755)
        _ROOT.append(root)
        atexit.register(shutil.rmtree, root, True)
    return _ROOT[0]


def _link_or_copy(src: str, dst: str) -> None:
    """A hard link to a file every user can read, else a copy made readable."""
    if os.stat(src).st_mode & stat.S_IROTH:
        try:
            os.link(src, dst)
            return
        except OSError:  # another file system, or links refused: copy
            pass
    shutil.copy2(src, dst)
    os.chmod(dst, os.stat(dst).st_mode | 0o444)


def _copy(src: str, dest: Path, link: bool) -> None:
    """``src`` copied to ``dest`` (hard links for ``link``), every folder and file readable."""
    shutil.copytree(
        src,
        dest,
        symlinks=True,
        copy_function=_link_or_copy if link else shutil.copy2,
        ignore=None if link else shutil.ignore_patterns("__pycache__"),
    )
    for folder, _dirs, files in os.walk(dest):
        os.chmod(folder, 0o755)
        for name in [] if link else files:
            file = os.path.join(folder, name)
            if not os.path.islink(file):
                os.chmod(file, os.stat(file).st_mode | 0o444)


def readable(path: str | os.PathLike) -> str:
    """``path`` (a folder) if every user can reach it, else a copy of it they can (hard
    links); the same copy for the same path in a process."""
    key = str(Path(path).resolve())
    if everyone_reaches(key):
        return key
    if key not in _COPIES:
        dest = _copies_root() / f"{len(_COPIES)}-{Path(key).name}"
        _copy(key, dest, link=True)
        _COPIES[key] = str(dest)
    return _COPIES[key]


def readable_site_packages() -> list[str]:
    """This interpreter's site folders, as every user can read them."""
    import site

    return [readable(p) for p in site.getsitepackages() if os.path.isdir(p)]


def readable_source() -> str:
    """The folder holding the ``doorlab`` package in use (``src`` of an editable install), as
    every user can read it: where a copy is needed, of the package alone, its files copied."""
    import doorlab

    package = Path(doorlab.__file__).resolve().parent
    if everyone_reaches(package):
        return str(package.parent)
    holder = _copies_root() / "src"
    if not holder.exists():
        _copy(str(package), holder / "doorlab", link=False)
        os.chmod(holder, 0o755)
    return str(holder)
