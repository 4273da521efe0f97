"""Where a stage's outputs are stored: its folder ``stages/<stage>/<key>/``, written and read back.

A folder holds ``output.json`` (tables, figures with captions, problems, warnings), the tables as
Parquet (``tables/<table>.parquet``; a table without rows only as its columns' dtypes in
``output.json``) and the figures as PNG (``figures/<name>.png``, drawn by :class:`FigureDrawer`,
possibly in a worker process). It is written under a temporary name and renamed into place once
complete, so a folder under its final name is always whole. The folder's key hashes the stage's
inputs: the same key, the same outputs (stages are deterministic), so an existing folder is reused.
"""
from __future__ import annotations

import io
import json
import os
import shutil
import stat
from pathlib import Path
from typing import TYPE_CHECKING

from pipeline.raw.problems import Problem
from pipeline.rebuild.executors import _kill_workers  # stop the figure worker of an interrupted rebuild
from pipeline.rebuild.executors import default_jobs, forked_pool
from pipeline.rebuild.figure_keys import figure_key, reusable_figures, table_key
from pipeline.rebuild.options import RebuildError
from pipeline.rebuild.garbage import remove_stage_folder
from pipeline.warehouse import STAGE_KEY

if TYPE_CHECKING:
    import pandas as pd

    from pipeline.stages import StageOutput

# pandas, pyarrow, matplotlib and the stage framework (which imports pandas) are imported by the
# functions that use them: a no-op rebuild imports this module and needs none of them.


def _save_figure(fig, path: Path) -> None:
    """Save a stage figure (a matplotlib Figure or a ``FigureRecipe``) as PNG, byte for byte the
    same for the same figure (no software or date in the metadata)."""
    from pipeline import stages as stage_registry

    fig = stage_registry.figure_of(fig)
    _drop_spent_layout(fig)
    fig.savefig(path, dpi=110, metadata={"Software": None})


def _drop_spent_layout(fig) -> None:
    """Take a spent layout engine off ``fig`` before it is saved: the same pixels, one draw fewer.

    ``Figure.tight_layout()`` lays the figure out once and leaves a ``PlaceHolderLayoutEngine``
    (its ``execute`` does nothing) in place of its engine; ``savefig`` draws a figure that has
    any layout engine twice, once without rendering "to make sure the layout works", and the
    placeholder makes that first draw change nothing but the time (20-35 % of saving such a
    figure; issue 26). The PNG bytes are those of the figure saved with it (tested). A figure
    with a working engine (constrained layout) keeps it and its two draws."""
    import matplotlib as mpl
    from matplotlib.layout_engine import PlaceHolderLayoutEngine

    if isinstance(fig.get_layout_engine(), PlaceHolderLayoutEngine) and \
            not mpl.rcParams["figure.autolayout"] and not mpl.rcParams["figure.constrained_layout.use"]:
        fig.set_layout_engine(None)  # (with those rcParams off, None is no engine at all)


def _warm_figures() -> None:
    """Import what drawing a figure needs (in the rebuild process, just before the drawing worker is
    forked: ~0.25 CPU-s, paid once and only when a figure is drawn)."""
    import matplotlib.backends.backend_agg  # noqa: F401
    import matplotlib.figure  # noqa: F401


def _started() -> None:
    """The drawing worker's first task when it is started ahead (:meth:`FigureDrawer.warm`): nothing."""


class FigureDrawer:
    """Draws the stages' figures into their stage folders, off the rebuild's critical path.

    With ``jobs`` > 1, each figure (a ``FigureRecipe``) is drawn in one worker process forked
    from the rebuild, while this process goes on with the next stages and the database; with
    ``jobs`` 1 (or a figure already drawn), here, at once. A stage folder is written under its
    temporary name and renamed into place only when its figures are all drawn (:meth:`finish`,
    before the new database is swapped in), so a folder under its final name always holds every
    figure its ``output.json`` lists, whenever the rebuild is killed. A figure that fails fails
    the rebuild, as a failing stage does. Use it as a context manager (the worker is closed).
    """

    def __init__(self, jobs: int | None = 1, close_fds: tuple[int, ...] = ()):
        self.jobs = default_jobs(jobs)
        self.close_fds = tuple(close_fds)
        self._pool = None
        self._pending: list[tuple[object, str, str]] = []  # (future, stage, figure name)
        self._folders: list[tuple[Path, Path]] = []  # (temporary folder, final folder)

    def _submit(self, func, *args):
        if self.jobs <= 1:
            return None
        if self._pool is None:
            _warm_figures()  # here, before the fork: the worker starts warm, and the report has them too
            self._pool = forked_pool(1, self.close_fds)
        return self._pool.submit(func, *args)

    def warm(self) -> None:
        """Start the drawing worker now (a stage is about to run that draws every figure), matplotlib's
        figure and Agg canvas imported first in this process (the worker and the report's own figures
        then use them: imported once). Not called when a figure may be taken from a previous folder:
        then the first figure to draw starts the worker, and a rebuild drawing none imports none."""
        if self._pool is None:
            self._submit(_started)

    def draw(self, stage: str, name: str, fig, path: Path) -> None:
        from pipeline import stages as stage_registry

        fut = self._submit(_save_figure, fig, path) if isinstance(fig, stage_registry.FigureRecipe) else None
        if fut is None:
            _save_figure(fig, path)
        else:
            self._pending.append((fut, stage, name))

    @property
    def busy(self) -> bool:
        return bool(self._pending)

    def publish(self, tmp: Path, final: Path) -> None:
        """Rename ``tmp`` to ``final`` once the figures drawn into it are done."""
        self._folders.append((tmp, final))

    def finish(self) -> int:
        """Wait for every figure; then put the stage folders in place. Returns how many figures
        were drawn in the worker."""
        pending, self._pending = self._pending, []
        failed = None
        for fut, stage, name in pending:
            try:
                fut.result()
            except Exception as exc:  # a bug in a plot function, or its worker died

                failed = failed or RebuildError(f"stage {stage} failed: figure {name}: {type(exc).__name__}: {exc}")
        folders, self._folders = self._folders, []
        if failed is not None:
            for tmp, _final in folders:
                shutil.rmtree(tmp, ignore_errors=True)
            raise failed
        for tmp, final in folders:
            _place_stage_folder(tmp, final)
        return len(pending)

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None

    def __enter__(self):
        return self

    def __exit__(self, exc_type, *exc):
        if self._pool is not None and exc_type is not None and not issubclass(exc_type, Exception):
            _kill_workers(self._pool)  # interrupted: not after the figure it is drawing
        self.close()
        return False


def own_stage_folder(warehouse: Path, rel: str, stage: str) -> Path | None:
    """The folder ``rel`` of a stage record when it is one of this warehouse's own stage folders:
    ``stages/<stage>/<key>`` relative to it (as :func:`save_stage_folder` names them), each level a
    real folder, not a symlink; else None (the stage runs: a record naming a folder elsewhere, an
    absolute path, ``..``, a link out, is never read). Relative names are why a warehouse copied or
    moved elsewhere reuses its own folders (issue 26), and only those."""
    parts = rel.split("/") if isinstance(rel, str) else []
    if len(parts) != 3 or parts[0] != "stages" or parts[1] != stage or not STAGE_KEY.fullmatch(parts[2]):
        return None
    folder = Path(warehouse)
    for part in parts:
        folder = folder / part
        try:
            if not stat.S_ISDIR(os.lstat(folder).st_mode):
                return None
        except OSError:
            return None
    return folder


def _place_stage_folder(tmp: Path, final: Path) -> None:
    """Rename a stage folder written under its temporary name into place (replacing a damaged one,
    or a link in its place: the link goes, never what it points at)."""
    if final.is_symlink():
        final.unlink()
    elif final.exists():  # damaged (its output.json gone), or tables that could not be stored

        remove_stage_folder(final)
    final.parent.mkdir(parents=True, exist_ok=True)  # the collection before the database removes empty folders
    os.replace(tmp, final)


class PooledTables:
    """A stage's pooled tables keyed by their inputs (``StageContext.pooled``): a table whose
    function, code and arguments are those of the stage's previous folder is read from there
    instead of computed again.

    One changed leakage check re-runs ``durability``, whose Weibull fits pool the hoses' lives,
    which did not change: they (and their ``scipy.stats`` import) were ~3 CPU-s of the change
    (issue 26). The previous folder's ``output.json`` keeps each pooled table's key
    (:func:`pipeline.rebuild.figure_keys.table_key`); a table is taken only when its key is
    there and its Parquet file (or its empty columns) too. The rebuild reads every stage table
    back from its folder's Parquet, so a taken table gives the database the rows a computed one
    gives (tested against ``--full``, which takes none).

    Parameters
    ----------
    previous : Path or None
        The stage's folder of the previous rebuild (None: every table is computed).
    """

    def __init__(self, previous: Path | None):
        self.keys: dict[str, str] = {}
        self.taken: list[str] = []
        self._folder = previous
        self._meta: dict = {}
        if previous is not None:
            try:
                self._meta = json.loads((previous / "output.json").read_text())
            except (OSError, ValueError):
                self._meta = {}

    def take(self, table: str, func, key_args: tuple):
        """The previous folder's ``table`` when its key is that of ``func(*key_args)``, else None
        (the caller computes it); the key is kept for this run's folder either way."""
        key = table_key(func, key_args)
        if key is None:
            return None
        self.keys[table] = key
        if (self._meta.get("pooled") or {}).get(table) != key or table not in self._meta.get("tables", ()):
            return None
        empty = self._meta.get("empty") or {}
        try:
            if table in empty:
                df = _empty_frame(empty[table])
            else:
                import pandas as pd

                df = pd.read_parquet(self._folder / "tables" / f"{table}.parquet")
        except (OSError, ValueError, TypeError):
            return None
        self.taken.append(table)
        return df

    @staticmethod
    def settle(df: pd.DataFrame) -> pd.DataFrame:
        """A computed pooled table as a taken one reads: through Parquet (as is when it cannot be)."""
        import pandas as pd
        import pyarrow as pa
        import pyarrow.parquet as pq

        try:
            buf = io.BytesIO()
            pq.write_table(pa.Table.from_pandas(df.reset_index(drop=True), preserve_index=False), buf)
            return pd.read_parquet(io.BytesIO(buf.getvalue()))
        except (pa.ArrowException, TypeError, ValueError):
            return df


def save_stage_folder(warehouse: Path, name: str, folder_key: str, out: StageOutput,
                       drawer: FigureDrawer | None = None, previous: Path | None = None,
                       pooled: dict[str, str] | None = None) -> tuple[str, bool, Path]:
    """Write a stage's outputs to ``stages/<name>/<key>/`` (temp folder, then one rename).

    Returns (folder relative to the warehouse, whether the tables could be cached, the folder
    that holds them now). With a ``drawer``, figures may still be being drawn into a temporary
    folder, which the drawer renames into place (:meth:`FigureDrawer.finish`). ``previous``: the
    stage's folder of the previous rebuild; a figure whose key
    (:func:`pipeline.rebuild.figure_keys.figure_key`) is one of its figures' is taken from there,
    not drawn. ``pooled``: the keys of its pooled tables (:class:`PooledTables`).
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    rel = f"stages/{name}/{folder_key}"
    final = warehouse / rel
    tmp = warehouse / "stages" / f".tmp-{name}-{folder_key}-{os.getpid()}"
    if own_stage_folder(warehouse, rel, name) and (final / "output.json").is_file() and _cacheable_tables(out):
        # same inputs, same outputs (stages are deterministic): keep the folder a live warehouse
        # may use, and draw nothing
        return rel, True, final
    shutil.rmtree(tmp, ignore_errors=True)
    (tmp / "tables").mkdir(parents=True)
    (tmp / "figures").mkdir()
    cacheable = True
    empty = {}  # a table without rows is kept as its columns' dtypes in output.json, not a Parquet file
    for table, df in out.tables.items():
        try:
            arrow = pa.Table.from_pandas(df.reset_index(drop=True), preserve_index=False)
            columns = _empty_columns(arrow) if arrow.num_rows == 0 else None
            if columns is not None:
                empty[table] = columns
                continue
            pq.write_table(arrow, tmp / "tables" / f"{table}.parquet")
        except (pa.ArrowException, TypeError, ValueError):
            cacheable = False
    drawer = drawer or FigureDrawer()
    figures = _save_figures(name, out, tmp / "figures", drawer, previous)
    meta = {"tables": sorted(out.tables), "empty": empty, "figures": figures, "cacheable": cacheable,
            "pooled": dict(sorted((pooled or {}).items())),
            "problems": [{"source_path": p.source_path, "error": p.error, "line": p.line, "stage": p.stage}
                         for p in out.problems],
            "warnings": {k: list(v) for k, v in sorted(out.warnings.items())}}
    (tmp / "output.json").write_text(json.dumps(meta, sort_keys=True, default=str))
    final.parent.mkdir(parents=True, exist_ok=True)
    drawer.publish(tmp, final)
    if drawer.busy:
        return rel, cacheable, tmp
    drawer.finish()
    return rel, cacheable, final


def _save_figures(name: str, out: StageOutput, folder: Path, drawer: FigureDrawer, previous: Path | None) -> dict:
    """Draw each figure of ``out`` into ``folder`` (or link the previous folder's file with the same
    key); ``{name: {"file", "caption", "key"}}`` for ``output.json``."""
    from pipeline import stages as stage_registry

    reusable = reusable_figures(previous)
    figures = {}
    for fname, fig in sorted(out.figures.items()):
        file = f"{fname}.png"
        key = figure_key(fig) if isinstance(fig, stage_registry.FigureRecipe) else None
        if key is None or not _link_figure(reusable.get(key), folder / file):
            drawer.draw(name, fname, fig, folder / file)
        figures[fname] = {"file": file, "caption": out.captions.get(fname, "")} | ({"key": key} if key else {})
    return figures


def _link_figure(source: Path | None, target: Path) -> bool:
    """Put the PNG ``source`` (a figure with the same key) at ``target``: a hard link, a copy where
    links are refused; False when there is none or it cannot be taken."""
    if source is None:
        return False
    try:
        try:
            os.link(source, target)
        except OSError:
            shutil.copyfile(source, target)
        return True
    except OSError:
        target.unlink(missing_ok=True)
        return False


def _cacheable_tables(out: StageOutput) -> bool:
    """Whether every table of ``out`` can be stored as Parquet (and so read back from a folder)."""
    import pyarrow as pa

    try:
        for df in out.tables.values():
            pa.Schema.from_pandas(df, preserve_index=False)
    except (pa.ArrowException, TypeError, ValueError):
        return False
    return True


def _empty_frame(columns: list) -> pd.DataFrame:
    """The DataFrame ``pd.read_parquet`` gives for a table without rows, from its ``[[column, dtype]]``."""
    import pandas as pd

    return pd.DataFrame({c: pd.array([], dtype=d) for c, d in columns}, index=pd.RangeIndex(0), copy=False)


def _empty_columns(arrow) -> list | None:
    """``[[column, dtype]]`` of a table without rows, when :func:`_empty_frame` rebuilds exactly the
    frame its Parquet file would read back as; else None (the table is written as Parquet)."""
    import pandas as pd
    import pyarrow.parquet as pq

    buf = io.BytesIO()  # the round trip itself (Parquet has no second unit, for one: s comes back as ms)
    pq.write_table(arrow, buf)
    back = pd.read_parquet(io.BytesIO(buf.getvalue()))
    columns = [[c, str(d)] for c, d in back.dtypes.items()]
    if not all(isinstance(c, str) for c, _ in columns) or len(set(back.columns)) != len(columns):
        return None
    try:
        again = _empty_frame(columns)
    except (TypeError, ValueError):
        return None
    same = list(again.columns) == list(back.columns) and [repr(d) for d in again.dtypes] == [repr(d) for d in back.dtypes]
    return columns if same else None  # repr, not ==: a category dtype equals "category" whatever its categories


class DeferredTable:
    """A table of a reused stage's folder that no stage reads, read only when the database needs its rows.

    The database write takes an unchanged table's content key from the live copy and writes only the
    tables whose rows changed (:func:`pipeline.rebuild.assemble.write_database`); a one-file change
    reads the rest of the reused stages' Parquet files for nothing (``durability_strokes`` alone is
    188,000 rows at 1,000 runs; issue 26). :meth:`read_frame` reads the file once, ``finish`` (the
    run columns) applied, as the folder's eager read would have given it; ``len`` is the file's rows.
    """

    def __init__(self, path: Path, finish=None):
        self.path, self.finish, self._frame = Path(path), finish, None

    def read_frame(self) -> pd.DataFrame:
        """The table's frame (read, and ``finish`` applied, on the first call)."""
        if self._frame is None:
            import pandas as pd

            df = pd.read_parquet(self.path)
            self._frame = self.finish(df) if self.finish is not None else df
        return self._frame

    def __len__(self) -> int:
        if self._frame is not None:
            return len(self._frame)
        import pyarrow.parquet as pq

        return pq.read_metadata(self.path).num_rows


def load_stage_folder(warehouse: Path, rel: str, stage: str, fresh: StageOutput | None = None,
                       folder: Path | None = None, defer: frozenset[str] = frozenset()):
    """(tables, figure rows, problems, warnings) of a stage folder (``rel``; read from ``folder``
    when it is still under its temporary name); the tables of ``defer`` stored as Parquet are
    :class:`DeferredTable` (not read)."""
    import pandas as pd

    folder = folder or warehouse / rel
    meta = json.loads((folder / "output.json").read_text())
    empty = meta.get("empty") or {}
    tables = {}
    for t in meta["tables"]:
        f = folder / "tables" / f"{t}.parquet"
        if t in empty:  # no rows: its dtypes were checked to come back exactly as from Parquet
            tables[t] = _empty_frame(empty[t])
        elif t in defer and meta.get("cacheable", True) and f.is_file():
            tables[t] = DeferredTable(f)
        else:
            tables[t] = pd.read_parquet(f) if f.is_file() and meta.get("cacheable", True) else fresh.tables[t]
    figures = [{"stage": stage, "name": n, "path": f"{rel}/figures/{v['file']}", "caption": v["caption"]}
               for n, v in sorted(meta["figures"].items())]
    problems = [Problem(p["source_path"], p["error"], p["line"], p.get("stage") or stage) for p in meta["problems"]]
    return tables, figures, problems, meta["warnings"]
