"""The decision as people read it (``pneubench decision``, the report's "The decision"): per hose
type the verdict in words, the information fraction, the looks and the plan, from the tables of
the decision and test_plan stages (``life_verdict``, ``life_effect``, ``decision_looks``,
``test_plan``, see ``docs/warehouse.md``), read through the door (read-only).

The verdict is the group-sequential test's (Lan & DeMets 1983; Jennison & Turnbull 2000, ch. 9:
the repeated confidence interval of the last deciding look); the interval in its sentence is
``life_effect``'s profile-likelihood interval at the plan's confidence (Meeker & Escobar 1998,
sec. 8.3), or the last look's repeated interval when the fit gave none, and the sentence says
which. The words of each verdict and why are in ``docs/decision.md``, "Where people see it".
A number the tables hold as NULL is said to be absent, never filled in.
"""
from __future__ import annotations

import difflib
from dataclasses import dataclass
from datetime import date, datetime, timezone
from pathlib import Path

from pipeline.serve.door import connect_readonly
from pipeline.serve.remaining_life import dict_rows as _dicts
from pipeline.serve.remaining_life import num as _num
from pipeline.serve.remaining_life import read_sensitivity, running_lines, sensitivity_words
from pipeline.serve.remaining_life import table_names as _tables

#: Verdicts that are declared (they stick: later looks do not change them).
DECIDED = ("force longer", "distance longer", "no practical difference")
#: Width of the information bar in the terminal [characters].
BAR_WIDTH = 30


@dataclass(frozen=True)
class HoseDecision:
    """One hose type's decision: its ``life_verdict`` row, its ``life_effect`` row ({} when
    none), its ``decision_looks`` rows in look order and its ``test_plan`` rows (by power)."""

    hose_type: str
    verdict: dict
    effect: dict
    looks: list[dict]
    plans: list[dict]


def missing_line(con) -> str | None:
    """One line when the warehouse has no decision to show (no ``life_verdict`` table: built
    before the decision stage; or no row: no hose type tested both ways yet), else None."""
    if "life_verdict" not in _tables(con):
        return ("no decision tables in this warehouse (built before the decision stage): "
                "`pneubench rebuild` adds them")
    if con.execute("SELECT count(*) FROM life_verdict").fetchone()[0] == 0:
        return "no hose type has hoses of both adjustments (force and distance) yet: nothing to decide"
    return None


def read_decisions(con, hose_type: str | None = None) -> list[HoseDecision]:
    """Every hose type's decision (by hose type), or only ``hose_type``'s.

    Raises
    ------
    QueryError
        When ``hose_type`` is not one of ``life_verdict``: one line naming it and the known ones.
    """
    have = _tables(con)
    verdicts = _dicts(con, "SELECT * FROM life_verdict ORDER BY hose_type") if "life_verdict" in have else []
    known = [str(v["hose_type"]) for v in verdicts]
    if hose_type is not None:
        if hose_type not in known:
            from pipeline.serve.query import QueryError  # (with duckdb: kept off the rebuild's start-up)

            raise QueryError(_unknown(hose_type, known))
        verdicts = [v for v in verdicts if str(v["hose_type"]) == hose_type]

    def per_type(table: str, order: str) -> dict[str, list[dict]]:
        out: dict[str, list[dict]] = {}
        if table in have:
            for r in _dicts(con, f'SELECT * FROM "{table}" ORDER BY hose_type, {order}'):
                out.setdefault(str(r["hose_type"]), []).append(r)
        return out

    effects, looks = per_type("life_effect", "hose_type"), per_type("decision_looks", "look")
    plans = per_type("test_plan", "target_power")
    return [HoseDecision(str(v["hose_type"]), v, (effects.get(str(v["hose_type"])) or [{}])[0],
                         looks.get(str(v["hose_type"]), []), plans.get(str(v["hose_type"]), []))
            for v in verdicts]


def _unknown(hose_type: str, known: list[str]) -> str:
    """The line for a hose type the decision tables do not have."""
    if not known:
        return f"no hose type {hose_type!r}: the warehouse has no decision for any hose type"
    near = difflib.get_close_matches(hose_type, known, n=1)
    shown = ", ".join(repr(k) for k in known[:20]) + (f", ... ({len(known)} in all)" if len(known) > 20 else "")
    return f"no hose type {hose_type!r}" + (f" (did you mean {near[0]!r}?)" if near else "") + f"; known: {shown}"


# -- words ------------------------------------------------------------------------------------------
def ratio_text(value) -> str:
    """A life ratio to three significant digits (``1.82``); a dash when absent."""
    x = _num(value)
    return "—" if x is None else f"{x:.3g}"


def ordinal(n: int) -> str:
    """1st, 2nd, 3rd, 4th, ..., 11th, 12th, 13th, ..., 21st."""
    n = int(n)
    suffix = "th" if 10 <= n % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(n % 10, "th")
    return f"{n}{suffix}"


def _pct(value) -> str:
    """A fraction as a percentage with the lab's space (``90 %``)."""
    return f"{100 * value:.0f} %"


def _interval(lower, upper, label: str, invert: bool = False) -> str:
    """``90 % CI 1.31-2.53x`` (bounds swapped and inverted for ``invert``); an open side is said."""
    lo, hi = _num(lower), _num(upper)
    if invert:
        lo, hi = (1 / hi if hi else None), (1 / lo if lo else None)
    if lo is None and hi is None:
        return f"no {label}"
    if lo is None:
        return f"{label} up to {ratio_text(hi)}x, open below"
    if hi is None:
        return f"{label} from {ratio_text(lo)}x, open above"
    return f"{label} {ratio_text(lo)}-{ratio_text(hi)}x"


def _estimate(d: HoseDecision) -> tuple[float, object, object, str] | None:
    """(ratio, lower, upper, interval label) of the sentence: ``life_effect``'s profile-likelihood
    interval, else the last look's repeated interval; None when neither has an estimate."""
    e, v = d.effect, d.verdict
    if _num(e.get("life_ratio")) is not None:
        conf = _num(e.get("confidence")) or _num(v.get("confidence"))
        return _num(e["life_ratio"]), e.get("life_ratio_lower"), e.get("life_ratio_upper"), \
            (f"{_pct(conf)} CI" if conf is not None else "CI")
    if _num(v.get("life_ratio")) is not None:
        alpha = _num(v.get("alpha"))
        return _num(v["life_ratio"]), v.get("rci_lower"), v.get("rci_upper"), \
            (f"repeated {_pct(1 - alpha)} CI" if alpha is not None else "repeated CI")
    return None


def _decided(d: HoseDecision, invert: bool) -> str:
    """``; decided on 2026-03-02 at the 14th failure (then ...)`` of a declared verdict."""
    v = d.verdict
    at = v.get("decided_at")
    look = v.get("decided_at_look")
    failures = next((lk.get("failures") for lk in d.looks if lk.get("look") == look), None) or look
    out = "; decided" + (f" on {_day(at)}" if at is not None else "") + \
        (f" at the {ordinal(failures)} failure" if failures is not None else "")
    if _num(v.get("decided_ratio")) is not None:
        r = _num(v["decided_ratio"])
        alpha = _num(v.get("alpha"))
        label = f"repeated {_pct(1 - alpha)} CI" if alpha is not None else "repeated CI"
        out += (f" (then {ratio_text(1 / r if invert else r)}x, "
                f"{_interval(v.get('decided_lower'), v.get('decided_upper'), label, invert)})")
    return out


def _day(at) -> str:
    """A moment's UTC date (``2026-03-02``)."""
    if isinstance(at, datetime):
        return (at.astimezone(timezone.utc) if at.tzinfo else at).strftime("%Y-%m-%d")
    return str(at)


def _so_far(d: HoseDecision) -> str:
    """``after 12 of 170 planned failures`` (or ``after 12 failures`` without a maximum)."""
    n, m = d.verdict.get("failures"), d.verdict.get("max_failures")
    n = 0 if n is None else int(n)
    return f"after {n} " + (f"of {int(m)} planned failures" if m is not None else f"failure{'s' if n != 1 else ''}")


def verdict_words(d: HoseDecision) -> str:
    """The verdict of one hose type in one sentence (the report's and the terminal's)."""
    t, v = d.hose_type, d.verdict
    verdict = v.get("verdict")
    est = _estimate(d)
    if verdict in ("force longer", "distance longer") and est is not None:
        invert = verdict == "distance longer"
        r, lo, hi, label = est
        who, x = ("distance", 1 / r) if invert else ("force", r)
        if x <= 1:  # the verdict stays while the data go on: say so rather than "0.95x longer"
            return (f"{who}-set {t} hoses live longer (declared), but the estimate has since moved to "
                    f"{ratio_text(x)}x ({_interval(lo, hi, label, invert)}){_decided(d, invert)}")
        return (f"{who}-set {t} hoses live {ratio_text(x)}x longer ({_interval(lo, hi, label, invert)})"
                f"{_decided(d, invert)}")
    if verdict == "no practical difference":
        m = _num(v.get("margin"))
        band = f"within 1/{m:g}..{m:g}" if m is not None else "within the margin"
        now = f": {ratio_text(est[0])}x ({_interval(est[1], est[2], est[3])})" if est else ""
        return (f"no practical difference for {t} hoses: the force / distance life ratio is {band}{now}"
                f"{_decided(d, False)}")
    shown = (f"force / distance life ratio {ratio_text(est[0])}x ({_interval(est[1], est[2], est[3])})"
             if est else "no estimate of the force / distance life ratio yet")
    if verdict == "undecided":
        return f"not yet: {t} {shown} {_so_far(d)}"
    if verdict == "no plan":
        crossed = next((lk for lk in d.looks if lk.get("crossed")), None)
        seen = (f"; under the built-in defaults the {ordinal(crossed.get('failures') or crossed.get('look'))} "
                f"failure's data showed '{crossed['crossed']}'" if crossed else "")
        return (f"no plan.toml: no verdict is declared without the lab's plan (raw/plan.toml); {t} {shown} "
                f"{_so_far(d)}{seen}")
    return f"{verdict or 'no verdict'}: {t} {shown} {_so_far(d)}" + (_decided(d, False) if verdict in DECIDED else "")


def information_words(d: HoseDecision) -> str:
    """``34 % of the information: 58 of 170 failures (maximum from the plan)``."""
    v = d.verdict
    frac, n, m = _num(v.get("information_fraction")), v.get("failures"), v.get("max_failures")
    frm = {"plan": "maximum from the plan", "design": "maximum from the design"}.get(v.get("max_failures_from"))
    counts = f"{0 if n is None else int(n)} of {int(m)} failures" if m is not None else \
        f"{0 if n is None else int(n)} failures, no maximum"
    head = f"{_pct(frac)} of the information" if frac is not None else "information fraction unknown"
    return f"{head}: {counts}" + (f" ({frm})" if frm else "")


def text_bar(fraction, width: int = BAR_WIDTH) -> str:
    """The information fraction as a bar of ``width`` characters (``[#####.....]``)."""
    x = _num(fraction)
    filled = 0 if x is None else round(min(max(x, 0.0), 1.0) * width)
    return "[" + "#" * filled + "." * (width - filled) + "]"


def _plan_row(d: HoseDecision, power) -> dict | None:
    """The ``test_plan`` row of target ``power`` (None when there is none)."""
    p = _num(power)
    return next((r for r in d.plans if p is not None and _num(r.get("target_power")) is not None
                 and abs(_num(r["target_power"]) - p) < 1e-9), None)


def _plan_part(row: dict) -> str:
    """``11 more failures, about 6 more hoses per adjustment, verdict expected by 2026-08`` of one row."""
    need, have = row.get("failures_needed"), row.get("failures")
    if need is None:
        return "no number of failures" + (f": {row['note']}" if row.get("note") else "")
    more = max(int(need) - int(have or 0), 0)
    if more == 0:
        return f"the {int(need)} failures it needs are reached"
    parts = [f"{more} more failure{'s' if more != 1 else ''}"]
    if row.get("more_hoses_per_adjustment") is not None:
        parts.append(f"about {int(row['more_hoses_per_adjustment'])} more hoses per adjustment")
    if _num(row.get("more_km")) is not None:
        parts.append(f"about {_num(row['more_km']):,.0f} km more testing")
    when = row.get("expected_decision_date")
    if isinstance(when, (date, datetime)):
        pace = " at the last 30 days' pace" if str(row.get("capacity_from") or "").startswith("measured") else ""
        parts.append(f"verdict expected by {when:%Y-%m}{pace}")
    else:
        parts.append("no date (bench capacity unknown)")
    return ", ".join(parts)


def plan_words(d: HoseDecision) -> str:
    """The plan to reach a verdict: for the plan's power, then for the other target power."""
    if d.verdict.get("verdict") in DECIDED:
        return "decided: no more failures are needed for this verdict"
    if not d.plans:
        return "no test plan for this hose type"
    power = _num(d.verdict.get("power"))
    first = _plan_row(d, power) or d.plans[0]
    out = f"{_plan_part(first)} ({_pct(_num(first['target_power']) or 0)} power"
    now = _num(first.get("power_now"))
    out += (f"; {_pct(now)} chance of a verdict with the hoses on test now)" if now is not None else ")")
    for r in d.plans:
        if r is not first and _num(r.get("target_power")) is not None:
            out += f"; for {_pct(_num(r['target_power']))} power: {_plan_part(r)}"
    return out


# -- the terminal -------------------------------------------------------------------------------------
#: The columns of the looks table in the terminal (bounds as intervals, ratios to 3 digits).
LOOK_COLUMNS = ("look", "date", "failed", "failures", "info", "ratio", "repeated CI", "efficacy", "futility",
                "crossed", "decides")


def _bounds(lower, upper) -> str:
    """``0.61-1.64`` (a dash for an absent side; empty when both are)."""
    lo, hi = _num(lower), _num(upper)
    return "" if lo is None and hi is None else f"{ratio_text(lo)}-{ratio_text(hi)}"


def look_rows(d: HoseDecision) -> list[tuple]:
    """The looks of one hose type as rows of :data:`LOOK_COLUMNS` (text)."""
    return [(lk.get("look"), _day(lk["event_at"]) if lk.get("event_at") is not None else "", lk.get("hose_id"),
             lk.get("failures"),
             _pct(_num(lk["information_fraction"])) if _num(lk.get("information_fraction")) is not None else "",
             ratio_text(lk.get("life_ratio")), _bounds(lk.get("rci_lower"), lk.get("rci_upper")),
             _bounds(lk.get("efficacy_lower"), lk.get("efficacy_upper")),
             _bounds(lk.get("futility_lower"), lk.get("futility_upper")), lk.get("crossed") or "",
             "yes" if lk.get("decides") else "") for lk in d.looks]


def _block(d: HoseDecision, looks: bool, width: int | None, sensitivity: list[dict]) -> list[str]:
    """The lines of one hose type: verdict, information bar, plan, note, the verdict under each
    failure definition (``sensitivity``, none before the remaining_life stage), and its looks."""
    from pipeline.serve.formats import format_table

    import textwrap

    def wrapped(head: str, text: str) -> list[str]:
        return textwrap.wrap(text, width, initial_indent=head, subsequent_indent=" " * 15) if width else [head + text]

    lines = [*wrapped("", f"{d.hose_type}: {verdict_words(d)}"),
             *wrapped("  information  ", f"{text_bar(d.verdict.get('information_fraction'))} {information_words(d)}"),
             *wrapped("  plan         ", plan_words(d))]
    if d.verdict.get("note"):
        lines += wrapped("  note         ", str(d.verdict["note"]))
    if sensitivity:
        lines += wrapped("  definitions  ", sensitivity_words(sensitivity))
    if not looks:
        lines += wrapped("  looks        ", f"{len(d.looks)}: pneubench decision --hose-type {_quoted(d.hose_type)} "
                                            "lists them")
    elif d.looks:
        types = ["BIGINT" if c in ("look", "failures") else "VARCHAR" for c in LOOK_COLUMNS]
        lines += ["", format_table(list(LOOK_COLUMNS), types, look_rows(d), width=width)]
    else:
        lines.append("  looks        none yet (no failure)")
    return lines


def _quoted(text: str) -> str:
    """``text`` as one shell word (quoted when it has to be)."""
    import shlex

    return shlex.quote(text)


def decision_text(warehouse: str | Path, hose_type: str | None = None, width: int | None = None) -> str:
    """What ``pneubench decision`` prints: every hose type's verdict, information and plan (and
    with ``hose_type`` that one alone, with its looks), then the running hoses nearest their end
    first (:func:`~pipeline.serve.remaining_life.running_lines`); one line when there is nothing to show.

    Raises
    ------
    FileNotFoundError
        When there is no warehouse.
    QueryError
        For a ``hose_type`` the decision tables do not have (the line names the known ones).
    """
    con = connect_readonly(Path(warehouse))
    try:
        missing = missing_line(con) if hose_type is None else None
        if missing:
            return missing
        decisions = read_decisions(con, hose_type)
        sensitivity = read_sensitivity(con)
        out: list[str] = []
        for d in decisions:
            out += _block(d, hose_type is not None, width, sensitivity.get(d.hose_type, [])) + [""]
        out += running_lines(con, hose_type, width)
    finally:
        con.close()
    return "\n".join(out).rstrip("\n")
