"""The folders doorlab writes, and the rule that nothing a user owns is lost.

A folder is assembled in a hidden staging folder beside its target and renamed into place at the
end (:func:`staged_output`), so it either appears complete or not at all; every way out removes
the staging folder. Every folder doorlab writes holds a manifest of the files it wrote
(:data:`MANIFEST_NAME`: path, size, SHA-256), and ``--force`` replaces a folder only if it holds
nothing else, unchanged (:func:`check_replaceable`). Run folders, reports, sweeps, problem-set
folders, the simulated driver's ground truth: all go through here.
"""

from __future__ import annotations

import atexit
import hashlib
import json
import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

from doorlab.errors import OutputError
from doorlab.runtime.interrupts import (
    deferred_signals,
    ignoring_signals,
)

MANIFEST_NAME = ".doorlab-manifest.json"
"""The file in every folder doorlab writes that lists the files it wrote (path -> size and
SHA-256); ``--force`` replaces a folder only if it holds nothing else, unchanged."""


CACHE_FOLDER = "__pycache__"
"""Python's bytecode caches (``__pycache__/*.pyc``, written when a problem set's modules are
imported) are not a user's files: ``--force`` does not count them."""


_staged: set[Path] = set()
"""Staging folders not yet committed or discarded (removed at exit, whatever the way out)."""


def umask() -> int:
    """The process's file-creation mask (read without changing it for long)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def follow_umask(path: Path, *, folder: bool) -> None:
    """Gives ``path`` the mode a plain ``open``/``mkdir`` would have (``tempfile`` makes its
    files 0600 and folders 0700, private; results shared with a course group must not be)."""
    os.chmod(path, (0o777 if folder else 0o666) & ~umask())


def _digest(path: Path) -> str:
    sha = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(1 << 20):
            sha.update(chunk)
    return sha.hexdigest()


def read_manifest(folder: Path) -> dict[str, dict] | None:
    """What doorlab wrote into ``folder`` (relative POSIX path -> ``{"bytes", "sha256"}``), or
    None if it has no readable manifest (then doorlab did not write the folder)."""
    path = Path(folder) / MANIFEST_NAME
    try:
        if path.is_symlink() or not path.is_file():
            return None
        data = json.loads(path.read_text())
        files = data["files"]
        if not isinstance(files, dict):
            return None
        return {str(k): v for k, v in files.items() if isinstance(v, dict)}
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _write_manifest(folder: Path, files: dict[str, dict]) -> None:
    from doorlab import __version__

    data = {"written_by": f"doorlab {__version__}", "files": dict(sorted(files.items()))}
    path = Path(folder) / MANIFEST_NAME
    tmp = path.with_name(f"{MANIFEST_NAME}.{os.getpid()}.tmp")
    try:
        tmp.write_text(json.dumps(data, indent=1) + "\n")
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _entry(path: Path) -> dict:
    return {"bytes": path.stat().st_size, "sha256": _digest(path)}


def _walk_files(folder: Path) -> Iterator[Path]:
    for entry in sorted(os.scandir(folder), key=lambda e: e.name):
        path = Path(entry.path)
        if entry.is_dir(follow_symlinks=False):
            yield from _walk_files(path)
        elif entry.is_file(follow_symlinks=False):
            yield path


def write_manifest(folder: Path, *, exclude: Iterable[str] = ()) -> None:
    """Records every file now under ``folder`` as written by doorlab (a complete staging
    folder, just before it is committed), but the top-level names ``exclude`` (a user's)."""
    folder = Path(folder)
    files = {
        p.relative_to(folder).as_posix(): _entry(p)
        for p in _walk_files(folder)
        if p.relative_to(folder).as_posix() not in (MANIFEST_NAME, *exclude)
    }
    _write_manifest(folder, files)


def record_written(folder: Path, paths: Iterable[Path]) -> None:
    """Adds files doorlab just wrote into a folder it wrote earlier to that folder's manifest
    (a sweep's table and page, a report's PDF, a problem set's grading results); entries of
    files that are gone are dropped. Nothing happens in a folder without a manifest."""
    folder = Path(folder)
    files = read_manifest(folder)
    if files is None:
        return
    root = folder.resolve()
    for path in paths:
        path = Path(path)
        try:
            rel = path.resolve().relative_to(root).as_posix()
        except ValueError:
            continue  # not inside the folder
        if path.is_file() and not path.is_symlink():
            files[rel] = _entry(path)
    files = {rel: e for rel, e in files.items() if (folder / rel).is_file()}
    _write_manifest(folder, files)


def replace_recorded(folder: Path, tmp: Path, path: Path) -> None:
    """Moves the complete file ``tmp`` over ``path`` (inside ``folder``, which doorlab wrote)
    with its manifest entry: the entry first, then the rename, so that a full disk (ENOSPC)
    at either step leaves the file and its entry agreeing (the old ones): no file the next
    run would refuse as changed since doorlab wrote it. Nothing is recorded in a folder
    without a manifest.

    Raises:
        OSError: The manifest or the rename failed (``tmp`` is left to the caller).
    """
    folder = Path(folder)
    files = read_manifest(folder)
    if files is None:
        os.replace(tmp, path)
        return
    rel = Path(os.path.abspath(path)).relative_to(Path(os.path.abspath(folder))).as_posix()
    before = files.get(rel)
    files[rel] = _entry(Path(tmp))
    _write_manifest(folder, files)
    try:
        os.replace(tmp, path)
    except BaseException:
        if before is None:
            files.pop(rel)
        else:
            files[rel] = before
        _write_manifest(folder, files)
        raise


def remove_unrecorded(folder: Path, names: Iterable[str]) -> list[str]:
    """Removes the files under ``folder``'s top-level ``names`` that its manifest does not
    record as they are (outputs doorlab rewrites on every run, whose manifest update a full
    disk cut short); returns them (relative paths)."""
    folder = Path(folder)
    files = read_manifest(folder) or {}
    removed = []
    for name in names:
        top = folder / name
        paths = list(_walk_files(top)) if top.is_dir() and not top.is_symlink() else [top]
        for path in paths:
            if not path.is_file() or path.is_symlink():
                continue
            rel = path.relative_to(folder).as_posix()
            if rel not in files or not _unchanged(path, files[rel]):
                path.unlink(missing_ok=True)
                removed.append(rel)
    return removed


def remove_written(folder: Path, subfolder: str) -> None:
    """Removes the files doorlab wrote under ``folder/subfolder`` and that are unchanged (a
    page's old figures); a user's files there stay."""
    folder = Path(folder)
    files = read_manifest(folder) or {}
    prefix = subfolder.rstrip("/") + "/"
    for rel, entry in files.items():
        if rel.startswith(prefix) and _unchanged(folder / rel, entry):
            (folder / rel).unlink(missing_ok=True)


def _unchanged(path: Path, entry: dict) -> bool:
    try:
        if path.is_symlink() or not path.is_file():
            return False
        return path.stat().st_size == entry.get("bytes") and _digest(path) == entry.get("sha256")
    except OSError:
        return False


def foreign_file(
    folder: Path, *, only: Iterable[str] | None = None, keep: Iterable[str] = ()
) -> tuple[str, str] | None:
    """The first thing under ``folder`` that replacing it would lose, and why; None if it holds
    nothing but the files doorlab wrote, unchanged (or is empty, or does not exist).

    Args:
        folder: The folder (not followed if it is a link: callers resolve it first).
        only: Check only these top-level names (what a resumed sweep rewrites).
        keep: Top-level names of a user's files that a replacement keeps (not counted).

    Returns:
        (path relative to ``folder``, why), e.g. ``("p.txt", "which doorlab did not write")``.
    """
    folder = Path(folder)
    if not folder.is_dir():
        return None
    files = read_manifest(folder)
    names = [n for n in sorted(os.listdir(folder)) if n not in set(keep)]
    if only is not None:
        names = [n for n in names if n in set(only)]
    if files is None:
        if not names:
            return None
        return (names[0], f"which doorlab did not write (the folder has no {MANIFEST_NAME})")
    return _foreign_in(folder, "", names, files)


def _foreign_in(folder: Path, prefix: str, names: list[str], files: dict) -> tuple | None:
    for name in names:
        rel = f"{prefix}{name}"
        path = folder / rel
        if rel == MANIFEST_NAME:
            continue
        if path.is_symlink():
            return (rel, "a link doorlab did not make")
        if path.is_dir():
            if name == CACHE_FOLDER and _only_bytecode(path):
                continue
            found = _foreign_in(folder, f"{rel}/", sorted(os.listdir(path)), files)
            if found is not None:
                return found
        elif rel not in files:
            return (rel, "which doorlab did not write")
        elif not _unchanged(path, files[rel]):
            return (rel, "which changed since doorlab wrote it")
    return None


def _only_bytecode(folder: Path) -> bool:
    return all(p.is_file() and not p.is_symlink() and p.suffix == ".pyc" for p in folder.iterdir())


def _target(out_dir: Path) -> Path:
    """The folder ``out_dir`` names: a link to a folder is followed (the link stays)."""
    out_dir = Path(out_dir)
    return out_dir.resolve() if out_dir.is_symlink() else Path(os.path.abspath(out_dir))


def check_replaceable(
    out_dir: Path, *, force: bool, label: str | None = None, keep: Iterable[str] = ()
) -> Path:
    """Checks that ``out_dir`` may be written, writing nothing; returns the folder it names.

    The rule: a missing or empty folder may be written; one holding only files doorlab wrote,
    unchanged, may be replaced with ``force``; nothing else, ever (the message names a file
    that would be lost).

    Args:
        out_dir: The output folder (a link to a folder names that folder).
        force: Replace a folder doorlab wrote.
        label: How messages name the folder (default ``--out 'DIR'``).
        keep: Top-level names of a user's files that a replacement keeps
            (:func:`commit_output`).

    Raises:
        OutputError: ``out_dir`` is a file, under a file, the root, exists without ``force``,
            or holds something doorlab did not write or that changed since.
    """
    name = label or f"--out {str(out_dir)!r}"
    target = _target(out_dir)
    if target == Path(target.anchor):
        raise OutputError(f"{name} is the file system's root; choose a folder inside it")
    if target.exists() and not target.is_dir():
        raise OutputError(f"{name} is a file, not a folder")
    for ancestor in target.parents:
        if ancestor.exists() and not ancestor.is_dir():
            raise OutputError(f"{name}: {str(ancestor)!r} is a file, not a folder")
    if not target.is_dir():
        return target
    try:
        found = foreign_file(target, keep=keep)
        empty = not any(p.name not in set(keep) for p in target.iterdir())
    except OSError as e:
        raise OutputError(f"cannot read {name}: {e.strerror or e}") from None
    if found is not None:
        rel, why = found
        raise OutputError(
            f"{name} already exists and holds {rel!r}, {why}; --force replaces only a folder "
            "holding nothing but the files doorlab wrote, unchanged: move it away or choose "
            "another folder"
        )
    if not empty and not force:
        raise OutputError(f"{name} already exists; pass --force to replace it")
    return target


def prepare_output(
    out_dir: Path, *, force: bool, label: str | None = None, keep: Iterable[str] = ()
) -> Path:
    """Checks that ``out_dir`` may be written (:func:`check_replaceable`) and returns a fresh
    staging folder beside it; :func:`commit_output` moves it into place, :func:`discard_output`
    removes it. A staging folder neither committed nor discarded is removed at exit.

    Raises:
        OutputError: ``out_dir`` may not be written (see :func:`check_replaceable`), or its
            parent cannot be created or written.
    """
    name = label or f"--out {str(out_dir)!r}"
    target = check_replaceable(out_dir, force=force, label=label, keep=keep)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        with deferred_signals():
            staging = Path(
                tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".partial", dir=target.parent)
            )
            _staged.add(staging)
        follow_umask(staging, folder=True)
        return staging
    except OSError as e:
        raise OutputError(f"cannot write {name}: {e.strerror or e}") from None


def commit_output(staging: Path, out_dir: Path, *, keep: Iterable[str] = ()) -> None:
    """Moves a complete staging folder into place, with its manifest, replacing ``out_dir``
    (checked again: it may have changed since :func:`prepare_output`). The swap is not cut
    short by a signal (which is raised right after it). The user's files ``keep`` (top-level
    names) of the folder replaced are copied into the new one first (not in its manifest).

    Raises:
        OutputError: ``out_dir`` now holds a file doorlab did not write (nothing is moved).
    """
    staging, target = Path(staging), _target(out_dir)
    keep = tuple(keep)
    try:
        for name in keep:
            kept = target / name
            if kept.is_file() and not kept.is_symlink() and not (staging / name).exists():
                shutil.copy2(kept, staging / name)
    except OSError as e:
        raise OutputError(f"cannot write {str(out_dir)!r}: {e.strerror or e}") from None
    write_manifest(staging, exclude=keep)
    try:
        _swap(staging, target, out_dir, keep)
    except OSError as e:
        raise OutputError(f"cannot write {str(out_dir)!r}: {e.strerror or e}") from None


def _swap(staging: Path, target: Path, out_dir: Path, keep: tuple[str, ...] = ()) -> None:
    with deferred_signals():
        if target.exists() and not target.is_dir():
            raise OutputError(f"{str(out_dir)!r} is now a file; it was not replaced")
        if target.is_dir():
            found = foreign_file(target, keep=keep)
            if found is not None:
                raise OutputError(
                    f"{str(out_dir)!r} now holds {found[0]!r}, {found[1]}; it was not replaced"
                )
            old = staging.with_name(staging.name + ".old")
            os.replace(target, old)
            _staged.add(old)
            try:
                os.replace(staging, target)
            except BaseException:
                os.replace(old, target)
                _staged.discard(old)
                raise
            _staged.discard(staging)
            shutil.rmtree(old, ignore_errors=True)
            _staged.discard(old)
        else:
            os.replace(staging, target)
            _staged.discard(staging)


def discard_output(staging: Path) -> None:
    """Removes a staging folder (an uncommitted result); not cut short by a signal."""
    staging = Path(staging)
    with deferred_signals():
        if staging in _staged:
            shutil.rmtree(staging, ignore_errors=True)
            _staged.discard(staging)


@contextmanager
def staged_output(
    out_dir: Path, *, force: bool, label: str | None = None, keep: Iterable[str] = ()
) -> Iterator[Path]:
    """A staging folder for the ``with`` block, committed to ``out_dir`` when the block ends
    normally and removed when it ends by any exception (Ctrl-C and SIGTERM included);
    ``keep``: the top-level names of a user's files the new folder keeps."""
    staging = prepare_output(out_dir, force=force, label=label, keep=keep)
    try:
        yield staging
        commit_output(staging, out_dir, keep=keep)
    finally:
        discard_output(staging)


@contextmanager
def private_folder(prefix: str) -> Iterator[Path]:
    """A private temporary folder (``tempfile``'s, mode 0700) for the ``with`` block, removed
    when it ends, however it ends: its creation and its removal are not cut short by a
    signal (``tempfile.TemporaryDirectory`` leaves its folder when Ctrl-C lands between
    ``mkdtemp`` and its finalizer, or in the middle of its ``rmtree``), and a folder the
    block did not get to remove is removed at exit.

    Raises:
        OutputError: the temporary folder cannot be made.
    """
    folder: Path | None = None
    try:
        with deferred_signals():  # a signal here is raised once the folder is known
            try:
                folder = Path(tempfile.mkdtemp(prefix=prefix))
            except OSError as e:
                raise OutputError(f"cannot make a temporary folder: {e.strerror or e}") from None
            _staged.add(folder)
        yield folder
    finally:
        if folder is not None:
            discard_output(folder)


@atexit.register
def remove_staged_folders() -> None:
    """The last way out: staging and private folders a caller neither committed nor removed
    (run at exit; a process that leaves by ``os._exit`` from a signal handler calls it
    there)."""
    with ignoring_signals():
        for path in sorted(_staged, reverse=True):
            shutil.rmtree(path, ignore_errors=True)
        _staged.clear()


def write_json(path: Path, data: dict) -> None:
    """Writes ``data`` as indented JSON (NaN as null)."""

    def clean(value):
        if isinstance(value, float) and value != value:
            return None
        if isinstance(value, dict):
            return {k: clean(v) for k, v in value.items()}
        if isinstance(value, (list, tuple)):
            return [clean(v) for v in value]
        return value

    path.write_text(json.dumps(clean(data), indent=2) + "\n")
