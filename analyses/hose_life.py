"""Hose life: which hose each durability run belongs to, and each hose's distance, strokes and status.

Pure functions on DataFrames: the hoses come merged from their logbooks (one row per hose with
its installation ``intervals``, :func:`pipeline.raw.logbook.merge_logbooks`), the runs from the
durability stage (``run_id``, ``hose_id``, ``started_at`` [UTC], ``distance_km`` [km],
``strokes``).

* **Runs.** A ``durability`` run belongs to a hose when its ``hose_id`` matches and its
  ``started_at`` lies in one of the hose's installations ``[installed, end)`` (end = the
  failed/removed time; open when still running). Runs outside every installation, and runs
  naming a hose no logbook knows, are reported as run warnings; a hose with runs but no
  logbook still gets a ``hose_life`` row (status ``running``, type and adjustment NULL).
* **Life.** When runs cover a hose, its life is their summed distance; else the odometer; a
  running hose without runs has covered 0 km; a failed/removed hose without runs or odometer
  has NULL distance. Runs and odometer disagreeing by more than 2 % is a warning in
  ``hose_life.warnings`` (the runs count).
"""
from __future__ import annotations

import math

import numpy as np
import pandas as pd

#: Relative disagreement between runs and odometer above which hose_life warns [-] (2 %).
ODOMETER_TOLERANCE = 0.02

LIFE_COLUMNS = ["hose_id", "hose_type", "adjustment", "distance_km", "strokes", "status", "failure_mode", "n_runs",
                "z_rollers_mm", "spring_force_n", "runs_km", "odometer_km", "distance_source", "installed_at",
                "ended_at", "n_installations", "campaigns", "wall_thickness_mm", "warnings", "odometer_at"]


def match_runs(hoses: pd.DataFrame, runs: pd.DataFrame) -> tuple[pd.Series, dict[str, list[str]]]:
    """The hose each durability run belongs to.

    Parameters
    ----------
    hoses : DataFrame
        From :func:`pipeline.raw.logbook.merge_logbooks`.
    runs : DataFrame
        ``run_id``, ``hose_id``, ``started_at`` (UTC).

    Returns
    -------
    (Series, dict)
        Per run (index of ``runs``) the matched hose_id or None; warnings per run_id.
    """
    intervals = dict(zip(hoses["hose_id"], hoses["intervals"])) if len(hoses) else {}
    out, warnings = [], {}
    for rid, hid, started in zip(runs["run_id"], runs["hose_id"], runs["started_at"]):
        if hid is None or (isinstance(hid, float) and math.isnan(hid)):
            out.append(None)
            continue
        if hid not in intervals:
            warnings.setdefault(rid, []).append(f"hose {hid} is in no hoses.csv logbook")
            out.append(hid)
            continue
        ts = pd.Timestamp(started)
        ts = ts.tz_localize("UTC") if ts.tzinfo is None else ts
        if pd.isna(ts) or not any(s <= ts and (e is None or ts < e) for s, e in intervals[hid]):
            warnings.setdefault(rid, []).append(
                f"started at {ts.isoformat() if not pd.isna(ts) else '?'} outside every installation of hose {hid}; "
                "not counted in its life")
            out.append(None)
            continue
        out.append(hid)
    return pd.Series(out, index=runs.index, dtype=object), warnings


def hose_life(hoses: pd.DataFrame, runs: pd.DataFrame) -> tuple[pd.DataFrame, dict[str, list[str]]]:
    """The ``hose_life`` table: distance, strokes, status and runs per hose.

    Parameters
    ----------
    hoses : DataFrame
        From :func:`pipeline.raw.logbook.merge_logbooks`.
    runs : DataFrame
        Durability results per run: ``run_id``, ``hose_id``, ``started_at``, ``distance_km``,
        ``strokes`` (NaN when the run could not be analysed).

    Returns
    -------
    (DataFrame, dict)
        One row per hose (``hose_id, hose_type, adjustment, distance_km, strokes, status,
        failure_mode, n_runs`` and more: ``runs_km``, ``odometer_km``, ``distance_source``,
        ``warnings``...), and run warnings.
    """
    runs = runs.copy()
    if runs.empty:
        runs = pd.DataFrame(columns=["run_id", "hose_id", "started_at", "distance_km", "strokes"])
    matched, run_warn = match_runs(hoses, runs)
    runs["_hose"] = matched
    known = set(hoses["hose_id"]) if len(hoses) else set()
    base = hoses.to_dict("records") if len(hoses) else []
    orphans = sorted({h for h in matched.dropna() if h not in known})
    for hid in orphans:
        base.append({"hose_id": hid, "status": "running", "campaigns": [], "n_installations": 0,
                     "warnings": ["hose is in no hoses.csv logbook"], "odometer_km": np.nan})
    rows = [_life_row(h, runs[runs["_hose"] == h["hose_id"]]) for h in base]
    out = pd.DataFrame(rows, columns=LIFE_COLUMNS)
    out["strokes"] = out["strokes"].astype("Int64")
    out["n_runs"] = out["n_runs"].astype("int64")
    for col in ("installed_at", "ended_at", "odometer_at"):
        out[col] = pd.to_datetime(out[col], utc=True, format="ISO8601")
    return out, run_warn


def _life_row(h: dict, mine: pd.DataFrame) -> dict:
    """One hose's ``hose_life`` row: its distance [km] from its runs, else its odometer, and
    its strokes, status and warnings.

    Parameters
    ----------
    h : dict
        The hose (a :func:`pipeline.raw.logbook.merge_logbooks` row, or a hose no logbook knows).
    mine : DataFrame
        The durability runs matched to it.
    """
    warnings = list(h.get("warnings") or [])
    n_runs = len(mine)
    runs_km = float(pd.to_numeric(mine["distance_km"], errors="coerce").sum()) if n_runs else np.nan
    strokes = pd.to_numeric(mine["strokes"], errors="coerce")
    unanalysed = int(strokes.isna().sum())
    if unanalysed:
        warnings.append(f"{unanalysed} of its runs could not be analysed; their distance is missing")
    odo = h.get("odometer_km", np.nan)
    odo = np.nan if odo is None else float(odo)
    if n_runs:
        distance, source = runs_km, "runs"
        if not math.isnan(odo) and odo > 0 and abs(runs_km - odo) > ODOMETER_TOLERANCE * odo:
            warnings.append(f"runs give {runs_km:.3f} km, odometer {odo:.3f} km "
                            f"({100 * (runs_km - odo) / odo:+.1f} %); the runs count")
    elif not math.isnan(odo):
        distance, source = odo, "odometer"
    elif h.get("status") == "running":
        distance, source = 0.0, "none"
    else:
        distance, source = np.nan, "none"
        warnings.append(f"{h.get('status')} without durability runs or odometer distance_km: life unknown")
    return {
        "hose_id": h["hose_id"], "hose_type": h.get("hose_type"), "adjustment": h.get("adjustment"),
        "distance_km": distance,
        "strokes": int(strokes.sum()) if n_runs and unanalysed < n_runs else None,
        "status": h.get("status"), "failure_mode": h.get("failure_mode"), "n_runs": n_runs,
        "z_rollers_mm": h.get("z_rollers_mm"), "spring_force_n": h.get("spring_force_n"),
        "runs_km": runs_km, "odometer_km": odo, "distance_source": source,
        "installed_at": h.get("installed_at"), "ended_at": h.get("ended_at"),
        "n_installations": h.get("n_installations"), "campaigns": list(h.get("campaigns") or []),
        "wall_thickness_mm": h.get("wall_thickness_mm"), "warnings": warnings,
        "odometer_at": h.get("odometer_at"),
    }


def hose_distance_at(hose_runs: pd.DataFrame, when) -> float:
    """Cumulative distance [km] of a hose's runs that started before ``when``.

    Parameters
    ----------
    hose_runs : DataFrame
        That hose's matched durability runs: ``started_at``, ``distance_km``.
    when : Timestamp
        UTC time (e.g. a leakage run's start).
    """
    if hose_runs.empty:
        return 0.0
    before = hose_runs[hose_runs["started_at"] < when]
    return float(pd.to_numeric(before["distance_km"], errors="coerce").fillna(0.0).sum())
