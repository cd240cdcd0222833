"""The order of the suite's files (tests/file_order.py): every file once, the real-time ones
first, each group longest first."""

from __future__ import annotations

import file_order
from file_order import UNKNOWN_S


def test_the_real_time_files_come_first_then_the_others_each_longest_first():
    durations = {"a.py": 170.0, "b.py": 90.0, "rt1.py": 55.0, "rt2.py": 170.0}
    durations |= {f"s{i}.py": 20.0 + i for i in range(12)}
    order = file_order.file_order(durations, {"rt1.py", "rt2.py"}, durations)
    assert sorted(order) == sorted(durations)  # each file once
    assert order[:4] == ["rt2.py", "rt1.py", "a.py", "b.py"]
    others = order[2:]
    assert [durations[n] for n in others] == sorted((durations[n] for n in others), reverse=True)


def test_an_unrecorded_file_counts_its_default():
    durations = {"x.py": UNKNOWN_S + 1, "y.py": UNKNOWN_S - 1}
    order = file_order.file_order(["new.py", "rt.py", "x.py", "y.py"], {"rt.py"}, durations)
    assert order == ["rt.py", "x.py", "new.py", "y.py"]


def test_recorded_durations_round_trip(tmp_path):
    path = tmp_path / "durations.json"
    file_order.write_durations({"a.py": 1.234, "b.py": 9.87}, {"b.py": 12.34}, path)
    assert file_order.read_durations(path) == {"b.py": 9.9, "a.py": 1.2}
    assert list(file_order.read_durations(path)) == ["b.py", "a.py"]  # longest first
    assert file_order.read_cpu(path) == {"b.py": 12.3}
    path.write_text('{"old.py": 4.5}')  # a record from before the CPU was kept
    assert file_order.read_durations(path) == {"old.py": 4.5} and file_order.read_cpu(path) == {}
    path.write_text("not json")
    assert file_order.read_durations(path) == {} and file_order.read_cpu(path) == {}


def test_beside_the_real_time_files_those_that_keep_more_than_a_core_busy_come_first():
    durations = {"rt.py": 100.0, "a.py": 90.0, "b.py": 70.0, "p1.py": 60.0, "p2.py": 50.0}
    durations |= {"p3.py": 30.0, "c.py": 20.0, "empty.py": 0.0}
    # p1-p3 ran a process per core (1.2-1.4 CPU-s a second); a, b and c one process (0.9).
    cpu = {"a.py": 81.0, "b.py": 63.0, "p1.py": 84.0, "p2.py": 60.0, "p3.py": 36.0, "c.py": 18.0}
    cpu["empty.py"] = 0.0  # no time, no CPU: nothing to say it keeps a core busy
    order = file_order.file_order(durations, {"rt.py"}, durations, cpu)
    # p1 and p2 (110 s) cover the real-time file's 100 s; p3 waits its turn by its length.
    assert order == ["rt.py", "p1.py", "p2.py", "a.py", "b.py", "p3.py", "c.py", "empty.py"]
    # A real-time file that keeps its core busy (busy.py: 1.05 CPU-s a second) comes after
    # those that wait, and does not count in the time the others fill.
    durations["busy.py"], cpu["busy.py"], cpu["rt.py"] = 200.0, 210.0, 40.0
    order = file_order.file_order(durations, {"rt.py", "busy.py"}, durations, cpu)
    assert order[:5] == ["rt.py", "busy.py", "p1.py", "p2.py", "a.py"]
    del durations["busy.py"]
    # Without the CPU, or without a real-time file, it is longest first.
    assert file_order.file_order(durations, {"rt.py"}, durations) == [
        "rt.py", "a.py", "b.py", "p1.py", "p2.py", "p3.py", "c.py", "empty.py"
    ]  # fmt: skip
    assert file_order.file_order(durations, set(), durations, cpu)[:3] == ["rt.py", "a.py", "b.py"]


def test_the_real_time_files_are_dealt_into_a_bin_per_worker_longest_first():
    durations = {"a.py": 70.0, "b.py": 44.0, "c.py": 25.0, "d.py": 7.0}
    bins = file_order.realtime_bins(durations, durations, workers=2)
    assert bins == {
        "a.py": "realtime-2",
        "b.py": "realtime-1",
        "c.py": "realtime-1",
        "d.py": "realtime-1",
    }
    # b + c + d = 76 s against a's 70: the fuller bin first. One worker: one bin.
    assert set(file_order.realtime_bins(durations, durations, workers=1).values()) == {"realtime-1"}
    three = file_order.realtime_bins(durations, durations, workers=3)
    assert three["a.py"] == "realtime-1" and three["c.py"] == three["d.py"] != three["b.py"]
    assert file_order.realtime_bins([], durations, workers=2) == {}
