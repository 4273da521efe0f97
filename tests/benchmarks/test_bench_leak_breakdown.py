"""bench_leak_breakdown's edit: 90 different files from one run file, the old bytes given back; its timers
count calls and keep what the wrapped function returns."""
from benchmarks.bench_leak_breakdown import _timer, fresh_edit

CSV = b"# kind: leakage\nt[s],p_supply[bar],q_leak[l/min]\n0,0.00597,0.002\n20.95,5.99948,-0.009\n"


def test_fresh_edit_gives_90_distinct_files_and_returns_the_old_bytes(tmp_path):
    path = tmp_path / "check.csv"
    seen = set()
    for n in range(90):
        path.write_bytes(CSV)
        assert fresh_edit(path, n) == CSV
        new = path.read_bytes()
        assert new != CSV and len(new) == len(CSV) and new.rsplit(b"\n", 2)[0] == CSV.rsplit(b"\n", 2)[0]  # last line only
        seen.add(new)
    assert len(seen) == 90


def test_a_timer_counts_calls_and_returns_the_result():
    acc = {}
    twice = _timer(acc, "twice", lambda x: 2 * x)
    assert twice(3) == 6 and twice(4) == 8
    assert acc["twice"][1] == 2 and acc["twice"][0] >= 0.0
