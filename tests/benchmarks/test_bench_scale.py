"""The cost curve's per-kind figures (issue 26): the target per size and the table and checks."""
import pytest

from benchmarks import bench_scale as bs


def test_the_target_is_5_percent_at_1000_runs_and_2_percent_at_10000():
    assert bs.kind_target(300) == bs.kind_target(1000) == 0.05
    assert bs.kind_target(10000) == bs.kind_target(30000) == 0.02
    assert bs.kind_target(3000) == pytest.approx(0.05 - 0.03 * 0.47712, rel=1e-4)  # log-interpolated


def test_the_worst_kind_is_judged_by_its_cpu_share_of_its_own_sizes_full_rebuild():
    results = [
        {"runs": 1000, "full_cpu_s": 80.0, "per_kind": {"spring": [9.0, 4.0], "leakage": [5.0, 3.0]},
         "worst_kind": "spring", "worst_kind_cpu_s": 4.0},
        {"runs": 10000, "full_cpu_s": 800.0, "per_kind": {"spring": [30.0, 20.0]},
         "worst_kind": "spring", "worst_kind_cpu_s": 20.0},
        {"runs": 3000},  # measured before the per-kind figures: left out
    ]
    lines, checks = bs.kind_lines(results)
    assert lines[0] == "| change: CPU share of full (CPU s) | 1,000 runs | 10,000 runs |"
    assert "| spring | 0.050 (4.0) | 0.025 (20.0) |" in lines and "| leakage | 0.037 (3.0) | - |" in lines
    assert [(round(v, 3), ok) for _, v, ok in checks] == [(0.05, False), (0.025, False)]
    assert "worst kind (spring) under 5% of a full rebuild at 1000 runs" in checks[0][0]
    assert bs.kind_lines([{"runs": 30}]) == ([], [])


def test_a_campaign_without_a_plan_gets_the_simulators_and_its_plan_change_is_measured(tmp_path):
    import time

    from pipeline.raw.plan import read_plan
    from pipeline.raw.tree import RawTree

    raw = tmp_path / "raw"
    raw.mkdir()
    assert bs.ensure_plan(raw) is True
    plan = read_plan(RawTree(raw))
    assert plan.present and plan.problems == () and plan.for_hose_type("FLEXIGOM AIR").margin == 1.5
    assert time.time() - (raw / "plan.toml").stat().st_mtime > 3000  # aged: not hashed as a racy file
    (raw / "plan.toml").write_text("[defaults]\nmargin = 1.3\n")
    assert bs.ensure_plan(raw) is False and (raw / "plan.toml").read_text() == "[defaults]\nmargin = 1.3\n"
    old = bs.bump_plan(raw / "plan.toml", 2)
    assert old == b"[defaults]\nmargin = 1.3\n" and (raw / "plan.toml").read_text() == "[defaults]\nmargin = 1.32\n"


@pytest.mark.parametrize("keep_mtime", [True, False])
def test_a_copy_has_new_inodes_and_its_mtimes_kept_or_aged(tmp_path, keep_mtime):
    import os
    import time

    src = tmp_path / "src"
    (src / "c").mkdir(parents=True)
    (src / "c" / "a.csv").write_text("t[s]\n0\n")
    os.utime(src / "c" / "a.csv", (1_000_000_000, 1_000_000_000))
    bs.copy_tree(src, tmp_path / "dst", keep_mtime)
    a, b = (src / "c" / "a.csv").stat(), (tmp_path / "dst" / "c" / "a.csv").stat()
    assert b.st_ino != a.st_ino and (tmp_path / "dst" / "c" / "a.csv").read_text() == "t[s]\n0\n"
    assert (b.st_mtime == a.st_mtime) if keep_mtime else (3000 < time.time() - b.st_mtime < 4000)


def test_what_a_rebuild_did_is_read_from_its_last_line():
    class M:
        stderr = ""

        def __init__(self, out):
            self.stdout = out

    assert bs._rebuilt(M("x\nrebuild: 3 runs (0 new, ..., 3 unchanged: a no-op), 0 quarantined, stages run: none, "
                         "0.9 s\n")) == "no-op"
    assert bs._rebuilt(M("rebuild: 3 runs (...), 0 quarantined, stages run: models, durability, 12.0 s")) == \
        "stages run: models, durability"
    assert bs._rebuilt(M("")) == "stages run: ?"
