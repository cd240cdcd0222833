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
    file_order.write_durations({"a.py": 1.234, "b.py": 9.87}, path)
    assert file_order.read_durations(path) == {"b.py": 9.9, "a.py": 1.2}
    assert list(file_order.read_durations(path)) == ["b.py", "a.py"]  # longest first
    path.write_text("not json")
    assert file_order.read_durations(path) == {}


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
