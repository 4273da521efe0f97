"""The columns a person filters a stage's tables by, joined from the runs they come from.

``campaign`` and ``hose_id`` for tables with a ``run_id``; ``campaigns`` and ``n_runs`` for the
aggregated tables of :data:`POOLS`. The rebuild adds them to every stage's tables, run or reused
(they are not part of a stage folder).
"""
from __future__ import annotations

import json
from dataclasses import dataclass

import pandas as pd


#: Aggregated tables: the run-level table whose rows they pool and the columns that group them
#: (an empty tuple: the whole table is one pool). The rows' campaigns and runs are stated as
#: ``campaigns`` (sorted list) and ``n_runs``.
POOLS: dict[str, tuple[str, tuple[str, ...]]] = {
    "seal_envelope": ("leakage_map", ("chamber", "adjustment", "z_rollers_mm", "spring_force_n")),
    "breakaway_summary": ("breakaway", ("direction", "backpressure_bar", "force_rate_n_s")),
    "breakaway_findings": ("breakaway", ()),
    "viscous_fits": ("viscous_points", ("backpressure_bar", "direction")),
    "viscous_transition": ("viscous_points", ("backpressure_bar",)),
    "spring_fits": ("spring_tests", ("chamber",)),
    "pressure_dynamics": ("pressure_steps", ("chamber", "direction")),  # the stage fills its own (per rig, part)
    "service_life": ("hose_life", ("hose_type", "adjustment")),
    "hose_survival": ("hose_life", ("hose_type", "adjustment")),
    "service_life_test": ("hose_life", ("hose_type",)),
}


def _hose_of(params) -> str | None:
    if isinstance(params, str):
        try:
            params = json.loads(params)
        except ValueError:
            return None
    h = params.get("hose_id") if isinstance(params, dict) else None
    return None if h is None or (isinstance(h, float) and h != h) or str(h) == "" else str(h)


def _key(value):
    """A group-key cell comparable across tables (floats rounded to 9 digits, NULL as None)."""
    if value is None or (isinstance(value, float) and value != value):
        return None
    if isinstance(value, float):
        return round(value, 9)
    return value


@dataclass(frozen=True)
class RunLookup:
    """What :func:`add_run_columns` reads of the runs: each run's campaign, and its hose when it names one.

    Read out once (:func:`run_lookup`) for every stage's tables: the rebuild adds run columns to the
    tables of every stage, run or reused, and reading 10,000 runs' params again for each cost ~0.035
    CPU-s a stage, ~0.3 of every change at 10,000 runs (issue 26)."""

    campaign: dict
    hose: dict


def run_lookup(runs: pd.DataFrame | None) -> RunLookup | None:
    """:class:`RunLookup` of ``runs`` (``run_id``, ``campaign``, ``params``: dict or JSON text); None when
    there are no runs (then no table gets run columns)."""
    if runs is None or runs.empty or "run_id" not in runs.columns:
        return None
    return RunLookup(dict(zip(runs["run_id"], runs["campaign"])),
                     {rid: h for rid, p in zip(runs["run_id"], runs["params"]) if (h := _hose_of(p)) is not None})


def add_run_columns(tables: dict[str, pd.DataFrame], runs: pd.DataFrame | RunLookup | None) -> dict[str, pd.DataFrame]:
    """The stage's tables with the columns a person filters by, joined from ``runs``.

    Every table with a ``run_id`` gets ``campaign`` and, when any of its runs names a hose,
    ``hose_id`` (columns a stage already fills are kept as they are). The aggregated tables of
    :data:`POOLS` get ``campaigns`` (sorted list) and ``n_runs``: the campaigns and the number of
    runs of the pooled rows of the same group (``seal_envelope`` pools its setting's
    characterisation runs, or its hose checks when it has nothing else, as ``runs_used`` says;
    hose tables pool the hoses' logbook campaigns and count no runs). A group whose rows cannot be
    matched gets NULLs, never a guess.

    Parameters
    ----------
    tables : dict of str to DataFrame
        One stage's output tables (not modified).
    runs : DataFrame or RunLookup
        ``runs`` rows with ``run_id``, ``campaign`` and ``params`` (dict or JSON text), or their
        :func:`run_lookup` (read out once for many calls).

    Returns
    -------
    dict of str to DataFrame
    """
    lookup = runs if isinstance(runs, RunLookup) else run_lookup(runs)
    if lookup is None:
        return tables
    campaign, hose = lookup.campaign, lookup.hose
    out = dict(tables)
    for name, df in tables.items():
        if df is None or "run_id" not in df.columns:
            continue
        if df.empty:  # the same columns and dtypes, without pandas' per-column work (a reused empty stage)
            out[name] = df.assign(campaign=pd.array([], dtype="string")) if "campaign" not in df.columns else df.copy()
            continue
        df = df.copy()
        if "campaign" not in df.columns:
            df["campaign"] = pd.array(df["run_id"].map(campaign), dtype="string")
        if "hose_id" not in df.columns and df["run_id"].isin(list(hose)).any():
            df["hose_id"] = pd.array(df["run_id"].map(hose), dtype="string")
        out[name] = df
    for name, (source, keys) in POOLS.items():
        df, src = out.get(name), out.get(source)
        if (df is None or src is None or "campaigns" in df.columns or not set(keys) <= set(src.columns)
                or not set(keys) <= set(df.columns)):
            continue
        out[name] = _pool_columns(name, df, src, keys)
    return out


def _pool_columns(name: str, df: pd.DataFrame, src: pd.DataFrame, keys: tuple[str, ...]) -> pd.DataFrame:
    if "campaign" in src.columns:
        camp = src["campaign"].map(lambda c: [c] if isinstance(c, str) else [])
    elif "campaigns" in src.columns:
        camp = src["campaigns"].map(lambda c: [str(x) for x in c] if c is not None and not isinstance(c, str) else [])
    else:
        return df
    run = src["run_id"] if "run_id" in src.columns else pd.Series(None, index=src.index, dtype=object)
    hose_check = (src["hose_id"].map(lambda h: isinstance(h, str) and h != "") if "hose_id" in src.columns
                  else pd.Series(False, index=src.index))
    groups: dict[tuple, list[int]] = {}   # the source rows of each key, by position (labels may repeat)
    for i, k in enumerate(zip(*(src[c] for c in keys)) if keys else ((),) * len(src)):
        groups.setdefault(tuple(_key(v) for v in k), []).append(i)
    # per source row as plain values: no pandas lookup per pooled row (issue 26: the rebuild adds these
    # columns to every stage's tables, run or reused, on every change)
    camp_of, run_of, hose_of = (s.tolist() for s in (camp, run, hose_check))
    used = df["runs_used"].tolist() if "runs_used" in df.columns else [None] * len(df)
    campaigns, n_runs = [], []
    for k, runs_used in zip(zip(*(df[c].tolist() for c in keys)) if keys else ((),) * len(df), used):
        idx = groups.get(tuple(_key(v) for v in k))
        if idx and name == "seal_envelope":  # the rows the envelope is made of (analyses/leakage.py)
            want = runs_used == "hose_checks"
            idx = [i for i in idx if bool(hose_of[i]) == want] or None
        if not idx:
            campaigns.append(None)
            n_runs.append(None)
            continue
        campaigns.append(sorted({c for i in idx for c in camp_of[i]}))
        n_runs.append(len({r for i in idx if not _missing(r := run_of[i])}) if "run_id" in src.columns else None)
    df = df.copy()
    df["campaigns"] = pd.Series(campaigns, index=df.index, dtype=object)
    if "n_runs" not in df.columns and "run_id" in src.columns:
        df["n_runs"] = pd.array(n_runs, dtype="Int64")
    return df


def _missing(value) -> bool:
    """Whether a cell is NULL as ``nunique`` leaves it out (None, NaN, NA, NaT)."""
    return value is None or bool(pd.isna(value)) if not isinstance(value, (list, tuple)) else False
