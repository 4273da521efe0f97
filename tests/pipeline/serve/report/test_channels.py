"""The channels of a run as SVG: every excursion kept, round ticks, h:mm:ss past an hour, the
analyses' events marked and bounded."""
import re


def test_downsampling_keeps_every_excursion_of_a_long_run(tmp_path):
    import numpy as np
    import pyarrow as pa
    import pyarrow.parquet as pq

    from pipeline.serve.report import channels as rp

    n = 250_000
    t = np.arange(n) / 1000.0
    x = np.sin(t)
    x[123_457] = 5.0   # one-sample spike
    x[200_001] = -7.0
    f = tmp_path / "s.parquet"
    pq.write_table(pa.table({"t_s": t, "x_m": x}), f, row_group_size=40_000)
    old = rp.BATCH_ROWS
    rp.BATCH_ROWS = 30_000  # batches that do not line up with the pixel columns
    try:
        b = rp.downsample_minmax(f, ["x_m", "missing"], n, width=500)
    finally:
        rp.BATCH_ROWS = old
    lo, hi = b["x_m"]
    assert lo.size == 500 and "missing" not in b
    assert np.nanmax(hi) == 5.0 and np.nanmin(lo) == -7.0
    assert hi[123_457 * 500 // n] == 5.0 and lo[200_001 * 500 // n] == -7.0
    assert b["t_s"] == (0.0, t[-1])
    svg = rp.channels_svg(b, "t")
    assert svg.startswith("<svg") and "x [mm]" in svg and "5000" in svg and "-7000" in svg


def test_a_long_runs_time_axis_reads_h_mm_ss_and_a_breakaway_onset_is_marked(tmp_path):
    import numpy as np
    import pyarrow as pa
    import pyarrow.parquet as pq

    from pipeline.serve.report import channels as rp

    n = 11_251  # an hour-long durability record at 1 Hz, to 3:07:30
    t = np.arange(n, dtype=float)
    f = tmp_path / "s.parquet"
    pq.write_table(pa.table({"t_s": t, "p_a_pa": 2e5 + 3e4 * np.sin(t / 7), "x_m": 0.1 + 0.5 * np.sin(t / 5)}), f)
    svg = rp.channels_svg(rp.downsample_minmax(f, ["p_a_pa", "x_m"], n), "long")
    texts = re.findall(r"<text[^>]*>([^<]*)</text>", svg)
    assert "t [h:mm:ss]" in texts and {"0:00:00", "1:00:00", "2:00:00", "3:00:00"} <= set(texts)
    assert not any("e+" in x for x in texts)
    assert {"1.8", "2.0", "2.2"} <= set(texts) and {"-250", "0", "250", "500"} <= set(texts)  # bar, mm
    # a short run stays in seconds; a breakaway onset (and nothing of other tables) is drawn with a legend
    res = [("breakaway", ["run_id", "direction", "onset_t_s"], ("r", "P", 12.5)),
           ("breakaway_findings", ["run_id", "onset_t_s"], ("r", 3.0)),
           ("step_response", ["run_id", "t_step_s"], ("r", float("nan")))]
    ev = rp.run_events(res)
    assert ev == [("onset", 12.5, None, "breakaway onset P")]
    bands = {"t_s": (0.0, 40.0), "x_m": (np.linspace(0, 0.01, 100), np.linspace(0, 0.01, 100))}
    svg = rp.channels_svg(bands, "brk", ev)
    texts = re.findall(r"<text[^>]*>([^<]*)</text>", svg)
    assert "breakaway onset (1)" in texts and "t [s]" in texts and {"0", "10", "20", "30", "40"} <= set(texts)
    x_onset = 70 + 12.5 / 40 * rp.WIDTH
    assert f'x1="{x_onset:.1f}"' in svg and "<title>breakaway onset P: 12.5 s</title>" in svg


def test_a_run_with_thousands_of_events_draws_a_bounded_page():
    import numpy as np

    from pipeline.serve.report import channels as rp

    n = 5 * rp.MAX_EVENTS
    res = [("viscous_points", ["run_id", "pass_index", "t_start_s", "t_end_s"], ("r", i, i + 0.2, i + 0.7))
           for i in range(n)] + [("viscous_points", ["run_id", "t_start_s", "t_end_s"], ("r", None, 3.0))]
    ev = rp.run_events(res)
    assert len(ev) == n  # a pass without a start is not drawn
    bands = {"t_s": (0.0, float(n)), "x_m": (np.zeros(rp.WIDTH), np.ones(rp.WIDTH)),
             "p_a_pa": (np.zeros(rp.WIDTH), np.ones(rp.WIDTH))}
    svg = rp.channels_svg(bands, "many", ev)
    assert svg.count("<title>constant-velocity pass") == 2 * rp.MAX_EVENTS
    assert f"constant-velocity pass ({rp.MAX_EVENTS})" in svg
    assert f"(first {rp.MAX_EVENTS} drawn, {n - rp.MAX_EVENTS} more in the tables)" in svg
    assert len(svg) < 300_000


def test_pixel_columns_begin_where_every_row_says_they_do():
    """``bin_starts`` against the per-row rule ``min(r * width // n_rows, width - 1)``: batches that
    do not line up with the columns, a batch inside one column, more rows than ``n_rows`` says."""
    import numpy as np

    from pipeline.serve.report.channels import bin_starts

    for start, n, n_rows, width in [(0, 1000, 1000, 880), (0, 1_000_000, 3_400_000, 880), (1_000_000, 1_000_000,
                                    3_400_000, 880), (3_000_000, 400_000, 3_400_000, 880), (7, 3, 997, 10),
                                    (5, 1, 997, 10), (900, 300, 1000, 7), (1200, 50, 1000, 7), (0, 13, 13, 13)]:
        bins = np.minimum(np.arange(start, start + n, dtype=np.int64) * width // n_rows, width - 1)
        idx = np.concatenate(([0], np.flatnonzero(np.diff(bins)) + 1))
        got_idx, got_cols = bin_starts(start, n, n_rows, width)
        assert got_idx.tolist() == idx.tolist() and got_cols.tolist() == bins[idx].tolist(), (start, n, n_rows, width)


def test_infinite_and_missing_samples_are_no_samples_of_their_pixel_column(tmp_path):
    import numpy as np
    import pyarrow as pa
    import pyarrow.parquet as pq

    from pipeline.serve.report import channels as rp

    x = np.linspace(0.0, 1.0, 100)
    x[10] = np.inf      # column 1 (10 rows each): its other samples stay
    x[20:30] = np.nan   # column 2: no sample at all -> NaN
    x[35] = -np.inf
    y = np.linspace(5.0, 6.0, 100)  # finite throughout
    f = tmp_path / "s.parquet"
    pq.write_table(pa.table({"t_s": np.arange(100.0), "x_m": x, "y_m": y}), f)
    b = rp.downsample_minmax(f, ["x_m", "y_m"], 100, width=10)
    lo, hi = b["x_m"]
    assert hi[1] == x[19] and lo[1] == x[11] and np.isnan(lo[2]) and np.isnan(hi[2])
    assert lo[3] == x[30] and hi[3] == x[39]
    assert b["y_m"][0].tolist() == y[::10].tolist() and b["y_m"][1].tolist() == y[9::10].tolist()


def test_ticks_are_matplotlibs_maxnlocator_ticks_computed_without_importing_it():
    """The run pages' ticks are MaxNLocator's, float for float (over awkward ranges: tiny, huge, far
    from zero, empty, reversed, not finite), and drawing them imports no matplotlib."""
    import math
    import random

    from matplotlib.ticker import MaxNLocator

    from tests.fresh import loaded_after

    from pipeline.serve.report.channels import TICK_STEPS, max_n_ticks

    rng = random.Random(26)
    ranges = [(0.0, 1.0), (0.0, 0.0), (5.0, 5.0), (3.0, -2.0), (1e5, 1e5 + 1e-7), (28800.0, 28800.5),
              (-1e-300, 1e-300), (0.0, math.inf), (math.nan, 1.0), (-0.004, 0.021), (1e12, 1e12 + 3)]
    for _ in range(3000):
        e = rng.uniform(-12, 12)
        a = rng.uniform(-1, 1) * 10 ** e
        ranges.append((a, a + abs(rng.gauss(0, 1)) * 10 ** (e + rng.uniform(-10, 2))))
    for a, b in ranges:
        for n in (4, 8):
            want = MaxNLocator(nbins=n, steps=list(TICK_STEPS)).tick_values(a, b).tolist()
            assert max_n_ticks(a, b, n).tolist() == want, (a, b, n)
    code = "from pipeline.serve.report import channels as c; c.time_ticks(0.0, 7.3); c.value_ticks(-0.004, 0.021)"
    assert loaded_after(code, ("matplotlib",)) == []
