"""The order of the suite's files (tests/file_order.py): every file once, the long ones first,
the real-time ones once only short files are left, with TAIL_S of them after."""

from __future__ import annotations

import file_order
from file_order import TAIL_S, UNKNOWN_S


def test_the_real_time_files_come_after_the_long_ones_with_short_work_left_after_them():
    durations = {"a.py": 170.0, "b.py": 90.0, "rt1.py": 170.0, "rt2.py": 55.0}
    durations |= {f"s{i}.py": 20.0 for i in range(12)}  # 240 s of short files
    order = file_order.file_order(durations, {"rt1.py", "rt2.py"}, durations)
    assert sorted(order) == sorted(durations)  # each file once
    first_rt = order.index("rt1.py")
    assert order[:2] == ["a.py", "b.py"] and order[first_rt + 1] == "rt2.py"
    after = [durations[n] for n in order[first_rt + 2 :]]
    assert TAIL_S <= sum(after) < TAIL_S + 20.0  # the fewest short files that reach TAIL_S
    others = [n for n in order if not n.startswith("rt")]
    assert [durations[n] for n in others] == sorted((durations[n] for n in others), reverse=True)


def test_an_unrecorded_file_counts_its_default_and_too_little_work_puts_real_time_first():
    order = file_order.file_order(["new.py", "rt.py", "x.py"], {"rt.py"}, {"x.py": UNKNOWN_S + 1})
    assert order == ["rt.py", "x.py", "new.py"]  # 21 s of others: below TAIL_S, all after


def test_recorded_durations_round_trip(tmp_path):
    path = tmp_path / "durations.json"
    file_order.write_durations({"a.py": 1.234, "b.py": 9.87}, path)
    assert file_order.read_durations(path) == {"b.py": 9.9, "a.py": 1.2}
    assert list(file_order.read_durations(path)) == ["b.py", "a.py"]  # longest first
    path.write_text("not json")
    assert file_order.read_durations(path) == {}
