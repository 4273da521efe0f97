"""benchmarks/bench_remaining_life_stage.py: its synthetic hoses and its --quick run's report."""
import re

from benchmarks import bench_remaining_life_stage as bench


def test_the_synthetic_hoses_have_failed_and_running_ones_and_a_leak_path_each():
    t = bench.synthetic(4)
    life = t["hose_life"]
    assert len(life) == 8 and set(life["status"]) == {"failed", "running"}
    assert set(t["hose_leak_growth"]["hose_id"]) == set(life["hose_id"])
    assert set(t["leakage_map"]["run_id"]) == set(t["hose_leak_growth"]["run_id"])


def test_quick_prints_the_stage_and_its_parts_with_pass_or_miss(capsys):
    assert bench.main(["--quick"]) == 0
    out = capsys.readouterr().out
    assert "8 hoses" in out and "models + backtests (2 groups)" in out and "the whole stage" in out
    assert re.search(r"^stage cpu \d+\.\d\d s \(wall \d+\.\d\d s\) against 5 s: (PASS|MISS)$", out, re.M)
