"""The hose logbook: read every ``hoses.csv`` under raw/ and merge them into one row per hose.

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
* **Runs and life**: how durability runs are matched to hoses and a hose's life is counted
  is the analysis's: :mod:`analyses.hose_life`.
"""
from __future__ import annotations

import math
import os
import re
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.raw.problems import Problem, display_name
from pipeline.raw.rawfile import read_raw_bytes
from pipeline.raw.walk import walk_raw
from pipeline.readers.base import SideCsvError, side_csv_rows

LOGBOOK_NAME = "hoses.csv"
EVENTS = ("installed", "inspected", "failed", "removed")
NUMERIC = ("z_rollers_mm", "spring_force_n", "wall_thickness_mm", "distance_km")
TEXT = ("hose_type", "adjustment", "failure_mode", "notes")
REQUIRED = ("hose_id", "event", "at")
_EVENT_ORDER = {"installed": 0, "inspected": 1, "failed": 2, "removed": 2}

EVENT_COLUMNS = ["hose_id", "event", "at", *TEXT, *NUMERIC, "campaign", "source_path", "line"]
HOSE_COLUMNS = ["hose_id", "hose_type", "adjustment", "z_rollers_mm", "spring_force_n", "status",
                "failure_mode", "installed_at", "ended_at", "odometer_km", "wall_thickness_mm",
                "n_installations", "campaigns", "intervals", "warnings", "odometer_at"]


#: Raw trees a rebuild has walked, while its stages run (:func:`walked`): real path -> (the walk's
#: logbooks, :func:`read_logbooks`' result once read).
_WALKED: dict[str, list] = {}


@contextmanager
def walked(raw: Path, side: list[Path]):
    """Within it, :func:`find_logbooks` of ``raw`` gives the logbooks among ``side`` (the side files
    of the walk the rebuild already made of ``raw``: :meth:`pipeline.raw.tree.RawTree.listing`)
    instead of walking raw/ again, and :func:`read_logbooks` reads them once for every stage that
    asks (issue 26: the durability and decision stages each walked raw/ and parsed the logbooks)."""
    key = os.path.realpath(raw)
    _WALKED[key] = [[p for p in side if p.name.lower() == LOGBOOK_NAME], None]
    try:
        yield
    finally:
        _WALKED.pop(key, None)


def find_logbooks(raw: Path) -> list[Path]:
    """Every readable ``hoses.csv`` under ``raw`` (dotted folders skipped, no folder symlink
    followed, a symlink from outside raw/ not read: :func:`pipeline.raw.walk.walk_raw`, whose
    quarantine rows the rebuild reports), sorted by relative path (the rebuild's own walk of it
    within :func:`walked`)."""
    known = _WALKED.get(os.path.realpath(raw))
    if known is not None:
        return list(known[0])
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
    # opened without following a symlink out of raw/ (pipeline.raw.rawfile): from raw/ when given
    data = read_raw_bytes(root if root is not None else os.path.dirname(os.path.abspath(path)), path)
    try:
        parsed = list(side_csv_rows(data))
    except SideCsvError as exc:
        msg, start = exc.args
        return pd.DataFrame(columns=EVENT_COLUMNS), [Problem(rel, f"{msg}; no row of it is read", start,
                                                             stage="logbook")]
    return _events(parsed, rel, campaign)


def _events(parsed: list, rel: str, campaign: str | None) -> tuple[pd.DataFrame, list[Problem]]:
    """The event rows of a logbook's CSV rows ``(first line, line, cells)``, and the rows that
    cannot be used (a header without :data:`REQUIRED` columns: the whole file)."""
    problems: list[Problem] = []
    header = None
    rows = []
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
        rec, bad = _event(header, cells)
        if bad:
            problems.append(Problem(rel, bad, line, stage="logbook"))
            continue
        rows.append({**rec, "campaign": campaign, "source_path": rel, "line": line})
    return pd.DataFrame(rows, columns=EVENT_COLUMNS), problems


def _event(header: list[str], cells: list[str]) -> tuple[dict | None, str | None]:
    """One logbook row as an event (hose, event, time, texts and numbers), or why it makes no sense."""
    if len(cells) > len(header) and any(c.strip() for c in cells[len(header):]):
        return None, f"{len(cells)} fields for {len(header)} columns"
    row = {h: (cells[i].strip() if i < len(cells) else "") for i, h in enumerate(header)}
    hose = row.get("hose_id", "")
    event = row.get("event", "").lower()
    if not hose:
        return None, "row has no hose_id"
    if event not in EVENTS:
        return None, f"hose {hose}: unknown event `{row.get('event', '')}` (expected {', '.join(EVENTS)})"
    at = parse_time(row.get("at", ""))
    if at is None:
        return None, (f"hose {hose}: {event} time `{row.get('at', '')}` is not ISO 8601 "
                      "(YYYY-MM-DD or YYYY-MM-DDTHH:MM[:SS][+HH:MM])")
    rec = {"hose_id": hose, "event": event, "at": at}
    bad = _numbers(row, rec, hose)
    for col in TEXT:
        rec[col] = row.get(col, "") or None
    if bad is None and rec["adjustment"] is not None:
        adj = rec["adjustment"].strip().lower()
        if adj not in ("distance", "force"):
            bad = f"hose {hose}: adjustment `{rec['adjustment']}` is neither distance nor force"
        rec["adjustment"] = adj
    return (None, bad) if bad else (rec, None)


def _numbers(row: dict, rec: dict, hose: str) -> str | None:
    """Put the :data:`NUMERIC` columns of a row into ``rec`` (NaN when empty); why one is not a
    non-negative number, or None."""
    for col in NUMERIC:
        raw_v = row.get(col, "")
        if raw_v == "":
            rec[col] = np.nan
            continue
        try:
            rec[col] = _number(raw_v)
        except ValueError:
            return f"hose {hose}: {col} `{raw_v}` is not a number"
        if rec[col] < 0:
            return f"hose {hose}: {col} {raw_v} is negative"
    return None


def read_logbooks(raw: Path) -> tuple[pd.DataFrame, list[Problem]]:
    """Every logbook under ``raw``, concatenated (sorted path order), and their problems (read
    once within :func:`walked`; each caller gets its own copy)."""
    known = _WALKED.get(os.path.realpath(raw))
    if known is not None:
        if known[1] is None:
            known[1] = _read_logbooks(Path(raw))
        events, problems = known[1]
        return events.copy(), [replace(p) for p in problems]
    return _read_logbooks(Path(raw))


def _read_logbooks(raw: Path) -> tuple[pd.DataFrame, list[Problem]]:
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
    if events.empty:
        return pd.DataFrame(columns=HOSE_COLUMNS), []
    ev = events.copy()
    ev["_order"] = ev["event"].map(_EVENT_ORDER)
    ev["_src"] = range(len(ev))
    ev = ev.sort_values(["hose_id", "at", "_order", "_src"], kind="stable")
    merge = _Merge()
    for r in ev.to_dict("records"):
        merge.add(r)
    rows = [_hose_row(merge.hoses[hid]) for hid in sorted(merge.hoses) if merge.hoses[hid].installs]
    return pd.DataFrame(rows, columns=HOSE_COLUMNS), merge.problems


@dataclass
class _Merge:
    """Logbook events merged one by one, in time order per hose (:func:`merge_logbooks`)."""

    hoses: dict[str, _Hose] = field(default_factory=dict)
    seen: dict[tuple, dict] = field(default_factory=dict)  # (hose, event, time) -> its first row
    problems: list[Problem] = field(default_factory=list)

    def bad(self, r: dict, msg: str) -> None:
        """An event that makes no sense: a quarantine row naming its logbook and line."""
        self.problems.append(Problem(r["source_path"], f"hose {r['hose_id']}: {msg}", int(r["line"]),
                                     stage="logbook"))

    def add(self, r: dict) -> None:
        """One event on top of the hose's history so far."""
        hid, event, at = r["hose_id"], r["event"], r["at"]
        key = (hid, event, at)
        h = self.hoses.setdefault(hid, _Hose(hid))
        if key in self.seen:  # the same event logged twice (e.g. in two campaigns' logbooks)
            self._repeated(h, r, self.seen[key])
            return
        is_open = bool(h.installs) and h.installs[-1][1] is None
        when = at.isoformat()
        if h.failed is not None:
            self.bad(r, f"{event} at {when} after its failure at {h.failed['at'].isoformat()} ({_where(h.failed)})")
            return
        if event == "installed":
            self._installed(h, r, is_open)
            return
        if not is_open:
            if not h.installs:
                self.bad(r, f"{event} at {when} before it was installed")
            else:
                self.bad(r, f"{event} at {when} while not installed (removed at {h.installs[-1][1].isoformat()})")
            return
        self.seen[key] = r
        h.campaigns.add(r["campaign"])
        if event == "inspected":
            if not math.isnan(r["wall_thickness_mm"]):
                h.wall = r["wall_thickness_mm"]
            return
        self._closed(h, r)

    def _repeated(self, h: _Hose, r: dict, first: dict) -> None:
        """An event logged again: its values must agree with the first row's (which then fills
        only its empty fields); a disagreement is a quarantine row and a hose warning."""
        clash = [f"{col} {_show(r[col])} vs {_show(first[col])}" for col in (*TEXT, *NUMERIC)
                 if col != "notes" and _differ(first.get(col), r[col])]
        if clash:
            msg = (f"{r['event']} at {r['at'].isoformat()} disagrees with {_where(first)} ({'; '.join(clash)}); "
                   f"the values of {_where(first)} are used")
            self.bad(r, msg)
            h.warnings.append(f"logbooks disagree: {_where(r)} {msg}")
            return
        for col in (*TEXT, *NUMERIC):
            if _empty(first.get(col)):
                first[col] = r[col]

    def _installed(self, h: _Hose, r: dict, is_open: bool) -> None:
        """An installation: a new interval of the hose's life (refused while still installed);
        a reinstallation keeps the first one's type and adjustment, warning when they differ."""
        when = r["at"].isoformat()
        if is_open:
            self.bad(r, f"installed at {when} while still installed since {h.installs[-1][0].isoformat()} "
                        f"({_where(h.installs[-1][3])})")
            return
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
        h.installs.append([r["at"], None, None, r])
        h.campaigns.add(r["campaign"])
        self.seen[(r["hose_id"], r["event"], r["at"])] = r

    def _closed(self, h: _Hose, r: dict) -> None:
        """A failure or removal: the end of the open installation, with its odometer reading
        (refused when lower than an earlier one: an odometer does not go back)."""
        h.installs[-1][1] = r["at"]
        h.installs[-1][2] = r["event"]
        h.last_close = r
        if not math.isnan(r["distance_km"]):
            if h.odo_row is not None and r["distance_km"] < h.odo:
                msg = (f"odometer distance_km {_show(r['distance_km'])} at {r['at'].isoformat()} is lower than "
                       f"{_show(h.odo)} at {h.odo_row['at'].isoformat()} ({_where(h.odo_row)}); an odometer "
                       "does not go back: this reading is not used")
                self.bad(r, msg)
                h.warnings.append(f"{_where(r)}: {msg}")
            else:
                h.odo, h.odo_row = r["distance_km"], r
        if r["event"] == "failed":
            h.failed = r


def _hose_row(h: _Hose) -> dict:
    """A merged hose as a row of :data:`HOSE_COLUMNS`: status from its last installation's end."""
    inst = h.inst_row
    last = h.installs[-1]
    status = last[2] or "running"
    close = h.last_close if status != "running" else None
    odo = h.odo  # latest odometer reading of any failed/removed event
    return {
        "hose_id": h.hose_id,
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
        "odometer_at": h.odo_row["at"] if h.odo_row is not None else pd.NaT,
    }


__all__ = ["find_logbooks", "read_logbook", "read_logbooks", "merge_logbooks", "parse_time", "EVENTS"]
