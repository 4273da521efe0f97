"""The rebuild: ingest raw/, run the analysis stages, swap in a new warehouse.

Exit codes (warehouse.md): 0 everything used; 1 warehouse built, some inputs quarantined;
2 usage error; anything else: failed, the previous warehouse untouched (3 failed, 4 another
rebuild holds the lock).
"""
from __future__ import annotations

import fcntl
import logging
import os
import shutil
import time
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from pipeline import stages as stage_registry
from pipeline.ingest import IngestResult, ingest_file
from pipeline.layout import Problem, RawTree, discover_runs
from pipeline.progress import Progress
from pipeline.warehouse import DB_NAME, build_database, connect_readonly, runs_frame, swap_in

log = logging.getLogger("pneubench")

EXIT_OK, EXIT_QUARANTINED, EXIT_USAGE, EXIT_FAILED, EXIT_LOCKED = 0, 1, 2, 3, 4


class RebuildError(Exception):
    """The rebuild failed; the previous warehouse is untouched. ``exit_code`` says how."""

    def __init__(self, message: str, exit_code: int = EXIT_FAILED):
        super().__init__(message)
        self.exit_code = exit_code


@dataclass
class RebuildSummary:
    """What a rebuild did."""

    raw: Path
    warehouse: Path
    n_files: int = 0
    n_runs: int = 0
    quarantine: list[Problem] = field(default_factory=list)
    seconds: float = 0.0
    tables: dict[str, int] = field(default_factory=dict)

    @property
    def exit_code(self) -> int:
        return EXIT_QUARANTINED if self.quarantine else EXIT_OK


@contextmanager
def warehouse_lock(warehouse: Path, wait_s: float = 0.0):
    """Hold the warehouse's rebuild lock; a second rebuild waits ``wait_s`` then gives up."""
    lock_path = Path(warehouse) / ".rebuild.lock"
    fh = open(lock_path, "a+")
    deadline = time.monotonic() + wait_s
    while True:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
            break
        except BlockingIOError:
            if time.monotonic() >= deadline:
                fh.seek(0)
                holder = fh.read().strip() or "unknown"
                fh.close()
                raise RebuildError(f"another rebuild is running on {warehouse} (pid {holder}); "
                                   "try again when it has finished", EXIT_LOCKED) from None
            time.sleep(0.2)
    try:
        fh.seek(0)
        fh.truncate()
        fh.write(str(os.getpid()))
        fh.flush()
        yield
    finally:
        fcntl.flock(fh, fcntl.LOCK_UN)
        fh.close()


_TREES: dict[str, RawTree] = {}


def _ingest_one(args) -> IngestResult:
    raw, path, warehouse, reuse = args
    tree = _TREES.get(raw)
    if tree is None:
        tree = _TREES[raw] = RawTree(Path(raw))
    return ingest_file(tree, Path(path), Path(warehouse), reuse=reuse)


def ingest_all(raw: Path, files: list[Path], warehouse: Path, jobs: int, progress: Progress,
               reuse: bool = True) -> list[IngestResult]:
    """Ingest files in parallel (``jobs`` processes); results in the order of ``files``."""
    args = [(str(raw), str(p), str(warehouse), reuse) for p in files]
    out: list[IngestResult] = []
    with progress.task("ingest", len(args)) as task:
        if jobs <= 1 or len(args) <= 1:
            for a in args:
                out.append(_ingest_one(a))
                task.advance()
        else:
            with ProcessPoolExecutor(max_workers=jobs) as pool:
                for res in pool.map(_ingest_one, args, chunksize=1):
                    out.append(res)
                    task.advance()
    return out


def deduplicate(results: list[IngestResult]) -> tuple[list[dict], list[dict], list[Problem]]:
    """Runs, channel rows and quarantine rows; a repeated run_id is quarantined (first path wins)."""
    runs, channels, problems = [], [], []
    owner: dict[str, str] = {}
    for r in sorted(results, key=lambda r: r.source_path):
        if r.error is not None:
            problems.append(Problem(r.source_path, r.error))
            continue
        rid = r.run["run_id"]
        if rid in owner:
            problems.append(Problem(r.source_path, f"duplicate run_id `{rid}`, already used by `{owner[rid]}`"))
            continue
        owner[rid] = r.source_path
        runs.append(r.run)
        channels += r.channels
    return runs, channels, problems


def run_stages(ctx: stage_registry.StageContext, progress: Progress):
    """Run every analysis stage in order; returns (tables, figures, captions, problems, warnings)."""
    tables: dict[str, pd.DataFrame] = {}
    figures: dict[tuple[str, str], object] = {}
    captions: dict[tuple[str, str], str] = {}
    problems: list[Problem] = []
    warnings: dict[str, list[str]] = {}
    for mod in stage_registry.discover():
        t0 = time.monotonic()
        ctx.results = tables
        try:
            out = mod.run(ctx)
        except Exception as exc:  # a bug in an analysis: fail, keep the previous warehouse
            raise RebuildError(f"stage {mod.NAME} failed: {type(exc).__name__}: {exc}") from exc
        for name, df in out.tables.items():
            tables[name] = df if name not in tables else pd.concat([tables[name], df], ignore_index=True)
        for name, fig in out.figures.items():
            figures[(mod.NAME, name)] = fig
            if name in out.captions:
                captions[(mod.NAME, name)] = out.captions[name]
        problems += out.problems
        for rid, ws in out.warnings.items():
            warnings.setdefault(rid, []).extend(ws)
        progress.message(f"stage {mod.NAME}: " + ", ".join(f"{k} {len(v)} rows" for k, v in out.tables.items())
                         + f" ({time.monotonic() - t0:.1f} s)")
    return tables, figures, captions, problems, warnings


def save_figures(figures: dict, captions: dict, folder: Path) -> pd.DataFrame:
    """Save matplotlib figures as PNG under ``folder/<stage>/<name>.png``; the figures table."""
    import matplotlib.pyplot as plt

    rows = []
    for (stage, name), fig in sorted(figures.items(), key=lambda kv: kv[0]):
        path = folder / stage / f"{name}.png"
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=110, metadata={"Software": None})
        plt.close(fig)
        rows.append({"stage": stage, "name": name, "path": f"figures/{stage}/{name}.png",
                     "caption": captions.get((stage, name), "")})
    return pd.DataFrame(rows, columns=["stage", "name", "path", "caption"])


def _previous_samples(warehouse: Path) -> set[str]:
    try:
        con = connect_readonly(warehouse)
    except Exception:
        return set()
    try:
        return {r[0] for r in con.execute("SELECT samples_path FROM runs").fetchall() if r[0]}
    except Exception:
        return set()
    finally:
        con.close()


def _collect_garbage(warehouse: Path, keep: set[str]) -> None:
    """Delete samples files neither the new nor the previous warehouse uses, and stale temps."""
    samples = warehouse / "samples"
    if not samples.is_dir():
        return
    for f in samples.rglob("*"):
        if not f.is_file():
            continue
        rel = f.relative_to(warehouse).as_posix()
        if rel not in keep:
            f.unlink(missing_ok=True)
    for d in sorted((d for d in samples.rglob("*") if d.is_dir()), key=lambda d: len(d.parts), reverse=True):
        try:
            d.rmdir()
        except OSError:
            pass


def rebuild(raw: str | Path, warehouse: str | Path, jobs: int | None = None, full: bool = False,
            progress: Progress | None = None, lock_wait_s: float = 0.0) -> RebuildSummary:
    """Ingest ``raw``, run the analyses and swap in a new warehouse.

    Parameters
    ----------
    raw : path-like
        The raw tree (never modified).
    warehouse : path-like
        The warehouse folder (created if missing).
    jobs : int, optional
        Worker processes; default all cores.
    full : bool
        Re-ingest every file even when its samples file is up to date.
    progress : Progress, optional
        Where progress goes (silent by default).

    Returns
    -------
    RebuildSummary

    Raises
    ------
    RebuildError
        When the rebuild fails; the previous warehouse is left as it was.
    """
    t0 = time.monotonic()
    progress = progress or Progress()
    raw, warehouse = Path(raw), Path(warehouse)
    if not raw.is_dir():
        raise RebuildError(f"raw folder {raw} does not exist", EXIT_USAGE)
    jobs = jobs or os.cpu_count() or 1
    warehouse.mkdir(parents=True, exist_ok=True)
    summary = RebuildSummary(raw=raw, warehouse=warehouse)
    with warehouse_lock(warehouse, lock_wait_s):
        tree = RawTree(raw)
        tree.scan_rigs()
        tree.scan_manifests()
        files = discover_runs(tree.root)
        summary.n_files = len(files)
        progress.message(f"rebuild: {len(files)} run files under {raw}")
        results = ingest_all(tree.root, files, warehouse, jobs, progress, reuse=not full)
        runs, channels, problems = deduplicate(results)
        problems = tree.problems + problems
        runs_df = runs_frame(runs)
        ctx = stage_registry.StageContext(raw=tree.root, warehouse=warehouse, runs=runs_df.assign(
            params=[r["params"] for r in runs]) if runs else runs_df, jobs=jobs, progress=progress)
        tables, figures, captions, stage_problems, stage_warnings = run_stages(ctx, progress)
        problems += stage_problems
        if stage_warnings and not runs_df.empty:
            runs_df["warnings"] = [list(w) + stage_warnings.get(rid, [])
                                   for rid, w in zip(runs_df["run_id"], runs_df["warnings"])]
        fig_tmp = warehouse / f".figures.tmp-{os.getpid()}"
        shutil.rmtree(fig_tmp, ignore_errors=True)
        figures_df = save_figures(figures, captions, fig_tmp)
        quarantine = pd.DataFrame([{"source_path": p.source_path, "error": p.error, "line": p.line,
                                    "campaign": p.source_path.split("/")[0] if "/" in p.source_path else None,
                                    "stage": p.stage} for p in problems],
                                  columns=["source_path", "error", "line", "campaign", "stage"])
        all_tables = {"runs": runs_df, "quarantine": quarantine, "channels": pd.DataFrame(channels),
                      "figures": figures_df, **tables}
        previous = _previous_samples(warehouse)
        tmp_db = warehouse / f".{DB_NAME}.tmp-{os.getpid()}"
        try:
            build_database(tmp_db, warehouse, all_tables, runs_df)
            swap_figures(fig_tmp, warehouse / "figures")
            swap_in(tmp_db, warehouse / DB_NAME)
        except Exception as exc:
            tmp_db.unlink(missing_ok=True)
            shutil.rmtree(fig_tmp, ignore_errors=True)
            if isinstance(exc, RebuildError):
                raise
            raise RebuildError(f"could not write the warehouse: {type(exc).__name__}: {exc}") from exc
        _collect_garbage(warehouse, previous | set(runs_df.get("samples_path", [])))
        summary.n_runs = len(runs)
        summary.quarantine = problems
        summary.tables = {k: len(v) for k, v in all_tables.items()}
    summary.seconds = time.monotonic() - t0
    for p in problems:
        where = f"{p.source_path}:{p.line}" if p.line else p.source_path
        progress.message(f"quarantined {where}: {p.error}")
    progress.message(f"rebuild: {summary.n_runs} runs, {len(problems)} quarantined, {summary.seconds:.1f} s")
    return summary


def swap_figures(new: Path, final: Path) -> None:
    """Put a new figures folder in place of the old one (two renames; old removed after)."""
    old = final.with_name(f".{final.name}.old-{os.getpid()}")
    if final.exists():
        os.replace(final, old)
    if new.exists():
        os.replace(new, final)
    else:
        final.mkdir(parents=True, exist_ok=True)
    shutil.rmtree(old, ignore_errors=True)
