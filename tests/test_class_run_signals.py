"""grade-all's record of a finished submission: its results file and its row in the sheet go
together, whatever Ctrl-C does (a results file without its row, left once by a Ctrl-C between
the two, is a submission --resume does not know; tests/test_pset_batch.py's Ctrl-C test met it
once in six whole runs of the suite)."""

from __future__ import annotations

import os
import signal
from types import SimpleNamespace

import pytest

from doorlab.pset.classroom import class_run


class _Ledger:
    def released(self, submission, outcome):
        return []

    def finish(self, submission, results):
        return results


def test_a_ctrl_c_between_the_results_file_and_the_row_comes_after_the_row(tmp_path, monkeypatch):
    run = object.__new__(class_run._ClassRun)  # only what done() reads
    run.out, run.ledger, run.bar, run.deferred = tmp_path, _Ledger(), None, True
    run.rows, run.results, run.errors, run.graded = {}, {}, {}, []

    def commit(out, submission_id, results):  # the file written, then the terminal's Ctrl-C
        (out / submission_id).mkdir()
        (out / submission_id / "results.json").write_text("{}")
        os.kill(os.getpid(), signal.SIGINT)

    monkeypatch.setattr(class_run, "_commit", commit)
    monkeypatch.setattr(class_run, "sheet_row", lambda s, r, error=None: {"submission": s.id})
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)  # as in the command
    try:
        with pytest.raises(KeyboardInterrupt):
            run.done(SimpleNamespace(id="submission_123"), {"results": {"score": 14}})
    finally:
        signal.signal(signal.SIGINT, previous)
    assert (tmp_path / "submission_123" / "results.json").is_file()
    assert run.rows == {"submission_123": {"submission": "submission_123"}}
    assert run.graded == ["submission_123"]
