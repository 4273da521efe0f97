"""The decision stage's items as plain data (session 26: split from :mod:`pipeline.stages.decision`): a hose type's
hoses and runs as lists of plain values (times as int nanoseconds, UTC) for ``ctx.map``, picked per hose type
from columns converted once, and read back as frames to the nanosecond."""
from __future__ import annotations

import numpy as np
import pandas as pd

#: NaT as int64 nanoseconds.
_NAT = np.iinfo(np.int64).min


def _ns_list(values) -> list:
    """UTC times as int nanoseconds since the epoch (None for NaT): plain data for a ``ctx.map`` item."""
    t = pd.to_datetime(pd.Series(values), utc=True, format="ISO8601")
    return [None if pd.isna(v) else int(v) for v in t.to_numpy("datetime64[ns]").astype("int64").astype(object)
            ] if len(t) else []


def _floats(values) -> list:
    return [float(v) for v in pd.to_numeric(pd.Series(values), errors="coerce").to_numpy(float)]


def _columns(df: pd.DataFrame, spec: dict) -> dict:
    """The item's columns of ``df``: name -> list of plain values (``spec``: name -> "text" | "float" | "time")."""
    conv = {"text": lambda v: [None if x is None or x != x else str(x) for x in v], "float": _floats, "time": _ns_list}
    return {c: conv[kind](df[c].tolist() if kind == "text" else df[c]) for c, kind in spec.items()}


HOSE_SPEC = {"hose_id": "text", "adjustment": "text", "distance_km": "float", "status": "text",
             "distance_source": "text", "installed_at": "time", "ended_at": "time", "odometer_at": "time"}
RUN_SPEC = {"hose_id": "text", "started_at": "time", "duration_h": "float", "distance_km": "float"}


def hose_type_item(hose_type: str, life: pd.DataFrame, runs: pd.DataFrame, settings) -> dict:
    """One hose type as plain data (the ``ctx.map`` item): its hoses, their matched runs (``hose_id`` the
    hose matched), its settings; columns as lists, times as int nanoseconds (UTC)."""
    if "odometer_at" not in life:   # a hose_life without reading times (written before they were kept)
        life = life.assign(odometer_at=pd.NaT)
    return _item(hose_type, _columns(life.sort_values("hose_id"), HOSE_SPEC),
                 _columns(runs.sort_values("run_id"), RUN_SPEC), settings)


def _item(hose_type: str, hoses: dict, runs: dict, settings) -> dict:
    """:func:`hose_type_item` from its columns already converted (:func:`_columns`)."""
    plan = {"present": bool(settings.present), "margin": float(settings.margin), "alpha": float(settings.alpha),
            "power": float(settings.power), "confidence": float(settings.confidence),
            "max_failures": settings.max_failures, "spending": settings.spending,
            "plan_from": settings.sources["margin"]}
    return {"hose_type": hose_type, "hoses": hoses, "runs": runs, "plan": plan}


def _pick(columns: dict, rows) -> dict:
    """The ``rows`` (positions) of converted columns, in that order."""
    return {c: [v[i] for i in rows] for c, v in columns.items()}


def _frame(columns: dict, spec: dict) -> pd.DataFrame:
    """An item's columns back as a DataFrame (times as UTC timestamps, to the nanosecond: the int
    nanoseconds are read as int64, never through a float, whose 53-bit mantissa would round
    today's times by up to 128 ns)."""
    out = {}
    for c, kind in spec.items():
        if kind == "time":
            ns = np.array([_NAT if v is None else int(v) for v in columns[c]], dtype=np.int64)
            out[c] = pd.Series(pd.DatetimeIndex(ns.view("datetime64[ns]")).tz_localize("UTC"))   # not .dt: 3x faster
        else:
            out[c] = (pd.Series(np.array(columns[c], dtype=object), dtype=object) if kind == "text"   # no str inference
                      else pd.Series(np.array(columns[c], dtype=np.float64)))
    return pd.DataFrame(out, columns=list(spec))
