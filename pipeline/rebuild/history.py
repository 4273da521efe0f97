"""What a new warehouse carries over from the previous one: the findings' last change, and
``rebuild_log``, the log of the last rebuilds.

A finding's ``change`` (overturned, now holds, ...) and ``changed_at`` are sticky: when ``holds``
differs from the previous warehouse they are the new change and the rebuild's start; while
``holds`` stays the same they are carried over, so a second rebuild in the same night does not
clear an overturned finding. :func:`finding_change` is that rule, once: the incremental rebuild
applies it to the new findings (:func:`compare_findings`, pandas), the no-op rebuild to the
carried-over database (:func:`carry_findings`, DuckDB; a no-op imports no pandas).
"""
from __future__ import annotations

from datetime import datetime, timezone
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # pandas: only the incremental path, imported where used (a no-op needs none)
    import duckdb
    import pandas as pd

#: Rows of ``rebuild_log`` carried from one warehouse to the next.
HISTORY_ROWS = 200


def _change(before: bool | None, holds: bool | None) -> str | None:
    """The change of a finding from the previous warehouse's ``holds`` to this one's, if any."""
    if before is True and holds is False:
        return "overturned"
    if before is False and holds is True:
        return "now holds"
    if before is None and holds is not None:
        return "new data"
    if before is not None and holds is None:
        return "no longer checkable"
    return None


def finding_change(before: bool | None, holds: bool | None, last: tuple, now: datetime) -> tuple:
    """``(change, changed_at)`` of a finding the previous warehouse had.

    Parameters
    ----------
    before, holds : bool or None
        ``holds`` in the previous warehouse and now (None: not checkable).
    last : (str or None, datetime or None)
        The previous warehouse's ``(change, changed_at)`` of the finding (missing values as None).
    now : datetime
        The rebuild's start.

    Returns
    -------
    (str or None, datetime or None)
        The new change and ``now``; without one, ``last`` when it is complete (both set), else
        ``(None, None)``.
    """
    new = _change(before, holds)
    if new is not None:
        return new, now
    ch, at = last
    return (ch, at) if ch is not None and at is not None else (None, None)


def compare_findings(findings: pd.DataFrame, previous: dict[str, bool | None], had_previous: bool,
                     previous_changes: dict[str, tuple] | None = None, now: datetime | None = None) -> pd.DataFrame:
    """Add ``previous_holds``, ``change`` (overturned, now holds, ...) and ``changed_at`` to the findings.

    ``change`` / ``changed_at`` follow :func:`finding_change` for a finding of the previous
    warehouse (``previous``: {finding_id: holds}; ``previous_changes``: {finding_id: (change,
    changed_at)}); a finding it did not have (or a first warehouse) has neither.
    """
    import pandas as pd

    if findings is None or findings.empty:
        return findings
    now = now or datetime.now(timezone.utc)
    previous_changes = previous_changes or {}

    def known(value):
        return None if value is None or pd.isna(value) else value

    df = findings.copy()
    prev_holds, change, changed_at = [], [], []
    for fid, holds in zip(df["finding_id"], df["holds"]):
        holds = None if pd.isna(holds) else bool(holds)
        before = previous.get(fid) if fid in previous else None
        before = None if before is None or pd.isna(before) else bool(before)
        prev_holds.append(before)
        ch, at = None, None
        if had_previous and fid in previous:
            last = previous_changes.get(fid, (None, None))
            ch, at = finding_change(before, holds, (known(last[0]), known(last[1])), now)
        change.append(ch)
        changed_at.append(at)
    df["previous_holds"] = pd.array(prev_holds, dtype="boolean")
    df["change"] = pd.array(change, dtype="string")
    df["changed_at"] = pd.to_datetime(pd.Series(changed_at, index=df.index, dtype=object), utc=True)
    return df


def carry_findings(con: duckdb.DuckDBPyConnection, now: datetime) -> None:
    """:func:`compare_findings` of a warehouse with itself, in its database (the no-op rebuild:
    every finding holds as before, its last change is carried over)."""
    rows = con.execute("SELECT rowid, holds, change, changed_at FROM findings").fetchall()
    if rows:
        con.executemany("UPDATE findings SET previous_holds = ?, change = ?, changed_at = ? WHERE rowid = ?",
                        [[holds, *finding_change(holds, holds, (ch, at), now), rowid] for rowid, holds, ch, at in rows])


def numbered_history(history: pd.DataFrame | None) -> pd.DataFrame | None:
    """``rebuild_log`` of the previous warehouse with its ``seq`` (None when empty). A log from
    before the column is numbered 1, 2, ... in its stored order (the order rebuilds appended it)."""
    if history is None or history.empty:
        return None
    if "seq" not in history.columns or history["seq"].isna().any():
        history = history.assign(seq=range(1, len(history) + 1))
    return history


def append_log(history: pd.DataFrame | None, row: dict) -> pd.DataFrame:
    """The new warehouse's ``rebuild_log``: the last :data:`HISTORY_ROWS` - 1 rows of the previous
    one (:func:`numbered_history`) and this rebuild's ``row``, numbered next."""
    import pandas as pd

    old_log = numbered_history(history)
    log_row = pd.DataFrame([row])
    log_row["seq"] = int(old_log["seq"].max()) + 1 if old_log is not None else 1
    if old_log is None:
        return log_row
    return pd.concat([old_log.tail(HISTORY_ROWS - 1), log_row], ignore_index=True)


def append_log_in_database(con: duckdb.DuckDBPyConnection, row: dict) -> None:
    """:func:`append_log` in the carried-over database of a no-op rebuild."""
    row = {**row, "seq": con.execute("SELECT coalesce(max(seq), 0) + 1 FROM rebuild_log").fetchone()[0]}
    con.execute(f"INSERT INTO rebuild_log ({', '.join(row)}) VALUES ({', '.join('?' * len(row))})",
                list(row.values()))
    con.execute("DELETE FROM rebuild_log WHERE rowid NOT IN "
                f"(SELECT rowid FROM rebuild_log ORDER BY rowid DESC LIMIT {HISTORY_ROWS})")
