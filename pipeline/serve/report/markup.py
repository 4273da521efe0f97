"""The report's text: its one style sheet, escaping, numbers to significant digits, a column's
name and unit, a run's link and an error in one line. Every page of the report is built from
these; nothing here reads the warehouse."""
from __future__ import annotations

import html
import math
from datetime import datetime
from functools import lru_cache

from pipeline.serve.report.folders import page_name
from schemas.units import column_unit

#: The style sheet of every page, inline (the pages open from disk, with nothing beside them).
CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;margin:0 auto;max-width:1180px;padding:0 20px 40px;color:#1d2330;line-height:1.4}
h1{font-size:1.6em;margin:20px 0 4px}h2{border-bottom:2px solid #d8dce4;padding-bottom:4px;margin-top:34px}
h3{margin:26px 0 6px}h4{margin:14px 0 4px}.meta{color:#5b6475;font-size:.92em}
table{border-collapse:collapse;margin:8px 0 14px;font-size:.84em}th,td{border:1px solid #d8dce4;padding:3px 7px;text-align:left;vertical-align:top}
th{background:#f1f3f7;font-weight:600}th small{font-weight:400;color:#5b6475;white-space:nowrap}td.num{text-align:right;font-variant-numeric:tabular-nums;white-space:nowrap}
.wrap{overflow-x:auto;max-width:100%}
.ok{background:#e3f5e6;color:#16632a;font-weight:600}.bad{background:#fde4e4;color:#9b1c1c;font-weight:600}
.nodata{background:#eef0f3;color:#5b6475}.alert{border:2px solid #c62828;background:#fff3f3;padding:10px 16px;margin:16px 0}
.cards{display:flex;gap:12px;flex-wrap:wrap}.card{border:1px solid #d8dce4;border-radius:6px;padding:8px 14px;min-width:110px}
.card b{display:block;font-size:1.5em}figure{margin:14px 0}figure img{max-width:100%;border:1px solid #d8dce4}
figcaption{color:#3a4252;font-size:.92em;margin-top:4px}.more{color:#5b6475;font-style:italic}
nav.toc{border:1px solid #d8dce4;background:#f8f9fb;padding:8px 18px;margin:14px 0;columns:2;column-gap:30px;font-size:.92em}
nav.toc ul{margin:2px 0;padding-left:18px}nav.toc>ul{padding-left:0;list-style:none}nav.toc li{break-inside:avoid}
details{margin:6px 0 12px}summary{cursor:pointer;color:#2a4d8f}a{color:#2a4d8f}
td.diff-ok{color:#16632a}td.diff-bad{color:#9b1c1c;font-weight:600}
.infobar{display:inline-block;width:180px;height:12px;border:1px solid #9aa3b5;background:#eef0f3;vertical-align:middle}
.infobar span{display:block;height:100%;background:#2a4d8f}
"""


def esc(value) -> str:
    """Any value as escaped HTML text."""
    return html.escape("" if value is None else str(value), quote=True)


def fmt(value, sig: int = 4) -> str:
    """A cell: numbers to ``sig`` significant digits (no float noise), NULL as an em dash; escaped."""
    if value is None:
        return "—"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        if math.isnan(value):
            return "—"
        return esc(significant(value, sig))
    if isinstance(value, datetime):
        return esc(value.strftime("%Y-%m-%d %H:%M:%S %Z").strip())
    if isinstance(value, (list, tuple)):
        return esc(", ".join(str(v) for v in value))
    return esc(value)


def significant(value: float, sig: int = 4) -> str:
    """A float to ``sig`` significant digits: 19.999999999999982 -> 20, 0.0001541 -> 1.541e-04."""
    if value == 0:
        return "0"
    if 1e-3 <= abs(value) < 1e6:
        digits = max(sig - 1 - math.floor(math.log10(abs(value))), 0)
        text = f"{value:.{digits}f}"
        return text.rstrip("0").rstrip(".") if "." in text else text
    return f"{value:.{sig - 1}e}"


@lru_cache(maxsize=4096)
def split_unit(column: str) -> tuple[str, str]:
    """(name in words, unit) of a warehouse column: ``leak_l_min`` -> (``leak``, ``l/min``); the
    unit is the short form of :data:`schemas.units.COLUMN_UNITS` (longest suffix). Kept per column
    name: every run page's result tables ask again for the same few columns (issue 26)."""
    found = column_unit(column, short=True)
    if found is None:
        return column.replace("_", " "), ""
    suffix, unit = found
    return column[: -len(suffix)].replace("_", " "), unit


def run_href(run_id: str, prefix: str = "runs/") -> str:
    """Relative link of a run's page (``report/runs/<safe id>.html``)."""
    return prefix + page_name(run_id)


def one_line_error(exc: BaseException) -> str:
    """An exception as one line of text: ``ValueError: what went wrong``."""
    return " ".join(f"{type(exc).__name__}: {exc}".split())
