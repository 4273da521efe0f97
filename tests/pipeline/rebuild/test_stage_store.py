"""A stage's folder written and read back: tables (those without rows kept as dtypes), figures
drawn beside the rebuild (FigureDrawer) and placed only when complete, an existing folder reused."""
import pytest

import pipeline.rebuild.stage_runner as runner
import pipeline.rebuild.stage_store as store
from pipeline.rebuild.flow import rebuild
from pipeline.rebuild.options import RebuildError
from tests.conftest import STEP_META, query

T = [0.0, 0.1, 0.2, 0.3]


def test_a_stage_table_without_rows_is_kept_as_dtypes_and_loads_as_its_parquet_file_would(tmp_path, monkeypatch):
    """A table without rows is stored as its columns' dtypes in ``output.json`` (no Parquet file to
    write and read back: a stage with nothing to do costs milliseconds), and loads exactly as the
    Parquet file would have; a dtype its name does not rebuild exactly still goes to Parquet."""
    import json

    import pandas as pd
    import pyarrow as pa
    import pyarrow.parquet as pq

    from pipeline.stages import StageOutput

    empty = pd.DataFrame({
        "run_id": pd.Series([], dtype="str"), "x": pd.Series([], dtype="float64"), "n": pd.Series([], dtype="Int64"),
        "k": pd.Series([], dtype="int64"), "ok": pd.Series([], dtype="boolean"), "flag": pd.Series([], dtype="bool"),
        "note": pd.Series([], dtype="string"), "anything": pd.Series([], dtype=object),
        "at": pd.Series([], dtype="datetime64[ns, UTC]"), "naive": pd.Series([], dtype="datetime64[s]"),
        "cat": pd.Series([], dtype=pd.CategoricalDtype(["a", "b"]))})
    full = pd.DataFrame({"run_id": ["a"], "x": [1.5]})

    def saved_and_loaded(out: StageOutput, key: str):
        rel, cacheable, now_in = store.save_stage_folder(tmp_path, "demo", key, out)
        assert now_in == tmp_path / rel  # no figure to draw: in place at once
        assert cacheable
        folder = tmp_path / rel
        tables, *_ = store.load_stage_folder(tmp_path, rel, "demo")
        for name, df in out.tables.items():  # what the Parquet file would give
            pq.write_table(pa.Table.from_pandas(df, preserve_index=False), tmp_path / f"{name}.parquet")
            pd.testing.assert_frame_equal(tables[name], pd.read_parquet(tmp_path / f"{name}.parquet"),
                                          check_index_type=True)
        return sorted(p.name for p in (folder / "tables").iterdir()), json.loads((folder / "output.json").read_text())

    files, meta = saved_and_loaded(StageOutput(tables={"empty": empty, "full": full}), "0" * 20)
    assert files == ["full.parquet"] and list(meta["empty"]) == ["empty"]
    assert dict(meta["empty"]["empty"])["naive"] == "datetime64[ms]"  # Parquet's unit, not the frame's
    real = store._empty_frame
    monkeypatch.setattr(store, "_empty_frame", lambda cols: real(cols).astype({"x": "float32"}) if
                        "x" in dict(cols) else real(cols))  # a name that does not rebuild its dtype
    files, meta = saved_and_loaded(StageOutput(tables={"empty": empty, "full": full}), "1" * 20)
    assert files == ["empty.parquet", "full.parquet"] and meta["empty"] == {}


def test_every_stage_loads_the_same_tables_with_or_without_empty_tables_kept_as_dtypes(raw, tmp_path, monkeypatch):
    """The whole rebuild: every stage's tables (most of them empty on a small tree) load equal to
    what the Parquet files gave before tables without rows were kept as dtypes."""
    import pandas as pd


    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[mm]": [0, 1, 2, 3], "x_ref[mm]": [3] * 4})
    loaded: dict[str, dict] = {}
    real = runner.load_stage_folder

    def spy(warehouse, rel, stage, fresh=None, folder=None):
        got = real(warehouse, rel, stage, fresh, folder)
        loaded.setdefault(warehouse.name, {})[stage] = got[0]
        return got

    monkeypatch.setattr(runner, "load_stage_folder", spy)
    rebuild(raw.root, tmp_path / "as-dtypes", jobs=1, report=False)
    monkeypatch.setattr(store, "_empty_columns", lambda arrow: None)  # every table as Parquet, as before
    rebuild(raw.root, tmp_path / "as-parquet", jobs=1, report=False)
    a, b = loaded["as-dtypes"], loaded["as-parquet"]
    assert sorted(a) == sorted(b) and sum(len(t) for t in a.values()) > 10
    n_empty = 0
    for stage in a:
        assert sorted(a[stage]) == sorted(b[stage])
        for name in a[stage]:
            pd.testing.assert_frame_equal(a[stage][name], b[stage][name], check_index_type=True)
            n_empty += a[stage][name].empty
    assert n_empty > 10


# -- figures drawn beside the rebuild (FigureDrawer) -----------------------------------------------
def tiny_plot(label: str, pid_file: str | None = None, fail: bool = False):
    """A module-level plot function for recipes: a small figure; notes the drawing process's pid."""
    import os

    from matplotlib.figure import Figure

    if fail:
        raise ValueError(f"cannot draw {label}")
    if pid_file:
        with open(pid_file, "a") as fh:
            fh.write(f"{os.getpid()}\n")
    fig = Figure(figsize=(2, 1.5))
    ax = fig.add_subplot()
    ax.plot([0, 1, 2], [0, 1, 4])
    ax.set_title(label)
    return fig


def _drawn(tmp_path, jobs, recipes, stage="demo"):
    """Draw ``recipes`` ({name: FigureRecipe}) with a FigureDrawer into a stage folder."""

    tmp, final = tmp_path / f".tmp-{stage}-{'0' * 20}-1", tmp_path / stage
    (tmp / "figures").mkdir(parents=True)
    with store.FigureDrawer(jobs) as drawer:
        for name, recipe in recipes.items():
            drawer.draw(stage, name, recipe, tmp / "figures" / f"{name}.png")
        drawer.publish(tmp, final)
        placed_before_finish = final.exists()
        drawer.finish()
    return placed_before_finish, final


def test_figures_drawn_in_a_worker_are_the_bytes_drawn_at_once_and_placed_only_when_done(tmp_path):
    import os

    from pipeline.stages import FigureRecipe

    pids = tmp_path / "pids.txt"
    recipes = {n: FigureRecipe(tiny_plot, (n, str(pids))) for n in ("a", "b")}
    early, aside = _drawn(tmp_path / "aside", 2, recipes)
    drawers = {int(p) for p in pids.read_text().split()}
    assert not early  # the folder is put in place by finish(), after its figures
    assert drawers and os.getpid() not in drawers  # drawn in the worker process
    pids.unlink()
    early, here = _drawn(tmp_path / "here", 1, recipes)
    assert not early and {int(p) for p in pids.read_text().split()} == {os.getpid()}  # --jobs 1: here
    for n in recipes:
        assert (aside / "figures" / f"{n}.png").read_bytes() == (here / "figures" / f"{n}.png").read_bytes()


def test_a_figure_that_fails_fails_the_rebuild_and_places_no_folder(tmp_path):
    from pipeline.stages import FigureRecipe

    for jobs in (1, 2):
        root = tmp_path / f"jobs{jobs}"
        recipes = {"ok": FigureRecipe(tiny_plot, ("ok",)), "bad": FigureRecipe(tiny_plot, ("bad",), {"fail": True})}
        with pytest.raises((RebuildError, ValueError), match="bad"):
            _drawn(root, jobs, recipes)
        assert not (root / "demo").exists()
        if jobs > 1:  # the worker's error names the stage and the figure; the temporary folder is gone
            assert not list(root.glob(".tmp-*"))


def test_a_stage_folder_that_exists_is_reused_without_drawing(tmp_path):
    import pandas as pd

    from pipeline.stages import StageOutput

    pids = tmp_path / "pids.txt"
    out = StageOutput(tables={"t": pd.DataFrame({"run_id": ["a"], "x": [1.0]})})
    out.draw("fig", tiny_plot, "fig", str(pids), caption="A figure.")
    with store.FigureDrawer(2) as drawer:
        rel, cacheable, now_in = store.save_stage_folder(tmp_path, "demo", "2" * 20, out, drawer)
        assert now_in != tmp_path / rel and not (tmp_path / rel).exists()  # being drawn
        drawer.finish()
    assert (tmp_path / rel / "figures" / "fig.png").is_file() and pids.read_text().count("\n") == 1
    _tables, figures, *_ = store.load_stage_folder(tmp_path, rel, "demo")
    assert figures == [{"stage": "demo", "name": "fig", "path": f"{rel}/figures/fig.png", "caption": "A figure."}]
    again = store.save_stage_folder(tmp_path, "demo", "2" * 20, out, store.FigureDrawer(2))
    assert again == (rel, True, tmp_path / rel) and pids.read_text().count("\n") == 1  # not drawn again


def test_a_rebuild_draws_the_same_figures_with_jobs_2_as_with_jobs_1(raw, tmp_path):
    from pipeline.simulator import simulate_durability

    sim = simulate_durability(hose_id="H1", distance_m=5.0, rng=1, stroke_m=0.1, dwell_s=0.05, fs_hz=200.0)
    cols = {"t[s]": sim.data["t_s"].tolist(), "x[mm]": (sim.data["x_m"] * 1e3).round(3).tolist(),
            "p_a[Pa]": sim.data["p_a_pa"].tolist(), "p_b[Pa]": sim.data["p_b_pa"].tolist()}
    raw.csv("c/d1.csv", {"kind": "durability", "rig": "plpa-1", "hose_id": "H1",
                         "started_at": "2026-01-02T08:00:00"}, cols)
    raw.write("c/hoses.csv", "hose_id,event,at,hose_type,adjustment,z_rollers_mm,spring_force_n,failure_mode,"
                             "wall_thickness_mm,distance_km,notes\nH1,installed,2026-01-01T00:00,FLEX,force,,866,,,,\n")
    figs = {}
    for jobs in (1, 2):
        wh = tmp_path / f"wh{jobs}"
        summary = rebuild(raw.root, wh, jobs=jobs, report=False)
        assert summary.exit_code == 0, summary.quarantine
        rows = query(wh, "SELECT stage, name, path FROM figures ORDER BY stage, name")
        figs[jobs] = {(s, n): (wh / p).read_bytes() for s, n, p in rows}
        assert not list((wh / "stages").glob(".tmp-*"))
    assert ("durability", "hose_distance") in figs[1]
    assert figs[2] == figs[1]


def test_a_re_run_stage_draws_only_the_figures_whose_inputs_changed(tmp_path):
    """Figures keyed by their own inputs: the next folder of a stage links the previous folder's
    figure with the same key (the bytes a new drawing gives) and draws only the changed one;
    without a previous folder (``--full``) every figure is drawn."""
    import pandas as pd

    from pipeline.stages import StageOutput

    pids = tmp_path / "pids.txt"

    def output(title_b):
        out = StageOutput(tables={"t": pd.DataFrame({"run_id": ["a"], "x": [1.0]})})
        out.draw("a", tiny_plot, "same", str(pids), caption="A.")
        out.draw("b", tiny_plot, title_b, str(pids), caption="B.")
        return out

    first, *_ = store.save_stage_folder(tmp_path, "demo", "1" * 20, output("before"))
    assert pids.read_text().count("\n") == 2
    second, *_ = store.save_stage_folder(tmp_path, "demo", "2" * 20, output("after"), previous=tmp_path / first)
    assert pids.read_text().count("\n") == 3  # only "b" drawn
    a1, a2 = (tmp_path / rel / "figures" / "a.png" for rel in (first, second))
    assert a2.read_bytes() == a1.read_bytes() and a2.stat().st_ino == a1.stat().st_ino  # linked
    full, *_ = store.save_stage_folder(tmp_path, "demo", "3" * 20, output("after"))  # no previous: all drawn
    assert pids.read_text().count("\n") == 5
    for name in ("a", "b"):  # a figure taken over has the bytes it would be drawn with
        assert (tmp_path / full / "figures" / f"{name}.png").read_bytes() == \
            (tmp_path / second / "figures" / f"{name}.png").read_bytes()
    _tables, figures, *_ = store.load_stage_folder(tmp_path, second, "demo")
    assert [f["caption"] for f in figures] == ["A.", "B."]


def pooled_sum(df, by):
    """A pooled table of the test (module-level: keyable); counts its calls."""
    pooled_sum.calls += 1
    return df.groupby(by, as_index=False)["x"].sum()


pooled_sum.calls = 0


def test_a_pooled_table_with_unchanged_inputs_is_taken_from_the_previous_folder(tmp_path):
    """``StageContext.pooled`` through :class:`PooledTables`: the previous folder's table is taken
    when the function and its arguments' content are unchanged (not computed), computed when they
    changed or without a previous folder (``--full``); a computed one comes back as Parquet gives
    it, so a taken and a computed table are the same frame."""
    import pandas as pd
    import pandas.testing as pdt

    from pipeline.stages import StageContext, StageOutput

    data = pd.DataFrame({"g": ["a", "b", "a"], "x": [1.0, 2.0, 3.5]})

    def run(previous, df):
        pooled = store.PooledTables(previous)
        ctx = StageContext(raw=tmp_path, warehouse=tmp_path, runs=pd.DataFrame(), pooled_tables=pooled)
        table = ctx.pooled("sums", pooled_sum, df, by="g")
        out = StageOutput(tables={"sums": table})
        rel, *_ = store.save_stage_folder(tmp_path, "demo", f"{len(list(tmp_path.glob('stages/demo/*'))):020d}",
                                          out, previous=previous, pooled=pooled.keys)
        return tmp_path / rel, table, pooled

    pooled_sum.calls = 0
    first, computed, p1 = run(None, data)
    assert pooled_sum.calls == 1 and p1.taken == [] and set(p1.keys) == {"sums"}
    second, taken, p2 = run(first, data.copy())  # equal content, another frame
    assert pooled_sum.calls == 1 and p2.taken == ["sums"] and p2.keys == p1.keys
    pdt.assert_frame_equal(taken, computed, check_exact=True)
    assert list(taken["x"]) == [4.5, 2.0]
    _third, changed, p3 = run(second, data.assign(x=[1.0, 2.0, 4.0]))  # one value changed: computed
    assert pooled_sum.calls == 2 and p3.taken == [] and list(changed["x"]) == [5.0, 2.0]
    _full, again, p4 = run(None, data)  # no previous folder: computed, the same frame as taken
    assert pooled_sum.calls == 3 and p4.taken == []
    pdt.assert_frame_equal(again, taken, check_exact=True)
    ctx = StageContext(raw=tmp_path, warehouse=tmp_path, runs=pd.DataFrame())  # outside a rebuild: computed
    assert list(ctx.pooled("sums", pooled_sum, data, by="g")["x"]) == [4.5, 2.0] and pooled_sum.calls == 4


def test_a_pooled_table_is_not_taken_from_a_damaged_or_foreign_previous_folder(tmp_path):
    import pandas as pd

    from pipeline.stages import StageOutput

    data = pd.DataFrame({"g": ["a"], "x": [1.0]})
    pooled = store.PooledTables(None)
    assert pooled.take("sums", pooled_sum, ((data,), {"by": "g"})) is None
    rel, *_ = store.save_stage_folder(tmp_path, "demo", "1" * 20, StageOutput(tables={"sums": data}),
                                      pooled=pooled.keys)
    folder = tmp_path / rel
    again = store.PooledTables(folder)
    assert again.take("sums", pooled_sum, ((data,), {"by": "g"})) is not None
    assert store.PooledTables(folder).take("other", pooled_sum, ((data,), {"by": "g"})) is None  # not kept
    assert store.PooledTables(folder).take("sums", lambda d: d, ((data,), {})) is None  # no key: computed
    (folder / "tables" / "sums.parquet").unlink()
    assert store.PooledTables(folder).take("sums", pooled_sum, ((data,), {"by": "g"})) is None
    (folder / "output.json").write_text("{not json")
    assert store.PooledTables(folder).take("sums", pooled_sum, ((data,), {"by": "g"})) is None


def _laid_out_plot(layout: str):
    """A small figure with text to lay out, laid out by ``fig.tight_layout()`` or constrained layout."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(3, 2), layout="constrained" if layout == "constrained" else None)
    axes = fig.subplots(1, 2)
    for i, ax in enumerate(axes):
        ax.plot([0, 1, 2, 3], [3 * i, 1, 4, 1.5], label=f"curve {i}")
        ax.set_xlabel("x [mm]")
        ax.set_ylabel("force [N]")
        ax.set_title(f"panel {i}")
        ax.legend(loc="best")
    fig.suptitle("a figure laid out")
    if layout == "tight":
        fig.tight_layout()
    return fig


def test_a_figure_laid_out_by_tight_layout_is_saved_with_one_draw_and_the_same_bytes(tmp_path, monkeypatch):
    """``tight_layout()`` leaves a placeholder layout engine, for which ``savefig`` drew the figure
    once more before saving it, changing nothing: the stage figure is saved without it, with the
    bytes matplotlib's own ``savefig`` gives; a constrained layout keeps its engine and its draws."""
    from matplotlib.figure import Figure
    from matplotlib.layout_engine import ConstrainedLayoutEngine, PlaceHolderLayoutEngine

    draws = []
    real_draw = Figure.draw
    monkeypatch.setattr(Figure, "draw", lambda self, renderer: draws.append(1) or real_draw(self, renderer))
    for layout in ("tight", "constrained", "none"):
        plain, ours = tmp_path / f"{layout}-savefig.png", tmp_path / f"{layout}-stage.png"
        draws.clear()
        fig = _laid_out_plot(layout)
        if layout == "tight":
            assert isinstance(fig.get_layout_engine(), PlaceHolderLayoutEngine)
        fig.savefig(plain, dpi=110, metadata={"Software": None})
        plain_draws = len(draws)
        draws.clear()
        fig = _laid_out_plot(layout)
        store._save_figure(fig, ours)
        assert ours.read_bytes() == plain.read_bytes(), layout
        if layout == "tight":
            assert (plain_draws, len(draws)) == (2, 1) and fig.get_layout_engine() is None
        elif layout == "constrained":
            assert len(draws) == plain_draws == 2 and isinstance(fig.get_layout_engine(), ConstrainedLayoutEngine)
        else:
            assert len(draws) == plain_draws == 1


def test_matplotlib_is_imported_here_once_just_before_the_drawing_worker_is_forked(tmp_path, monkeypatch):
    """The rebuild imports matplotlib's figure and canvas only when a figure is to be drawn (a
    change drawing none does without them), in this process just before forking the worker (which
    starts warm); a drawer that draws nothing forks nothing and imports nothing."""
    import os

    from pipeline.stages import FigureRecipe

    here = []
    monkeypatch.setattr(store, "_warm_figures", lambda: here.append(os.getpid()))
    with store.FigureDrawer(2) as idle:
        pass
    assert idle._pool is None and here == []
    pids = tmp_path / "pids.txt"
    with store.FigureDrawer(2) as drawer:
        (tmp_path / "figures").mkdir()
        for n in ("a", "b"):
            drawer.draw("demo", n, FigureRecipe(tiny_plot, (n, str(pids))), tmp_path / "figures" / f"{n}.png")
        drawer.finish()
    assert here == [os.getpid()]  # once, here, before the fork
    assert os.getpid() not in {int(p) for p in pids.read_text().split()}  # drawn in the worker
    here.clear()
    with store.FigureDrawer(2) as drawer:
        drawer.warm()
        drawer.warm()
    assert here == [os.getpid()]


def test_a_deferred_table_is_read_once_when_asked_with_its_finish_and_counts_its_rows(tmp_path):
    import pandas as pd

    from pipeline.rebuild.stage_store import DeferredTable

    path = tmp_path / "t.parquet"
    pd.DataFrame({"run_id": ["a", "b", "c"], "x": [1.0, 2.0, 3.0]}).to_parquet(path)
    calls = []
    table = DeferredTable(path, finish=lambda df: calls.append(1) or df.assign(y=df["x"] * 2))
    assert len(table) == 3 and not calls   # rows from the file's footer, nothing read
    df = table.read_frame()
    assert list(df["y"]) == [2.0, 4.0, 6.0] and table.read_frame() is df and calls == [1]
    pd.testing.assert_frame_equal(df.drop(columns="y"), pd.read_parquet(path))
