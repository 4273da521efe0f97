"""benchmarks/decision_probe.py: a rebuild run with the probe tells its stages' parts and its maps' memo hits."""
import subprocess

from benchmarks import bench_decision_stage as bench
from benchmarks import decision_probe as probe


def _rebuild(raw, wh):
    cmd = bench.rebuild_cmd(raw, wh, bench.NOT_COMPARED)
    assert cmd[2].startswith(probe.PROBE)
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]
    return probe.parse(res.stdout + res.stderr)


def test_a_probed_rebuild_tells_each_maps_hits_and_each_stages_parts(tmp_path):
    raw, wh = tmp_path / "raw", tmp_path / "wh"
    bench.campaign(3, 5, raw, (8, 8), varied=True, odometer_only=True)
    (raw / "plan.toml").write_text(bench.SYNTH_PLAN.format(power=0.8))
    first = _rebuild(raw, wh)
    assert not first.get("unprobed")
    maps = {(m["stage"], m["label"]): m for m in first["maps"]}
    looks = maps["decision", "decision: looks"]
    assert looks["items"] == 3 and looks["hits"] == 0 and looks["computed"] == 3
    assert {"run", "memo save", "total"} <= set(first["stages"]["test_plan"])
    parts = probe.stage_parts(first, "decision")
    assert parts["total"][0] >= parts["run"][0] > 0 and parts["total"][1] >= parts["run"][1] >= 0
    assert {"stages", "assemble", "publish"} <= set(first["phases"])
    assert 1 <= first["report"]["looks drawn"] <= 3      # the looks figures, SVG drawn in the rebuild (session 28)
    assert "looks figures: " in "\n".join(probe.lines(first))
    (raw / "plan.toml").write_text(bench.SYNTH_PLAN.format(power=0.8))
    again = _rebuild(raw, wh)                      # nothing changed: neither stage runs, no map
    assert "decision" not in again["stages"] and not [m for m in again["maps"] if m["stage"] == "decision"]
    (raw / "plan.toml").write_text(bench.SYNTH_PLAN.format(power=0.81))
    moved = _rebuild(raw, wh)                      # a power change: the looks' parts from the memo
    maps = {(m["stage"], m["label"]): m for m in moved["maps"]}
    assert maps["decision", "decision: parts"]["hits"] == 3
    text = "\n".join(probe.lines(moved))
    assert "decision: parts" in text and "3 from the memo" in text and "test_plan: memo save" in text


def test_parse_reads_the_last_probe_line_and_none_without_one():
    assert probe.parse("stage x ran\n") is None
    assert probe.parse('bench-probe {"maps": [], "a": 1}\nbench-probe {"maps": [], "a": 2}\n')["a"] == 2
    assert probe.lines(None) == ["(no probe record)"]
