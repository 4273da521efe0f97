"""Remaining life as people read it (the report's "Running hoses" and the sensitivity of the
verdict, ``pneubench decision``'s list of running hoses): the remaining_life stage's tables
(``hose_rul``, ``rul_backtest``, ``decision_sensitivity``, see ``docs/warehouse.md``) and the leak
path behind each prediction (``hose_leak_growth``), read through the door (read-only).

The numbers are the stage's: the remaining kilometres are prediction intervals at the plan's
``confidence`` (``weibull``: the life model conditioned on survival to the hose's distance,
Meeker & Escobar 1998, ch. 12; ``degradation``: the hose's own leak path in a random-effects
model run to the limit, Lu & Meeker 1993), each shown with the backtest's coverage of its
(hose type, adjustment, method) so that a reader sees how far to trust it. A number the tables
hold as NULL is said to be absent, with the table's note, never filled in. An older warehouse
without these tables says "remaining life not computed" (never an error). What is shown and why:
``docs/decision.md``, "Remaining life: what the reader sees".
"""
from __future__ import annotations

import math
from dataclasses import dataclass

#: The methods of ``hose_rul`` in the order they are shown.
METHODS = ("weibull", "degradation")
#: The failure definitions of ``decision_sensitivity`` in the order they are shown.
DEFINITIONS = ("logbook", "leak limit", "leak limit x0.5", "leak limit x2")
#: Running hoses the terminal lists without ``--hose-type`` (nearest their end first).
MAX_TERMINAL_HOSES = 20
#: The line for a warehouse built before the remaining_life stage.
NOT_COMPUTED = ("remaining life not computed in this warehouse (built before the remaining_life stage): "
                "`pneubench rebuild` adds it")


@dataclass(frozen=True)
class RunningHose:
    """One running hose: its ``hose_rul`` rows by method (``rows[method]``)."""

    hose_type: str
    hose_id: str
    adjustment: str
    distance_km: float | None
    rows: dict

    def nearest_km(self) -> float | None:
        """The smallest remaining-life median over the methods that have one (None: none has)."""
        known = [m for m in (num(r.get("rul_median_km")) for r in self.rows.values()) if m is not None]
        return min(known) if known else None

    def notes(self) -> str:
        """The notes of its rows, each named by its method (``degradation: fewer than 3 ...``)."""
        return "; ".join(f"{m}: {self.rows[m]['note']}" for m in _ordered(self.rows) if self.rows[m].get("note"))

    def row(self, key: str) -> dict:
        """The first of its rows that has ``key`` (the plan's leak limit and pressure are the same on each)."""
        return next((r for r in (self.rows[m] for m in _ordered(self.rows)) if r.get(key) is not None), {})


def num(value) -> float | None:
    """A finite number, else None (NULL, NaN and inf are absent)."""
    if value is None or isinstance(value, bool):
        return None
    try:
        x = float(value)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def _ordered(keys) -> list[str]:
    """Methods ``keys`` in the order of :data:`METHODS`, unknown ones after (by name)."""
    return sorted(keys, key=lambda k: (METHODS.index(k) if k in METHODS else len(METHODS), str(k)))


def table_names(con) -> set[str]:
    """The tables of the warehouse ``con`` is connected to."""
    return {r[0] for r in con.execute("SELECT table_name FROM duckdb_tables() "
                                      "WHERE database_name = current_database()").fetchall()}


def dict_rows(con, sql: str, params=()) -> list[dict]:
    """The rows of ``sql`` as dicts by column name."""
    cur = con.execute(sql, list(params))
    cols = [d[0] for d in cur.description]
    return [dict(zip(cols, r)) for r in cur.fetchall()]


def rul_missing(con) -> str | None:
    """:data:`NOT_COMPUTED` when the warehouse has no ``hose_rul`` (built before the stage), else None."""
    return NOT_COMPUTED if "hose_rul" not in table_names(con) else None


def end_order(hose: RunningHose) -> tuple:
    """Nearest its end first: the smallest median over the methods with a number; the hoses
    without one last (by hose type and id)."""
    near = hose.nearest_km()
    return (near is None, near if near is not None else 0.0, hose.hose_type, hose.hose_id)


def read_running(con, hose_type: str | None = None) -> list[RunningHose]:
    """The running hoses of ``hose_rul`` (only ``hose_type``'s when given), nearest their end first;
    [] when the table is absent."""
    if "hose_rul" not in table_names(con):
        return []
    where, params = ("WHERE hose_type = ?", [hose_type]) if hose_type is not None else ("", [])
    by_hose: dict[tuple, dict] = {}
    for r in dict_rows(con, f"SELECT * FROM hose_rul {where} ORDER BY hose_type, hose_id, method", params):
        by_hose.setdefault((str(r["hose_type"]), str(r["hose_id"])), {})[str(r["method"])] = r
    out = []
    for (t, h), rows in by_hose.items():
        first = rows[_ordered(rows)[0]]
        out.append(RunningHose(t, h, str(first.get("adjustment") or ""), num(first.get("distance_km")), rows))
    return sorted(out, key=end_order)


def read_backtest(con) -> dict[tuple, dict]:
    """``rul_backtest`` by (hose type, adjustment, method); {} when the table is absent."""
    if "rul_backtest" not in table_names(con):
        return {}
    return {(str(r["hose_type"]), str(r["adjustment"]), str(r["method"])): r
            for r in dict_rows(con, "SELECT * FROM rul_backtest")}


def read_sensitivity(con) -> dict[str, list[dict]]:
    """``decision_sensitivity`` by hose type, each in the order of :data:`DEFINITIONS`; {} when absent."""
    if "decision_sensitivity" not in table_names(con):
        return {}
    out: dict[str, list[dict]] = {}
    for r in dict_rows(con, "SELECT * FROM decision_sensitivity ORDER BY hose_type"):
        out.setdefault(str(r["hose_type"]), []).append(r)
    rank = {d: i for i, d in enumerate(DEFINITIONS)}
    return {t: sorted(rows, key=lambda r: (rank.get(r.get("definition"), len(rank)), str(r.get("definition"))))
            for t, rows in out.items()}


def differs(row: dict, rows: list[dict]) -> bool:
    """Whether ``row``'s verdict differs from the ``logbook`` row's (both present, not the logbook row).

    A definition whose data cannot give a life ratio (no hose crossed the limit yet, too few
    crossings in an adjustment) is ``undecided`` for want of data, not a flip: not marked."""
    logbook = next((r for r in rows if r.get("definition") == "logbook"), None)
    return (logbook is not None and row is not logbook and row.get("verdict") is not None
            and num(row.get("life_ratio")) is not None
            and logbook.get("verdict") is not None and row["verdict"] != logbook["verdict"])


# -- words ------------------------------------------------------------------------------------------
def km_text(value) -> str:
    """A distance in km: whole kilometres with the thousands marked (``1,240``) from 100 km, three
    significant digits below; a dash when absent."""
    x = num(value)
    if x is None:
        return "—"
    return f"{x:,.0f}" if abs(x) >= 100 else f"{x:.3g}"


def rul_text(row: dict | None) -> str:
    """``1,240 km [610-2,380]`` of one ``hose_rul`` row; ``—`` when it has no median (the note is
    said beside it, :meth:`RunningHose.notes`)."""
    if not row or num(row.get("rul_median_km")) is None:
        return "—"
    lo, hi = row.get("rul_lower_km"), row.get("rul_upper_km")
    bounds = f" [{km_text(lo)}-{km_text(hi)}]" if num(lo) is not None or num(hi) is not None else ""
    return f"{km_text(row['rul_median_km'])} km{bounds}"


def _pct(value) -> str:
    return f"{100 * value:.0f} %"


def coverage_text(row: dict | None) -> str:
    """``backtest: 86 % of 40 intervals held (nominal 90 %)``; what the backtest could not tell, with its note."""
    if not row:
        return "backtest: none"
    n, cov, conf = row.get("n_predictions"), num(row.get("coverage")), num(row.get("confidence"))
    note = f" ({row['note']})" if row.get("note") else ""
    if cov is None or not n:
        return f"backtest: no interval to check{note}"
    nominal = f" (nominal {_pct(conf)})" if conf is not None else ""
    return f"backtest: {_pct(cov)} of {int(n)} intervals held{nominal}"


def interval_name(hoses: list[RunningHose]) -> str:
    """``90 % prediction interval``, or ``prediction interval at each hose type's plan confidence``
    when the hoses' plans differ (or do not say)."""
    levels = {num(r.get("confidence")) for h in hoses for r in h.rows.values()}
    if len(levels) == 1 and None not in levels:
        return f"{_pct(levels.pop())} prediction interval"
    return "prediction interval at each hose type's plan confidence"


def limit_text(row: dict) -> str:
    """``2 l/min at 6 bar`` of a row with ``leak_limit_l_min`` and ``leak_pressure_bar``; "" without a limit."""
    lim, p = num(row.get("leak_limit_l_min")), num(row.get("leak_pressure_bar"))
    if lim is None:
        return ""
    return f"{lim:.3g} l/min" + (f" at {p:.3g} bar" if p is not None else "")


def ratio_interval(row: dict) -> str:
    """``1.82x (90 % CI 1.31-2.53x)`` of a row's life ratio; ``—`` without one."""
    r = num(row.get("life_ratio"))
    if r is None:
        return "—"
    lo, hi, conf = num(row.get("life_ratio_lower")), num(row.get("life_ratio_upper")), num(row.get("confidence"))
    if lo is None and hi is None:
        return f"{r:.3g}x"
    label = f"{_pct(conf)} CI" if conf is not None else "CI"
    return f"{r:.3g}x ({label} {'—' if lo is None else f'{lo:.3g}'}-{'—' if hi is None else f'{hi:.3g}'}x)"


def sensitivity_words(rows: list[dict]) -> str:
    """The verdict under each failure definition in one line for the terminal; a verdict that differs
    from the logbook's is marked ``<- differs``; the leak rows' common note said once."""
    parts = []
    for r in rows:
        name = str(r.get("definition"))
        limit = limit_text(r)
        head = f"{name} ({limit})" if limit else name
        if r.get("verdict") is None:
            parts.append(f"{head}: —" + (f" ({r['note']})" if r.get("note") else ""))
        else:
            parts.append(f"{head}: {r['verdict']}, {ratio_interval(r)}" + (" <- differs" if differs(r, rows) else ""))
    return "; ".join(parts)


# -- the terminal -------------------------------------------------------------------------------------
def running_lines(con, hose_type: str | None, width: int | None) -> list[str]:
    """``pneubench decision``'s running hoses: nearest their end first (the first
    :data:`MAX_TERMINAL_HOSES` without ``hose_type``), then the backtest of the groups shown."""
    from pipeline.serve.formats import format_table

    missing = rul_missing(con)
    if missing:
        return _wrapped(missing, width)
    hoses = read_running(con, hose_type)
    if not hoses:
        return ["Running hoses: none" + (f" of {hose_type}" if hose_type is not None else "")]
    shown = hoses if hose_type is not None else hoses[:MAX_TERMINAL_HOSES]
    out = _wrapped(f"Running hoses, nearest their end first (remaining km: median [{interval_name(shown)}]):", width)
    cols = ["hose type", "hose", "adjustment", "now km", *METHODS, "leak now / limit", "note"]
    rows = [(h.hose_type, h.hose_id, h.adjustment, km_text(h.distance_km), *(rul_text(h.rows.get(m)) for m in METHODS),
             _leak_now(h), h.notes()) for h in shown]
    out.append(format_table(cols, ["VARCHAR"] * len(cols), rows, n_total=len(hoses), width=width))
    if len(shown) < len(hoses):
        out += _wrapped(f"({len(hoses) - len(shown)} more running hoses: pneubench decision --hose-type T lists "
                        "all of a type's)", width)
    backtest = read_backtest(con)
    out += _wrapped("How far to trust them (each method's intervals on the hoses that have failed):", width)
    groups = {(h.hose_type, h.adjustment, m) for h in shown for m in h.rows}
    rank = {m: i for i, m in enumerate(METHODS)}
    for t, a, m in sorted(groups, key=lambda g: (g[0], g[1], rank.get(g[2], len(rank)), g[2])):
        out += _wrapped(f"{t} {a} {m}: {coverage_text(backtest.get((t, a, m)))}", width, "  ")
    return out


def _wrapped(text: str, width: int | None, indent: str = "") -> list[str]:
    """``text`` as lines of at most ``width`` characters (one line without a width)."""
    import textwrap

    return textwrap.wrap(text, width, initial_indent=indent, subsequent_indent=indent + "  ") if width \
        else [indent + text]


def _leak_now(h: RunningHose) -> str:
    """``0.41 / 2 l/min at 6 bar``; ``no limit`` when the plan sets none."""
    r = h.row("leak_limit_l_min")
    if not r:
        return "no limit"
    now = num(h.row("leak_now_l_min").get("leak_now_l_min"))
    return f"{'—' if now is None else f'{now:.3g}'} / {limit_text(r)}"


# -- the leak path --------------------------------------------------------------------------------------
def leak_paths(con, hoses: list[RunningHose]) -> dict[str, list[tuple[float, float]]]:
    """Each hose's leak path at its plan's ``leak_pressure_bar``, the points the ``remaining_life``
    stage fitted: :func:`pipeline.stages.remaining_life.leak_paths` on its hose type's
    ``hose_leak_growth`` rows (the same rows, the same pressure matching); (distance [km], leak
    [l/min]) by distance. {} without ``hose_leak_growth`` or ``hose_life``."""
    from pipeline.stages.remaining_life import leak_paths as stage_paths

    target = {(h.hose_type, h.hose_id): num(h.row("leak_pressure_bar").get("leak_pressure_bar")) for h in hoses}
    wanted = {k: p for k, p in target.items() if p is not None}
    if not wanted or not {"hose_leak_growth", "hose_life"} <= table_names(con):
        return {}
    types = sorted({t for t, _ in wanted})
    growth = con.execute(
        "SELECT l.hose_type, g.hose_id, g.run_id, g.chamber, g.distance_km, g.pressure_bar, g.leak_l_min "
        "FROM hose_leak_growth g JOIN hose_life l USING (hose_id) WHERE l.hose_type IN (SELECT unnest(?))",
        [types]).df()
    out: dict[str, list[tuple[float, float]]] = {}
    by_type: dict[tuple, set] = {}
    for (hose_type, hose_id), pressure in wanted.items():
        by_type.setdefault((hose_type, pressure), set()).add(hose_id)
    for (hose_type, pressure), ids in sorted(by_type.items()):
        pts, _note = stage_paths(growth[growth["hose_type"] == hose_type].drop(columns="hose_type"), float(pressure))
        for hid, g in pts[pts["hose_id"].isin(ids)].groupby("hose_id", sort=True):
            out[str(hid)] = sorted(zip(g["distance_km"].astype(float), g["leak_l_min"].astype(float)))
    return out
