"""Rows as an HTML table, the way every table of the report shows them: the unit of a column's
suffix in its header, one number format per column chosen from its range (:func:`column_format`),
a leak under its flow sensor's floor as "< floor" (:data:`FLOORED_COLUMNS`; the stored value
stays; :func:`leak_floors` gives the floor of rows that copy leakage plateaus without their
sensors), a ``sensors`` text in display units and run ids linked to their pages."""
from __future__ import annotations

import math

from pipeline.serve.report.markup import esc, fmt, run_href, significant, split_unit
from schemas.sensors_text import sensor_parts
from schemas.units import display_sensors_text, kg_s_to_l_min_anr

#: Rows of a table shown (the rest: "n more rows: query the warehouse").
MAX_ROWS = 30


def _th(column: str) -> str:
    """A header cell: the column's name in words and its unit."""
    name, unit = split_unit(column)
    return f"<th>{esc(name)}" + (f"<br><small>[{esc(unit)}]</small>" if unit else "") + "</th>"


def _cell(column: str, value, links, number=None) -> str:
    """A body cell: run ids linked (``links``), sensors in display units, numbers in ``number``'s format."""
    if column == "run_id" and isinstance(value, str) and (links is True or (links and value in links)):
        return f'<td><a href="{esc(run_href(value))}">{esc(value)}</a></td>'
    if column == "sensors" and isinstance(value, str):  # stored in SI; shown in the report's units
        return f"<td>{esc(display_sensors_text(value))}</td>"
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return f'<td class="num">{esc(number(value)) if number is not None else fmt(value)}</td>'
    return f"<td>{fmt(value)}</td>"


#: Leak columns that read "< floor" where their value is under the flow sensor's floor (the stored
#: value stays as it is): a mean leak that small, or negative, is the sensor's own scatter.
FLOORED_COLUMNS = ("leak_l_min", "leak_at_5_bar_l_min", "leak_at_6_bar_l_min", "max_leak_l_min")
#: A row's floor of :data:`FLOORED_COLUMNS`: this column when the row has it, else the flow sensor
#: stated in its ``sensors`` text (``leakage_map``), else the floor the caller gives
#: (:func:`leak_floors`: ``hose_leak_growth``, ``seal_envelope``).
FLOOR_COLUMN = "leak_floor_l_min"


def flow_floor_l_min(sensors) -> float | None:
    """Floor of the leak-flow sensor a ``leakage_map.sensors`` text states
    (:func:`schemas.sensors_text.sensor_parts`), in l/min ANR: the larger of its resolution and
    noise (:meth:`analyses.quality.Sensor.floor`); None without one."""
    res, noise, _, unit = sensor_parts(sensors).get("q_leak", (math.nan, math.nan, "", "kg/s"))
    floor = max(res, noise) if unit == "kg/s" else math.nan
    return float(kg_s_to_l_min_anr(floor)) if math.isfinite(floor) and floor > 0 else None


def coarsest_floor_l_min(sensors_texts) -> float | None:
    """Floor of the coarsest flow sensor among ``sensors_texts`` (:func:`flow_floor_l_min` of each)
    [l/min ANR]: the floor of a value from several runs (a mean, a leak copied from a run with
    several plateaus); None when none states one."""
    return max((f for t in (sensors_texts or ()) if (f := flow_floor_l_min(t)) is not None), default=None)


def leak_floors(db, table: str, columns: list[str], rows: list[tuple]) -> list | None:
    """The flow sensor's floor [l/min ANR] of each of ``rows`` (of ``table``, with ``columns``) whose
    leak comes from ``leakage_map`` plateaus without the ``sensors`` they were measured with, read
    from ``leakage_map.sensors`` of ``db``: a row naming a ``run_id`` (``hose_leak_growth``, a
    plateau copied), the coarsest sensor of that run's plateaus; a ``seal_envelope`` row, the
    coarsest of its roller setting's runs that it used (``runs_used``: characterisation runs, or
    hose checks). None for a row without one, and in place of the list when the rows state their
    own floor, have no leak column or the database no ``leakage_map.sensors``."""
    if not rows or not any(c in FLOORED_COLUMNS for c in columns) or FLOOR_COLUMN in columns or \
            "sensors" in columns or not db.has("leakage_map") or "sensors" not in db.columns("leakage_map"):
        return None
    setting = ("chamber", "adjustment", "z_rollers_mm", "spring_force_n")
    if "run_id" in columns:
        k = columns.index("run_id")
        of = floors_by(db, "run_id", [r[k] for r in rows])
        return [of.get(r[k]) for r in rows]
    if table == "seal_envelope" and {*setting, "runs_used"} <= set(columns) and \
            set(setting) <= set(db.columns("leakage_map")):
        hose = "coalesce(hose_id, '') <> ''" if "hose_id" in db.columns("leakage_map") else "false"
        found = db.con.execute(f"SELECT {', '.join(setting)}, CASE WHEN {hose} THEN 'hose_checks' "
                               "ELSE 'characterisation' END, list(DISTINCT sensors) FROM leakage_map GROUP BY ALL"
                               ).fetchall()
        of = {tuple(r[:5]): coarsest_floor_l_min(r[5]) for r in found}
        at = [columns.index(c) for c in (*setting, "runs_used")]
        return [of.get(tuple(r[j] for j in at)) for r in rows]
    return None


def floors_by(db, key: str, ids) -> dict:
    """``{id: floor}``: per ``run_id`` or ``hose_id`` (``key``) of ``ids``, the floor of the coarsest
    flow sensor of its ``leakage_map`` rows (:func:`coarsest_floor_l_min`) [l/min ANR]; an id without
    one, or a database without ``leakage_map``'s ``key`` and ``sensors``, is left out."""
    if not db.has("leakage_map") or not {key, "sensors"} <= set(db.columns("leakage_map")):
        return {}
    found = db.con.execute(f"SELECT {key}, list(DISTINCT sensors) FROM leakage_map WHERE {key} IN (SELECT unnest(?)) "
                           f"GROUP BY {key}", [sorted({str(i) for i in ids if i is not None})]).fetchall()
    return {k: f for k, texts in found if (f := coarsest_floor_l_min(texts)) is not None}


#: A column shows at most this many decimals more than its largest value needs for its digits.
MORE_DECIMALS = 1


def column_format(values, sig: int = 4):
    """One number format for a column (a function float -> text), chosen from its range: fixed
    notation with the decimals its values need for ``sig`` significant digits each (fewer when they
    show the same with fewer; at most :data:`MORE_DECIMALS` past what the largest needs), or
    scientific notation throughout when the largest is under 1e-3 or from 1e6 up. Integers print
    whole; "-0.00" prints "0.00"."""
    finite = [abs(float(v)) for v in values if isinstance(v, float) and math.isfinite(v)]
    hi = max(finite, default=0.0)
    if hi == 0:
        return lambda v: significant(v, sig) if isinstance(v, float) else str(v)
    if not 1e-3 <= hi < 1e6:
        return lambda v: (str(v) if not isinstance(v, float) else "—" if math.isnan(v)
                          else "0" if v == 0 else f"{v:.{sig - 1}e}")
    top = max(sig - 1 - math.floor(math.log10(hi)), 0)
    # as many decimals as the values need to show their own ``sig`` digits (3.5 beside 1300 keeps its
    # .5), at most MORE_DECIMALS past what the largest needs: a value far under the largest is noise there
    need = max((sig - 1 - math.floor(math.log10(v)) for v in finite if v), default=0)
    limit = max(0, min(need, top + MORE_DECIMALS))
    shown = [float(f"{float(significant(v, sig)):.{limit}f}") for v in finite]
    decimals = next(d for d in range(limit + 1) if all(float(f"{v:.{d}f}") == v for v in shown))

    def number(v) -> str:
        if not isinstance(v, float):
            return str(v)
        if not math.isfinite(v):
            return "—" if math.isnan(v) else str(v)
        text = f"{v:.{decimals}f}"
        return text.lstrip("-") if float(text) == 0 else text
    number.decimals = decimals
    return number


def _row_floor(columns: list[str], row: tuple, given: float | None = None) -> float | None:
    """The flow sensor's floor of a row [l/min ANR]: its own (:data:`FLOOR_COLUMN`, ``sensors``),
    else ``given``; None when neither states one."""
    if FLOOR_COLUMN in columns:
        v = row[columns.index(FLOOR_COLUMN)]
        return float(v) if isinstance(v, (int, float)) and math.isfinite(v) and v > 0 else None
    if "sensors" in columns:
        return flow_floor_l_min(row[columns.index("sensors")])
    return float(given) if isinstance(given, (int, float)) and math.isfinite(given) and given > 0 else None


def _under_floor(value, floor) -> bool:
    """Whether ``value`` is a finite number under ``floor``."""
    return floor is not None and isinstance(value, (int, float)) and not isinstance(value, bool) \
        and math.isfinite(value) and abs(value) < floor


def floor_text(value, floor: float | None, number=None) -> str | None:
    """``< floor`` for a leak ``value`` under ``floor`` [l/min ANR] (rounded up to ``number``'s
    decimals, a :func:`column_format`; one significant digit without it); None for a value to show."""
    return _floor_text(floor, number) if _under_floor(value, floor) else None


def _floor_text(floor: float, number) -> str:
    """``< floor``, the floor rounded up to the column's decimals (at least one significant digit)."""
    decimals = getattr(number, "decimals", None)
    if decimals is None:
        return "< " + significant(floor, 1)
    d = max(decimals, -math.floor(math.log10(floor)))
    return f"< {math.ceil(floor * 10 ** d - 1e-9) / 10 ** d:.{d}f}"


def html_table(columns: list[str], rows: list[tuple], max_rows: int = MAX_ROWS, total: int | None = None,
               links: bool | set = True, floors: list | None = None) -> str:
    """Rows as a table: units from the column names in the headers, run ids linked to run pages
    (``links``: True for every run id, or the set of ids that have a page); ``floors``: per row,
    the flow sensor's floor [l/min ANR] of a row that states none of its own (:func:`leak_floors`)."""
    if not rows:
        return '<p class="more">no rows</p>'
    head = "".join(_th(c) for c in columns)
    shown = rows[:max_rows]
    given = list(floors or [])[:len(shown)]
    given += [None] * (len(shown) - len(given))
    floors = [_row_floor(columns, r, g) for r, g in zip(shown, given)] if any(c in FLOORED_COLUMNS for c in columns) \
        else [None] * len(shown)
    numbers = []  # one format per column, from the values it shows as numbers
    for j, c in enumerate(columns):
        values = [r[j] for r, f in zip(shown, floors) if not (c in FLOORED_COLUMNS and _under_floor(r[j], f))]
        numbers.append(column_format(values) if any(isinstance(v, float) for v in values) else None)
    body = []
    for r, floor in zip(shown, floors):
        cells = [f'<td class="num">{esc(_floor_text(floor, n))}</td>' if c in FLOORED_COLUMNS and _under_floor(v, floor)
                 else _cell(c, v, links, n) for c, v, n in zip(columns, r, numbers)]
        body.append("<tr>" + "".join(cells) + "</tr>")
    total = len(rows) if total is None else total
    more = f'<p class="more">{total - max_rows} more rows: query the warehouse</p>' if total > max_rows else ""
    return (f'<div class="wrap"><table><thead><tr>{head}</tr></thead><tbody>{"".join(body)}</tbody>'
            f"</table></div>{more}")
