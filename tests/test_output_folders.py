"""doorlab.runtime.folders' output folders in-process: the manifest rule of ``--force``, later
writes recorded, the swap not cut short by a signal, staging folders removed at exit (issue 19;
tests/test_data_loss.py runs the same through the CLI)."""

from __future__ import annotations

import json
import os
import signal
from pathlib import Path

import pytest

import doorlab.runtime.folders as folders
from doorlab.cli.parser import _interruption
from doorlab.errors import Interrupted, OutputError
from doorlab.runtime.folders import (
    MANIFEST_NAME,
    commit_output,
    discard_output,
    foreign_file,
    prepare_output,
    private_folder,
    read_manifest,
    record_written,
    remove_written,
    staged_output,
)
from doorlab.runtime.interrupts import deferred_signals


def _written(out, files: dict[str, str]):
    """A folder as doorlab writes it (through a staging folder), holding ``files``."""
    with staged_output(out, force=True) as staging:
        for rel, text in files.items():
            (staging / rel).parent.mkdir(parents=True, exist_ok=True)
            (staging / rel).write_text(text)
    return out


def test_the_manifest_lists_every_file_with_its_hash(tmp_path):
    out = _written(tmp_path / "out", {"a.json": "{}", "figures/b.png": "png"})
    files = read_manifest(out)
    assert set(files) == {"a.json", "figures/b.png"}
    assert files["a.json"]["bytes"] == 2 and len(files["a.json"]["sha256"]) == 64
    assert foreign_file(out) is None
    assert not list(tmp_path.glob(".*partial*"))


def test_foreign_files_are_named(tmp_path):
    out = _written(tmp_path / "out", {"a.json": "{}", "sub/b.txt": "b"})
    assert foreign_file(tmp_path / "missing") is None
    (tmp_path / "empty").mkdir()
    assert foreign_file(tmp_path / "empty") is None
    (out / "sub" / "mine.txt").write_text("mine")
    assert foreign_file(out) == ("sub/mine.txt", "which doorlab did not write")
    (out / "sub" / "mine.txt").unlink()
    (out / "a.json").write_text("{} ")
    assert foreign_file(out) == ("a.json", "which changed since doorlab wrote it")
    (out / "a.json").write_text("{}")
    (out / "link").symlink_to("a.json")
    assert foreign_file(out) == ("link", "a link doorlab did not make")
    (out / "link").unlink()
    cache = out / "sub" / "__pycache__"
    cache.mkdir()
    (cache / "b.cpython-311.pyc").write_bytes(b"\0")
    assert foreign_file(out) is None  # Python's bytecode cache is no user file
    (cache / "notes.txt").write_text("mine")
    assert foreign_file(out)[0].startswith("sub/__pycache__/")  # then it is a folder like others
    (cache / "notes.txt").unlink()
    (out / "index.html").write_text("mine")
    assert foreign_file(out, only=["a.json"]) is None
    assert foreign_file(out, only=["index.html"])[0] == "index.html"
    (out / MANIFEST_NAME).unlink()
    assert "no .doorlab-manifest.json" in foreign_file(out)[1]


def test_force_replaces_only_an_unchanged_folder(tmp_path):
    out = _written(tmp_path / "out", {"a.json": "old"})
    with pytest.raises(OutputError, match="--force"):
        prepare_output(out, force=False)
    _written(out, {"a.json": "new"})
    assert (out / "a.json").read_text() == "new"
    (out / "p.txt").write_text("precious")
    with pytest.raises(OutputError, match="p.txt"):
        prepare_output(out, force=True)
    assert (out / "p.txt").read_text() == "precious"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_commit_checks_again_what_changed_meanwhile(tmp_path):
    """A file the user put in the folder while the run ran: the swap is refused, the file and
    the old folder kept, the staging folder removed by the caller's clean-up."""
    out = _written(tmp_path / "out", {"a.json": "old"})
    staging = prepare_output(out, force=True)
    (staging / "a.json").write_text("new")
    (out / "p.txt").write_text("precious")
    with pytest.raises(OutputError, match="p.txt"):
        commit_output(staging, out)
    discard_output(staging)
    assert (out / "a.json").read_text() == "old" and (out / "p.txt").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_later_writes_are_recorded_and_old_figures_removed(tmp_path):
    out = _written(tmp_path / "out", {"figures/old.png": "old"})
    (out / "results.csv").write_text("a\n1\n")
    record_written(out, [out / "results.csv", tmp_path / "elsewhere.txt"])
    assert "results.csv" in read_manifest(out) and foreign_file(out) is None
    (out / "figures" / "my.png").write_text("mine")
    remove_written(out, "figures")
    assert sorted(p.name for p in (out / "figures").iterdir()) == ["my.png"]
    plain = tmp_path / "plain"
    plain.mkdir()
    (plain / "x.txt").write_text("x")
    record_written(plain, [plain / "x.txt"])  # no manifest: doorlab did not write the folder
    assert not (plain / MANIFEST_NAME).exists()


def test_a_signal_during_the_swap_is_raised_after_it(tmp_path):
    """SIGTERM while the folder is swapped into place: the swap completes, then Interrupted."""

    def raise_interrupted(signum, frame):
        raise Interrupted(signum)

    previous = signal.signal(signal.SIGTERM, raise_interrupted)
    try:
        with pytest.raises(Interrupted):
            with deferred_signals():
                os.kill(os.getpid(), signal.SIGTERM)
                done = True
        assert done
        out = tmp_path / "out"
        staging = prepare_output(out, force=False)
        (staging / "a.json").write_text("{}")
        original = os.replace

        def replace_with_a_signal(src, dst):
            if str(src) == str(staging):  # the swap itself (not the manifest's own write)
                os.kill(os.getpid(), signal.SIGTERM)
            original(src, dst)

        folders.os.replace = replace_with_a_signal
        try:
            with pytest.raises(Interrupted):
                commit_output(staging, out)
        finally:
            folders.os.replace = original
        assert json.loads((out / "a.json").read_text()) == {}
        assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
    finally:
        signal.signal(signal.SIGTERM, previous)


@pytest.mark.parametrize("when", ["made", "removing"])
def test_ctrl_c_as_a_private_folder_is_made_or_removed_leaves_nothing(tmp_path, monkeypatch, when):
    """Ctrl-C right after ``mkdtemp`` (before anything knows the folder) or in the middle of
    its removal (after a first entry went): the folder is gone all the same, then Ctrl-C is
    raised (CI: a grade-all interrupted at such a moment left a student's files in TMPDIR,
    as ``tempfile.TemporaryDirectory`` does)."""
    monkeypatch.setattr(folders.tempfile, "tempdir", str(tmp_path))
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    real_mkdtemp, real_rmtree = folders.tempfile.mkdtemp, folders.shutil.rmtree

    def mkdtemp_then_ctrl_c(**kwargs):
        made = real_mkdtemp(**kwargs)
        os.kill(os.getpid(), signal.SIGINT)
        return made

    def ctrl_c_midway(path, ignore_errors=False):
        entries = sorted(Path(path).iterdir())
        entries[0].unlink()  # a first entry removed, then the signal lands
        os.kill(os.getpid(), signal.SIGINT)
        real_rmtree(path, ignore_errors=ignore_errors)

    try:
        if when == "made":
            monkeypatch.setattr(folders.tempfile, "mkdtemp", mkdtemp_then_ctrl_c)
        with pytest.raises(KeyboardInterrupt):
            with private_folder("doorlab_submission_") as folder:
                for name in ("a.py", "b.py"):
                    (folder / name).write_text("student's code")
                if when == "removing":
                    monkeypatch.setattr(folders.shutil, "rmtree", ctrl_c_midway)
        assert list(tmp_path.iterdir()) == []
    finally:
        signal.signal(signal.SIGINT, previous)
    monkeypatch.undo()
    with pytest.raises(ValueError):  # the body's own exception: removed, then raised
        with private_folder("doorlab_test_") as folder:
            (folder / "a.py").write_text("x")
            raise ValueError
    assert not folder.exists()


def test_staging_folders_left_by_a_caller_are_removed_at_exit(tmp_path):
    staging = prepare_output(tmp_path / "out", force=False)
    (staging / "half.json").write_text("{")
    folders.remove_staged_folders()  # what atexit runs
    assert not staging.exists()


def test_an_import_cut_short_by_a_signal_is_an_interruption():
    cause = KeyboardInterrupt()
    try:
        try:
            raise cause
        except KeyboardInterrupt as e:
            raise ImportError("initialization failed") from e
    except ImportError as error:
        assert _interruption(error) is cause
    assert _interruption(ImportError("no module named x")) is None
