"""Issue 26's per-kind table and cost-curve plot, rendered from hand-made bench_scale JSON files."""
import json

import pytest

from benchmarks import bench_scale as bs
from benchmarks import scale_kinds as sk


def _per_kind(runs, full_cpu, kinds, load=None):
    """A --per-kind file as bench_scale writes it: [wall s, CPU s] per round, the after version."""
    doc = {"runs": runs, "ref": "none", "after": "HEAD",
           "times": {"after": {"full": [[full_cpu * 1.5, full_cpu]], **kinds}}}
    if load:
        doc["load"] = load
    return doc


K1000 = _per_kind(1000, 60.0, {"spring": [[8.0, 6.0], [9.0, 7.0]], "leakage": [[8.6, 7.2]],
                               "plan.toml": [[6.0, 2.4]]}, load="5.0-6.0")
K10000 = _per_kind(10000, 800.0, {"spring": [[30.0, 24.0]], "leakage": [[20.0, 12.0]], "durability": [[9.0, 8.0]]})


def test_a_per_kind_file_gives_each_kinds_median_cpu_share_of_its_own_full_rebuild():
    sizes = sk.sizes_from([("k1000", K1000), ("k10000", K10000)])
    assert list(sizes) == [1000, 10000]
    s = sizes[1000]
    assert s["full_cpu_s"] == 60.0 and s["load"] == ["5.0-6.0"] and s["sources"] == ["k1000"]
    assert s["kinds"]["spring"] == (6.5, pytest.approx(6.5 / 60))  # median of the two rounds
    assert s["kinds"]["plan.toml"] == (2.4, pytest.approx(0.04))
    assert sk.worst(s) == ("leakage", pytest.approx(0.12)) and sk.worst(sizes[10000]) == ("spring", 0.03)


def test_a_later_file_of_the_same_size_wins_for_its_kinds_and_cost_curve_files_are_read_too():
    again = _per_kind(1000, 50.0, {"leakage": [[3.0, 2.0]]})
    curve_json = {"results": [{"runs": 3000, "full_cpu_s": 200.0, "per_kind": {"step": [5.0, 4.0]}},
                              {"runs": 300, "full_s": 10.0}]}  # measured before the per-kind figures: left out
    sizes = sk.sizes_from([("a", K1000), ("b", again), ("c", curve_json)])
    assert list(sizes) == [1000, 3000]
    assert sizes[1000]["kinds"]["leakage"] == (2.0, 0.04) and sizes[1000]["kinds"]["spring"][1] == pytest.approx(6.5 / 60)
    assert sizes[3000]["kinds"] == {"step": (4.0, 0.02)}
    with pytest.raises(ValueError, match="neither"):
        sk.sizes_from([("x", {"runs": 3})])
    with pytest.raises(ValueError, match="no full rebuild"):
        sk.sizes_from([("x", {"runs": 3, "times": {"after": {"spring": [[1.0, 1.0]]}}})])


def test_the_issue_table_has_the_issues_before_and_each_sizes_share_with_pass_or_miss_against_its_target():
    lines, checks = sk.issue_table(sk.sizes_from([("k1000", K1000), ("k10000", K10000)]))
    assert lines[0] == ("| change | before: issue 26, 1,000 runs (wall share) | after, 1,000 runs: CPU share (CPU s), "
                        "target 5% | after, 10,000 runs: CPU share (CPU s), target 2% |")
    assert "| full rebuild, CPU s | (52-56 s wall) | 60.0 | 800.0 |" in lines
    assert "| spring | 0.280 | 0.1083 (6.5) MISS | 0.0300 (24.0) MISS |" in lines
    assert "| leakage | 0.130 | 0.1200 (7.2) MISS | 0.0150 (12.0) PASS |" in lines
    assert "| durability | 0.120 | not measured | 0.0100 (8.0) PASS |" in lines
    assert "| plan.toml | - | 0.0400 (2.4) PASS | not measured |" in lines
    assert "| pressure step | 0.250 | not measured | not measured |" in lines  # the issue's name, not the key
    assert lines[-1] == "| **worst kind** | **spring 0.280** | **leakage 0.1200 MISS** | **spring 0.0300 MISS** |"
    assert [(round(v, 3), ok) for _, v, ok in checks] == [(0.12, False), (0.03, False)]
    assert checks[1][0] == "worst kind (spring) under 2% of a full rebuild at 10,000 runs (CPU; 3 kinds measured)"


def test_every_kind_under_its_target_passes_and_the_no_op_is_never_the_worst_kind():
    quiet = _per_kind(10000, 1000.0, {"spring": [[5.0, 19.0]], "no-op": [[30.0, 25.0]]})
    sizes = sk.sizes_from([("q", quiet)])
    lines, checks = sk.issue_table(sizes)
    assert "| spring | 0.280 | 0.0190 (19.0) PASS |" in lines and "| no-op | 0.009 | 0.0250 (25.0) MISS |" in lines
    assert [ok for _, _, ok in checks] == [True] and sk.worst(sizes[10000]) == ("spring", 0.019)


def test_the_curve_follows_the_worst_kind_at_the_largest_size_and_draws_the_targets():
    c = sk.curve(sk.sizes_from([("k1000", K1000), ("k10000", K10000)]))
    assert c["runs"] == [1000, 10000] and c["worst_kind"] == "spring"
    assert c["shares"]["spring"] == [pytest.approx(6.5 / 60), 0.03]
    assert c["shares"]["durability"] == [None, 0.01] and c["shares"]["plan.toml"] == [0.04, None]
    assert c["worst_share"] == [pytest.approx(0.12), 0.03]  # leakage at 1,000, spring at 10,000
    assert (c["target_runs"][0], c["target_runs"][-1]) == (300, 10000)
    assert (c["target"][0], c["target"][-1]) == (0.05, 0.02)
    assert c["target"] == sorted(c["target"], reverse=True)  # 5 % to 1,000 runs, falling to 2 % at 10,000


def test_render_prints_the_table_and_checks_and_draws_the_png_through_bench_scale(tmp_path, capsys):
    files = []
    for name, doc in (("k1000.json", K1000), ("k10000.json", K10000)):
        files += ["--render", str(tmp_path / name)]
        (tmp_path / name).write_text(json.dumps(doc))
    png = tmp_path / "scale.png"
    assert bs.main([*files, "--plot", str(png)]) == 1  # the worst kinds MISS
    out = capsys.readouterr().out
    assert "| **worst kind** | **spring 0.280** | **leakage 0.1200 MISS** | **spring 0.0300 MISS** |" in out
    assert "1,000 runs: load average 5.0-6.0" in out
    assert "MISS  worst kind (spring) under 2% of a full rebuild at 10,000 runs (CPU; 3 kinds measured): 0.030" in out
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000


def test_the_one_run_table_gives_each_versions_share_of_its_own_full_rebuild():
    times = {"before": {"full": [[100.0, 60.0]], "spring": [[8.0, 6.0], [9.0, 9.0]]},
             "after": {"full": [[90.0, 50.0]], "spring": [[7.0, 5.0], [7.0, 5.0]]}}
    lines = bs.per_kind_table(times)
    assert lines[3] == "| spring | 8.5 / 7.5 | 0.125 | 7.0 / 5.0 | 0.100 | 0.67 |"
    assert bs.per_kind_table({"after": times["after"]})[3] == "| spring | 7.0 / 5.0 | 0.100 |"
