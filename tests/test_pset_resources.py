"""Issue 43, without a grading: what a class shares that no view owns, and the sheet's guard.

The limits derived from the machine and ``--jobs`` (:mod:`doorlab.pset.isolation.memory`), the
room checks and the writes that ENOSPC cannot leave half-done, the intake that writes nothing,
the CSV guard. The attacks themselves (a class beside hidden memory, beside a disk filler)
are graded in ``test_pset_exhaustion.py``.
"""

from __future__ import annotations

import pytest

from doorlab.pset.classroom.roster import _cell, sheet_text


@pytest.mark.parametrize(
    "text",
    [
        "=1+1",
        " =1+1",
        "\u3000=1+1",  # an ideographic space first
        "\u00a0@SUM(A1)",
        "\uff1dcmd|' /C calc'!A0",  # full-width equals
        "\uff0b1",  # full-width plus
        "\uff0d1",  # full-width hyphen-minus
        "\uff20SUM(A1)",  # full-width commercial at
        "\ufe66HYPERLINK(1)",  # small equals
        "\u2212 1",  # the minus sign
        "  -2+3",
    ],
)
def test_the_csv_guard_catches_full_width_and_space_led_formulas(text):
    """A cell a spreadsheet could run as a formula is written with a leading quote, however
    its formula character is spelled or spaced (issue 43: U+FF1D and a space before = passed)."""
    assert _cell(text) == "'" + text
    assert "\n'" in sheet_text([{"submission": text}], [])


@pytest.mark.parametrize("text", ["Ada Lovelace", "O'Brien", "\uff21da", "1-2", "a=b", ""])
def test_the_csv_guard_leaves_plain_cells_alone(text):
    assert _cell(text) == text


# Memory: the views' limits ----------------------------------------------------------------

GIB = 1 << 30


def test_each_view_s_limit_is_its_share_of_the_room_after_the_grader_s_own():
    """The views' limits together and what is kept for the grader fit in the room found (a
    container's limit, a test's group), at most 3 GiB each; the line names the room."""
    from doorlab.pset.isolation import memory

    room = memory.Room(int(2.5 * GIB), "the cgroup /class's limit")
    plan = memory.plan(views=2, gradings=2, found=room)
    kept = memory.GRADER_BYTES + 2 * memory.GRADING_BYTES
    assert plan.view_bytes == (room.bytes - kept) // 2 >> 20 << 20
    assert 2 * plan.view_bytes + kept <= room.bytes
    assert "2 at once" in plan.line() and "the cgroup /class's limit" in plan.line()
    big = memory.plan(views=2, gradings=2, found=memory.Room(64 * GIB, "this machine's"))
    assert big.view_bytes == memory.VIEW_MEMORY_MAX_BYTES


def test_too_little_room_for_the_jobs_is_one_line_naming_the_jobs_that_fit():
    """--jobs 4 in 2.5 GiB: refused in one line saying how many fit; where a grading must
    run anyway (the autograder's container), the least a view is given, and the line says
    the views may be ended early."""
    from doorlab.errors import ConfigError
    from doorlab.pset.isolation import memory

    room = memory.Room(int(2.5 * GIB), "the cgroup /x's limit")
    with pytest.raises(ConfigError) as refused:
        memory.plan(views=4, gradings=4, found=room)
    text = str(refused.value)
    assert "\n" not in text and "--jobs 4" in text and "use --jobs 3" in text, text
    assert memory.plan(views=3, gradings=3, found=room).view_bytes >= memory.VIEW_MEMORY_MIN_BYTES
    short = memory.plan(views=4, gradings=4, found=room, strict=False)
    assert short.view_bytes == memory.VIEW_MEMORY_MIN_BYTES and short.short
    assert "may end a view early" in short.line()


def test_a_test_s_process_is_the_first_the_oom_killer_ends():
    """The ranks: a test's process above its view's first process, both above the grader's
    (which only root may lower); the view's first process writes the test's value."""
    from doorlab.pset.isolation import memory, zygote

    assert memory.TRUSTED_OOM_SCORE_ADJ < 0 < memory.VIEW_OOM_SCORE_ADJ
    assert memory.VIEW_OOM_SCORE_ADJ < memory.STUDENT_OOM_SCORE_ADJ == 1000
    assert zygote.STUDENT_OOM_SCORE_ADJ == memory.STUDENT_OOM_SCORE_ADJ


# Disk: the intake writes nothing; what cannot be read is the grader's -----------------------


def test_the_intake_writes_nothing_so_a_full_tmpdir_changes_nothing(tmp_path, monkeypatch):
    """What is taken of a submission does not depend on TMPDIR (issue 43: with TMPDIR full,
    honest submissions were taken as nothing and recorded not_graded 0)."""
    import tempfile

    from doorlab.pset.grading.grader import take_files
    from doorlab.pset.handout.folder import init_folder

    folder = init_folder(tmp_path / "key", solutions=True)
    files, intake = take_files(folder)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "no-such-tmpdir"))
    again, intake_again = take_files(folder)
    assert again == files and intake_again == intake and len(files) == 3
    assert intake.unreadable == []


def _unreadable(monkeypatch, name: str) -> None:
    """Reading a file called ``name`` fails as a failing disk fails (EIO)."""
    import errno

    from doorlab.pset.isolation import intake

    real = intake._read_file

    def read_file(path):
        if path.name != name:
            return real(path)

        def fail() -> bytes:
            raise OSError(errno.EIO, "Input/output error")

        return fail

    monkeypatch.setattr(intake, "_read_file", read_file)


def test_a_submission_that_cannot_be_read_is_the_grader_s_error_row(tmp_path, monkeypatch):
    """A file of a submission that this machine cannot read: grade-all's row is an error
    (the grader's, --resume grades it), never not_graded with 0 points; --resume does not
    count such files unchanged."""
    from doorlab.pset.classroom.grade_all import grade_class
    from doorlab.pset.classroom.regrade import plan_step
    from doorlab.pset.handout.folder import init_folder

    export = tmp_path / "export"
    for name in ("a", "b"):
        init_folder(export / name)
    _unreadable(monkeypatch, "ik_utils.py")
    outcome = grade_class(export, tmp_path / "out", reference={"x": {}}, jobs=1)
    assert [r["status"] for r in outcome.rows] == ["error", "error"], outcome.rows
    assert all("Input/output error" in r["error"] for r in outcome.rows), outcome.rows
    assert all(r.get("total") is None for r in outcome.rows), outcome.rows  # no 0 points
    step = plan_step({"extra_data": {}}, "unread:Input/output error", {})
    assert step.action == "grade" and "could not be read" in step.why


# Disk: a write a full disk stops leaves the file and the manifest agreeing -------------------


def test_a_write_a_full_disk_stops_leaves_the_file_and_its_manifest_entry_as_they_were(
    tmp_path, monkeypatch
):
    import errno

    from doorlab.runtime import folders

    out = tmp_path / "class"
    with folders.staged_output(out, force=False) as staging:
        (staging / "summary.txt").write_text("old\n")
    before = folders.read_manifest(out)
    tmp = out / ".summary.tmp"
    tmp.write_text("new\n")

    def full(folder, files):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(folders, "_write_manifest", full)
    with pytest.raises(OSError):
        folders.replace_recorded(out, tmp, out / "summary.txt")
    assert (out / "summary.txt").read_text() == "old\n"
    assert folders.read_manifest(out) == before
    monkeypatch.undo()
    assert folders.foreign_file(out, only=["summary.txt"]) is None  # the next run goes on
    folders.replace_recorded(out, tmp, out / "summary.txt")
    assert (out / "summary.txt").read_text() == "new\n"
    assert folders.foreign_file(out) is None


# The cluster --------------------------------------------------------------------------------


def test_a_plain_tcp_scheduler_is_refused_without_insecure_cluster(tmp_path):
    """grade-all --scheduler tcp://...: refused in one line before anything is written or
    connected (port 9, discard: nothing listens), naming --insecure-cluster; with it, the
    warning line says whoever reaches the scheduler can change every grade."""
    from doorlab.errors import ConfigError
    from doorlab.pset.classroom.cluster import check_cluster
    from doorlab.pset.classroom.grade_all import grade_class
    from doorlab.pset.handout.folder import init_folder

    init_folder(tmp_path / "export" / "a")
    out = tmp_path / "out"
    with pytest.raises(ConfigError) as refused:
        grade_class(tmp_path / "export", out, scheduler="tcp://127.0.0.1:9", reference={})
    text = str(refused.value)
    assert "\n" not in text and "--insecure-cluster" in text and "tcp://" in text, text
    assert not out.exists()
    warning = check_cluster("tcp://127.0.0.1:9", None, insecure=True)
    assert "change every grade" in warning and "\n" not in warning


@pytest.mark.parametrize("verify", ["required", "none"])
def test_a_tls_server_that_lets_a_client_in_without_a_key_is_told(tmp_path, verify):
    """The try without a key: refused by a server that requires its authority's client
    certificates (as Dask's TLS does), let in by one that does not."""
    import socket
    import ssl
    import threading

    from doorlab.pset.classroom.cluster import accepts_anonymous, write_cluster_keys

    keys = write_cluster_keys(tmp_path / "keys", ["127.0.0.1"])
    context = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH, cafile=str(keys / "ca.pem"))
    context.load_cert_chain(keys / "scheduler.pem", keys / "scheduler.key")
    context.verify_mode = ssl.CERT_REQUIRED if verify == "required" else ssl.CERT_NONE
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]

    def serve() -> None:
        conn, _ = server.accept()
        try:
            with context.wrap_socket(conn, server_side=True) as tls:
                tls.sendall(b"hello")
                tls.recv(1)
        except (OSError, ssl.SSLError):
            pass

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        found = accepts_anonymous(f"tls://127.0.0.1:{port}", str(keys / "ca.pem"), timeout=10)
    finally:
        server.close()
        thread.join(10)
    assert found is (verify == "none")


def test_the_cluster_keys_are_the_course_s_own_and_private(tmp_path):
    """doorlab pset cluster-keys: an authority and a pair per role signed by it; the folder
    0700, every key 0600; a second write refused (nothing a user owns is replaced)."""
    import ssl
    import stat

    from doorlab.errors import OutputError
    from doorlab.pset.classroom.cluster import ROLES, write_cluster_keys

    keys = write_cluster_keys(tmp_path / "keys", ["127.0.0.1", "grader.example.edu"])
    assert stat.S_IMODE(keys.stat().st_mode) == 0o700
    for role in ROLES:
        assert stat.S_IMODE((keys / f"{role}.key").stat().st_mode) == 0o600
        context = ssl.create_default_context(cafile=str(keys / "ca.pem"))
        context.load_cert_chain(keys / f"{role}.pem", keys / f"{role}.key")  # a matching pair
    assert stat.S_IMODE((keys / "ca.key").stat().st_mode) == 0o600
    with pytest.raises(OutputError):
        write_cluster_keys(keys)


HOLD = {
    "memfd": """
import os
fd = os.memfd_create("hold")
for _ in range(64):
    os.write(fd, b"\\1" * (1 << 20))
""",
    "tmpfs": """
import sys
with open(sys.argv[1] + "/hold", "wb") as f:
    for _ in range(64):
        f.write(b"\\1" * (1 << 20))
""",
    "pipes": """
import fcntl, os
pipes = []
for _ in range(64):
    r, w = os.pipe()
    fcntl.fcntl(w, 1031, 1 << 20)  # F_SETPIPE_SZ
    os.set_blocking(w, False)
    try:
        while True:
            os.write(w, b"\\1" * 65536)
    except BlockingIOError:
        pipes.append((r, w))
""",
}
"""64 MiB held three ways, none of them a process's resident memory."""


@pytest.mark.parametrize("how", sorted(HOLD))
def test_what_a_process_holds_is_charged_to_its_group(tmp_path, how):
    """Issue 43: memfds, tmpfs files and pipe buffers count against the memory group of the
    process that fills them: 64 MiB of each in a 32-MiB group, the kernel ends the holder."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    from doorlab.pset.isolation import cgroups

    setup = cgroups.probe()
    if setup.version is None or os.geteuid() != 0:
        pytest.skip(f"needs root and writable cgroups ({setup.reason or 'not root'})")
    mount = tmp_path / "tmpfs"
    mount.mkdir()
    subprocess.run(["mount", "-t", "tmpfs", "-o", "size=128m", "tmpfs", str(mount)], check=True)
    base = cgroups.Group(setup, {k: Path(v) for k, v in setup.bases.items()})
    group = base.child(f"doorlab-test-hold-{os.getpid()}-{how}")
    try:
        group.set_memory(32 << 20)
        fds = group.join_descriptors()
        try:
            proc = subprocess.run(
                [sys.executable, "-I", "-S", "-c", HOLD[how], str(mount)],
                capture_output=True,
                timeout=60,
                pass_fds=fds,
                preexec_fn=lambda: cgroups.join_by_descriptors(fds),
            )
        finally:
            for fd in fds:
                os.close(fd)
        assert proc.returncode == -9, (proc.returncode, proc.stderr[-500:])
        assert group.oom_kills() >= 1
    finally:
        subprocess.run(["umount", "-l", str(mount)], check=False)
        group.remove()
