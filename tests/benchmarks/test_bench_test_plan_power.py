"""benchmarks/bench_test_plan_power.py: the test_plan stage after a power change, timed in a child process, with its
maps' items computed / from the memo and the table through the memo equal to a cold one."""
from benchmarks import bench_test_plan_power as bench


def test_a_child_measures_the_stage_after_a_power_change_through_the_memo(tmp_path):
    raw, wh = tmp_path / "raw", tmp_path / "wh"
    raw.mkdir()
    wh.mkdir()
    bench.write_campaign(raw, 3, 5)
    assert "power = {power}" in (raw / "plan.toml.in").read_text()
    assert bench.run_child(None, raw, wh, "fill") == {}
    res = bench.run_child(None, raw, wh, "measure", check=True)
    assert res["cold_equal"] is True
    assert res["rows"] >= 3 and res["cpu_s"] > 0
    maps = res["maps"]
    # the 0.9 designs come from the memo of the fill at 0.8; the new power's designs are computed
    assert maps["test plan designs"][1] >= 3 and maps["test plan designs"][0] >= 1
    assert set(maps) >= {"test plan: boundaries", "test plan: power_now", "test plan"}
    again = bench.run_child(None, raw, wh, "measure")      # a copy each time: the same items computed again
    assert again["maps"] == maps and again["digest"] == res["digest"]


def test_shared_counts_what_the_decision_stage_computed_in_the_same_rebuild(tmp_path):
    raw, wh = tmp_path / "raw", tmp_path / "wh"
    raw.mkdir()
    wh.mkdir()
    bench.write_campaign(raw, 3, 5)
    bench.run_child(None, raw, wh, "fill")
    plain = bench.run_child(None, raw, wh, "measure")
    res = bench.run_child(None, raw, wh, "measure", shared=True)
    assert "shared" not in plain and res["digest"] == plain["digest"]   # counting changes nothing computed
    s = res["shared"]
    # every test_plan design computed is counted, and those the decision computed too give the same result
    assert s["designs"] == res["maps"]["test plan designs"][0]
    assert 0 <= s["designs_shared"] <= min(s["designs"], s["decision_designs"])
    assert s["bit_identical"] is True
    assert s["boundaries"] == res["maps"]["test plan: boundaries"][0]
    assert s["boundaries_shared"] <= s["boundaries"] and s["above"] <= s["boundaries"]
    assert s["above_read"] <= s["above_looks"]
    assert 0 <= s["designs_shared_cpu"] <= s["designs_cpu"] and 0 <= s["above_cpu"] <= s["boundaries_cpu"]
    assert "bit-identical: True" in bench.shared_line(s)
