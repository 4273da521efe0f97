"""benchmarks/bench_memory.py: the line through the sizes (hand-checked) and one whole rebuild
sampled as a process tree."""
from __future__ import annotations

import math

import pytest

from benchmarks import bench_memory as bm
from tests.conftest import STEP_META


def test_the_slope_is_the_least_squares_line_through_the_peaks():
    peaks = [bm.Peak(1000, 0, 0, tree_pss_mb=500.0), bm.Peak(3000, 0, 0, tree_pss_mb=900.0),
             bm.Peak(10_000, 0, 0, tree_pss_mb=2300.0)]  # on the line 300 MB + 0.2 MB per run
    k, c = bm.slope(peaks)
    assert k == pytest.approx(0.2) and c == pytest.approx(300.0)
    assert all(math.isnan(v) for v in bm.slope(peaks[:1]))  # one size: no line


def test_a_rebuild_is_sampled_as_a_process_tree_and_its_warehouse_made_fresh(raw, tmp_path):
    for i in range(3):
        t = [0.05 * k for k in range(200)]
        raw.csv(f"c/s{i}.csv", {**STEP_META, "operator": f"op{i}"},
                {"t[s]": t, "x[mm]": [min(20.0, 0.3 * k) for k in range(200)], "x_ref[mm]": [20.0] * 200})
    wh = tmp_path / "wh"
    (wh / "stale").mkdir(parents=True)  # a warehouse left by an earlier run is removed first
    p = bm.rebuild_peak(raw.root, wh, 3, interval_s=0.01)
    assert p.exit_code == 0 and p.runs == 3 and not (wh / "stale").exists()
    assert 20 < p.main_pss_mb <= p.main_peak_mb and p.tree_pss_mb == pytest.approx(p.main_pss_mb + p.workers_pss_mb)
    assert p.n_processes >= 1 and p.wall_s > 0
