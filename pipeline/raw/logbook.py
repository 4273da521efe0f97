"""The hose logbook: read every ``hoses.csv`` under raw/, merge them, and join durability runs.

bench-exports.md, "hoses.csv: the hose logbook": columns ``hose_id, event, at, hose_type,
adjustment, z_rollers_mm, spring_force_n, failure_mode, wall_thickness_mm, distance_km, notes``;
events ``installed``, ``inspected``, ``failed``, ``removed``.

Decisions where the spec is silent
----------------------------------
* **Merging.** Logbooks of every campaign are read in sorted path order and merged by
  ``hose_id``: a hose installed in one campaign may fail in another's logbook. The same event
  (hose, event, time) logged in two logbooks counts once (later copies fill empty fields).
* **Reinstallation.** A hose that was ``removed`` may be ``installed`` again (moved to another
  rig or campaign): its life *continues*, distance accumulating over every installation; the
  removal in between is a pause, not a suspension. Only the last installation's end decides the
  status: ``failed`` (a failure), ``removed`` (a suspension) or ``running`` (still installed,
  censored at its distance so far). A failed hose cannot be reinstalled (quarantined).
* **Rows that make no sense** are quarantined with their line number (1-based, the header is
  line 1) and do not count: missing ``hose_id``, unknown event, unparsable or missing time,
  non-numeric or negative numbers, an adjustment other than ``distance``/``force``, a failure,
  removal or inspection of a hose that is not installed at that time (e.g. failure before its
  installation), a second ``installed`` while installed, any event after a failure.
  A logbook without the ``hose_id``/``event``/``at`` columns, or one that is not CSV text (a NUL
  byte, an unclosed quote, a field over the ``csv`` module's limit), is quarantined as a whole
  with the line: the events after an unclosed quote would be lost or mangled silently.
* **Times** are strict ISO 8601: a date ``2026-01-02``, or a date-time
  ``2026-01-02T08:30[:00[.123]]`` with an optional offset (``Z``, ``+01:00``, ``+0100``,
  ``+01``); a space instead of the ``T`` is accepted (RFC 3339). Without offset they are UTC
  (as for runs). Anything else (``now``, ``today``, ``1/2/2026``, ``2 Jan 2026``) is a
  quarantined row: a relative time would change a hose's life between two rebuilds, and
  ``1/2/2026`` is January or February depending on who reads it.
* **Odometer.** ``distance_km`` of a ``failed``/``removed`` event is read as the hose's
  cumulative distance at that event; the latest reading is used. A reading lower than an
  earlier one of the same hose is quarantined (an odometer does not go back; its event still
  counts, that reading does not) and the hose gets a warning.
* **Logbooks that disagree.** The same event (hose, event, time) logged in two logbooks with
  different values (``hose_type``, ``adjustment``, ``failure_mode``, a number) keeps the first
  logbook's value (sorted path order); the later row is quarantined naming both files and lines,
  and the hose gets a warning in ``hose_life.warnings``. Two installations of one hose that
  overlap (e.g. logged in two campaigns' logbooks at different times) quarantine the later one,
  naming where the first was logged.
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
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.raw.problems import Problem, display_name
from pipeline.raw.walk import walk_raw
from pipeline.raw.rawfile import read_raw_bytes
from pipeline.readers.base import SideCsvError, side_csv_rows

LOGBOOK_NAME = "hoses.csv"
EVENTS = ("installed", "inspected", "failed", "removed")
NUMERIC = ("z_rollers_mm", "spring_force_n", "wall_thickness_mm", "distance_km")
TEXT = ("hose_type", "adjustment", "failure_mode", "notes")
REQUIRED = ("hose_id", "event", "at")
#: Relative disagreement between runs and odometer above which hose_life warns.
ODOMETER_TOLERANCE = 0.02
_EVENT_ORDER = {"installed": 0, "inspected": 1, "failed": 2, "removed": 2}

EVENT_COLUMNS = ["hose_id", "event", "at", *TEXT, *NUMERIC, "campaign", "source_path", "line"]
HOSE_COLUMNS = ["hose_id", "hose_type", "adjustment", "z_rollers_mm", "spring_force_n", "status",
                "failure_mode", "installed_at", "ended_at", "odometer_km", "wall_thickness_mm",
                "n_installations", "campaigns", "intervals", "warnings"]


def find_logbooks(raw: Path) -> list[Path]:
    """Every readable ``hoses.csv`` under ``raw`` (dotted folders skipped, no folder symlink
    followed, a symlink from outside raw/ not read: :func:`pipeline.raw.walk.walk_raw`, whose
    quarantine rows the rebuild reports), sorted by relative path."""
    return [p for p in walk_raw(Path(raw)).side if p.name.lower() == LOGBOOK_NAME]


_ISO_TIME = re.compile(r"\d{4}-\d{2}-\d{2}(?:[T ]\d{2}:\d{2}(?::\d{2}(?:[.,]\d{1,9})?)?"
                       r"(?:Z|[+-]\d{2}(?::?\d{2})?)?)?", re.IGNORECASE)


def parse_time(text: str) -> pd.Timestamp | None:
    """Strict ISO 8601 text as a UTC Timestamp (no offset = UTC); None when it is anything else.

    Accepted: ``YYYY-MM-DD`` and ``YYYY-MM-DD[T ]HH:MM[:SS[.fraction]][Z|+HH:MM|+HHMM|+HH]``.
    Relative words (``now``, ``today``) and locale dates (``1/2/2026``) are refused.
    """
    text = (text or "").strip()
    if not text or not _ISO_TIME.fullmatch(text):
        return None
    try:
        ts = pd.Timestamp(text.replace(",", ".").replace(" ", "T", 1))
    except (ValueError, TypeError, OverflowError):
        return None
    if ts is pd.NaT or pd.isna(ts):
        return None
    return ts.tz_localize("UTC") if ts.tzinfo is None else ts.tz_convert("UTC")


def _number(text: str) -> float:
    value = float(text.strip().replace(",", "."))
    if not math.isfinite(value):
        raise ValueError
    return value


def read_logbook(path: Path, rel: str | None = None, root: Path | None = None) -> tuple[pd.DataFrame, list[Problem]]:
    """One ``hoses.csv`` as event rows, and the rows it cannot use.

    Parameters
    ----------
    path : Path
        The logbook.
    rel : str, optional
        Its path relative to raw/ (used in problems and rows; the campaign is its first folder).
    root : Path, optional
        raw/ (resolved): the file is opened from there without following a symlink out of it
        (default: its own folder).

    Returns
    -------
    (DataFrame, list of Problem)
        Events with columns :data:`EVENT_COLUMNS` (``at`` in UTC, numbers as floats, ``line``
        1-based with the header as line 1); problems with ``stage="logbook"``.
    """
    rel = rel or Path(path).name
    campaign = rel.split("/")[0] if "/" in rel else None
    problems: list[Problem] = []
    # opened without following a symlink out of raw/ (pipeline.raw.rawfile): from raw/ when given
    data = read_raw_bytes(root if root is not None else os.path.dirname(os.path.abspath(path)), path)
    empty = pd.DataFrame(columns=EVENT_COLUMNS)
    header = None
    rows = []
    try:
        parsed = list(side_csv_rows(data))
    except SideCsvError as exc:
        msg, start = exc.args
        problems.append(Problem(rel, f"{msg}; no row of it is read", start, stage="logbook"))
        return empty, problems
    for _start, line, cells in parsed:
        if not any(c.strip() for c in cells):
            continue
        if header is None:
            header = [c.strip().lower() for c in cells]
            missing = [c for c in REQUIRED if c not in header]
            if missing:
                problems.append(Problem(rel, f"logbook header lacks column(s) {', '.join(missing)}", line,
                                        stage="logbook"))
                return pd.DataFrame(columns=EVENT_COLUMNS), problems
            continue
        if len(cells) > len(header) and any(c.strip() for c in cells[len(header):]):
            problems.append(Problem(rel, f"{len(cells)} fields for {len(header)} columns", line, stage="logbook"))
            continue
        row = {h: (cells[i].strip() if i < len(cells) else "") for i, h in enumerate(header)}
        hose = row.get("hose_id", "")
        event = row.get("event", "").lower()
        if not hose:
            problems.append(Problem(rel, "row has no hose_id", line, stage="logbook"))
            continue
        if event not in EVENTS:
            problems.append(Problem(rel, f"hose {hose}: unknown event `{row.get('event', '')}` "
                                         f"(expected {', '.join(EVENTS)})", line, stage="logbook"))
            continue
        at = parse_time(row.get("at", ""))
        if at is None:
            problems.append(Problem(rel, f"hose {hose}: {event} time `{row.get('at', '')}` is not ISO 8601 "
                                         "(YYYY-MM-DD or YYYY-MM-DDTHH:MM[:SS][+HH:MM])", line, stage="logbook"))
            continue
        rec = {"hose_id": hose, "event": event, "at": at, "campaign": campaign, "source_path": rel, "line": line}
        bad = None
        for col in NUMERIC:
            raw_v = row.get(col, "")
            if raw_v == "":
                rec[col] = np.nan
                continue
            try:
                rec[col] = _number(raw_v)
            except ValueError:
                bad = f"hose {hose}: {col} `{raw_v}` is not a number"
                break
            if rec[col] < 0:
                bad = f"hose {hose}: {col} {raw_v} is negative"
                break
        for col in TEXT:
            rec[col] = row.get(col, "") or None
        if bad is None and rec["adjustment"] is not None:
            adj = rec["adjustment"].strip().lower()
            if adj not in ("distance", "force"):
                bad = f"hose {hose}: adjustment `{rec['adjustment']}` is neither distance nor force"
            rec["adjustment"] = adj
        if bad:
            problems.append(Problem(rel, bad, line, stage="logbook"))
            continue
        rows.append(rec)
    return pd.DataFrame(rows, columns=EVENT_COLUMNS), problems


def read_logbooks(raw: Path) -> tuple[pd.DataFrame, list[Problem]]:
    """Every logbook under ``raw``, concatenated (sorted path order), and their problems."""
    raw = Path(raw)
    frames, problems = [], []
    for p in find_logbooks(raw):
        rel = display_name(os.path.relpath(p, os.path.realpath(raw)).replace(os.sep, "/"))
        try:
            df, probs = read_logbook(p, rel, root=os.path.realpath(raw))
        except OSError as exc:
            problems.append(Problem(rel, f"cannot read logbook: {exc}", stage="logbook"))
            continue
        frames.append(df)
        problems += probs
    frames = [f for f in frames if not f.empty]
    events = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(columns=EVENT_COLUMNS)
    return events, problems


@dataclass
class _Hose:
    hose_id: str
    installs: list = field(default_factory=list)  # [start, end, end_event, row]
    inst_row: dict | None = None
    failed: dict | None = None
    last_close: dict | None = None
    wall: float = np.nan
    odo: float = np.nan
    odo_row: dict | None = None
    campaigns: set = field(default_factory=set)
    warnings: list = field(default_factory=list)


def _where(r) -> str:
    return f"{r['source_path']}:{r['line']}"


def _empty(v) -> bool:
    return v is None or (isinstance(v, float) and math.isnan(v)) or (isinstance(v, str) and not v.strip())


def _differ(a, b) -> bool:
    """Both given and different (numbers compared as numbers)."""
    if _empty(a) or _empty(b):
        return False
    if isinstance(a, float) and isinstance(b, float):
        return not math.isclose(a, b, rel_tol=1e-9, abs_tol=0.0)
    return str(a).strip() != str(b).strip()


def _show(v) -> str:
    return f"{v:g}" if isinstance(v, float) else f"`{v}`"


def merge_logbooks(events: pd.DataFrame) -> tuple[pd.DataFrame, list[Problem]]:
    """Merge logbook events into one row per hose.

    Parameters
    ----------
    events : DataFrame
        From :func:`read_logbooks`.

    Returns
    -------
    (DataFrame, list of Problem)
        Hoses with columns :data:`HOSE_COLUMNS` (``intervals``: list of ``(start, end)`` UTC
        Timestamps, end None while installed), and the events that make no sense.
    """
    problems: list[Problem] = []
    if events.empty:
        return pd.DataFrame(columns=HOSE_COLUMNS), problems
    ev = events.copy()
    ev["_order"] = ev["event"].map(_EVENT_ORDER)
    ev["_src"] = range(len(ev))
    ev = ev.sort_values(["hose_id", "at", "_order", "_src"], kind="stable")
    hoses: dict[str, _Hose] = {}
    seen: dict[tuple, dict] = {}
    for r in ev.to_dict("records"):
        hid, event, at = r["hose_id"], r["event"], r["at"]
        key = (hid, event, at)
        h = hoses.setdefault(hid, _Hose(hid))

        def bad(msg):
            problems.append(Problem(r["source_path"], f"hose {hid}: {msg}", int(r["line"]), stage="logbook"))

        if key in seen:  # the same event logged twice (e.g. in two campaigns' logbooks)
            first = seen[key]
            clash = [f"{col} {_show(r[col])} vs {_show(first[col])}" for col in (*TEXT, *NUMERIC)
                     if col != "notes" and _differ(first.get(col), r[col])]
            if clash:
                msg = (f"{event} at {at.isoformat()} disagrees with {_where(first)} ({'; '.join(clash)}); "
                       f"the values of {_where(first)} are used")
                bad(msg)
                h.warnings.append(f"logbooks disagree: {_where(r)} {msg}")
                continue
            for col in (*TEXT, *NUMERIC):
                if _empty(first.get(col)):
                    first[col] = r[col]
            continue
        is_open = bool(h.installs) and h.installs[-1][1] is None

        when = at.isoformat()
        if h.failed is not None:
            bad(f"{event} at {when} after its failure at {h.failed['at'].isoformat()} ({_where(h.failed)})")
            continue
        if event == "installed":
            if is_open:
                bad(f"installed at {when} while still installed since {h.installs[-1][0].isoformat()} "
                    f"({_where(h.installs[-1][3])})")
                continue
            if h.inst_row is not None:
                old = h.inst_row
                for col in ("hose_type", "adjustment"):
                    if r[col] and old[col] and r[col] != old[col]:
                        h.warnings.append(f"reinstalled at {when} with {col} {r[col]} ({_where(r)}; was "
                                          f"{old[col]} at {_where(old)}); grouped under {old[col]}")
                for col in ("hose_type", "adjustment", "z_rollers_mm", "spring_force_n"):
                    if old.get(col) is None or (isinstance(old.get(col), float) and math.isnan(old[col])):
                        old[col] = r[col]
            else:
                h.inst_row = r
            h.installs.append([at, None, None, r])
            h.campaigns.add(r["campaign"])
            seen[key] = r
            continue
        if not is_open:
            if not h.installs:
                bad(f"{event} at {when} before it was installed")
            else:
                bad(f"{event} at {when} while not installed (removed at {h.installs[-1][1].isoformat()})")
            continue
        seen[key] = r
        h.campaigns.add(r["campaign"])
        if event == "inspected":
            if not math.isnan(r["wall_thickness_mm"]):
                h.wall = r["wall_thickness_mm"]
            continue
        h.installs[-1][1] = at
        h.installs[-1][2] = event
        h.last_close = r
        if not math.isnan(r["distance_km"]):
            if h.odo_row is not None and r["distance_km"] < h.odo:
                msg = (f"odometer distance_km {_show(r['distance_km'])} at {when} is lower than "
                       f"{_show(h.odo)} at {h.odo_row['at'].isoformat()} ({_where(h.odo_row)}); an odometer "
                       "does not go back: this reading is not used")
                bad(msg)
                h.warnings.append(f"{_where(r)}: {msg}")
            else:
                h.odo, h.odo_row = r["distance_km"], r
        if event == "failed":
            h.failed = r
    rows = []
    for hid in sorted(hoses):
        h = hoses[hid]
        if not h.installs:
            continue
        inst = h.inst_row
        last = h.installs[-1]
        status = last[2] or "running"
        close = h.last_close if status != "running" else None
        odo = h.odo  # latest odometer reading of any failed/removed event
        rows.append({
            "hose_id": hid,
            "hose_type": inst["hose_type"],
            "adjustment": inst["adjustment"],
            "z_rollers_mm": inst["z_rollers_mm"],
            "spring_force_n": inst["spring_force_n"],
            "status": status,
            "failure_mode": h.failed["failure_mode"] if h.failed is not None else None,
            "installed_at": h.installs[0][0],
            "ended_at": close["at"] if close is not None else pd.NaT,
            "odometer_km": odo,
            "wall_thickness_mm": h.wall,
            "n_installations": len(h.installs),
            "campaigns": sorted(c for c in h.campaigns if c),
            "intervals": [(s, e) for s, e, _k, _r in h.installs],
            "warnings": list(h.warnings),
        })
    return pd.DataFrame(rows, columns=HOSE_COLUMNS), problems


def match_runs(hoses: pd.DataFrame, runs: pd.DataFrame) -> tuple[pd.Series, dict[str, list[str]]]:
    """The hose each durability run belongs to.

    Parameters
    ----------
    hoses : DataFrame
        From :func:`merge_logbooks`.
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
        From :func:`merge_logbooks`.
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
    rows = []
    base = hoses.to_dict("records") if len(hoses) else []
    orphans = sorted({h for h in matched.dropna() if h not in known})
    for hid in orphans:
        base.append({"hose_id": hid, "status": "running", "campaigns": [], "n_installations": 0,
                     "warnings": ["hose is in no hoses.csv logbook"], "odometer_km": np.nan})
    for h in base:
        mine = runs[runs["_hose"] == h["hose_id"]]
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
        rows.append({
            "hose_id": h["hose_id"], "hose_type": h.get("hose_type"), "adjustment": h.get("adjustment"),
            "distance_km": distance,
            "strokes": int(strokes.sum()) if n_runs and unanalysed < n_runs else None,
            "status": h.get("status"), "failure_mode": h.get("failure_mode"), "n_runs": n_runs,
            "z_rollers_mm": h.get("z_rollers_mm"), "spring_force_n": h.get("spring_force_n"),
            "runs_km": runs_km, "odometer_km": odo, "distance_source": source,
            "installed_at": h.get("installed_at"), "ended_at": h.get("ended_at"),
            "n_installations": h.get("n_installations"), "campaigns": list(h.get("campaigns") or []),
            "wall_thickness_mm": h.get("wall_thickness_mm"), "warnings": warnings,
        })
    out = pd.DataFrame(rows, columns=["hose_id", "hose_type", "adjustment", "distance_km", "strokes", "status",
                                      "failure_mode", "n_runs", "z_rollers_mm", "spring_force_n", "runs_km",
                                      "odometer_km", "distance_source", "installed_at", "ended_at",
                                      "n_installations", "campaigns", "wall_thickness_mm", "warnings"])
    out["strokes"] = out["strokes"].astype("Int64")
    out["n_runs"] = out["n_runs"].astype("int64")
    for col in ("installed_at", "ended_at"):
        out[col] = pd.to_datetime(out[col], utc=True, format="ISO8601")
    return out, run_warn


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


__all__ = ["find_logbooks", "read_logbook", "read_logbooks", "merge_logbooks", "match_runs", "hose_life",
           "hose_distance_at", "parse_time", "EVENTS", "ODOMETER_TOLERANCE"]
