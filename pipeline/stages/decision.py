"""The decision (issue 23): per hose type, how much longer force-set hoses live, and the verdict read at every failure.

For every hose type with at least one hose of each adjustment (``force``, ``distance``) in
``hose_life``:

* ``life_effect``: the force / distance life ratio with profile-likelihood bounds
  (:func:`analyses.life_effect.life_effect`; Meeker & Escobar 1998, ch. 8 and 17) on the hoses'
  lives (``hose_life.distance_km`` > 0; failed = exact, removed and running = suspensions);
* ``decision_looks`` / ``decision_look_hoses``: a look at each failure in logbook time order,
  every hose installed by then at its distance then (from its durability runs, matched to the
  hose as the durability stage matches them, :func:`analyses.hose_life.match_runs`; an
  odometer-only hose linear in time), the estimate and its standard error, the boundaries of the
  plan's alpha-spending function and what each look crossed (:mod:`analyses.decision`,
  :mod:`analyses.sequential`; Lan & DeMets 1983, Jennison & Turnbull 2000);
* ``life_verdict``: the sticky verdict, ``no plan`` without a usable ``raw/plan.toml`` (every
  number still computed, the note says what would have been declared).

Settings per hose type from the plan (:meth:`pipeline.raw.plan.Plan.for_hose_type`);
``max_failures`` the plan's, else the sequential design's (:func:`analyses.sequential.design_for`)
frozen at a defined look (:func:`analyses.decision.freeze_look`: the first with ``FEW_FAILURES / 2``
failures of each adjustment), from that look's own common shape and the hoses on test by its
time, and kept for every later look: the same raw/ gives the same maximum whatever the night, and a
past look's boundary never moves. The looks before it do not decide (looks without an estimate);
until it, no look decides and ``max_failures`` is NULL (docs/decision.md, "max_failures frozen at
a look").

Decisions
---------
* It reads ``hose_life`` and ``durability_runs`` (tables) and the logbooks (the installations the
  runs are matched to) and the plan, no run kind: a change to a leakage or PLA run does not
  re-run it, a logbook, a durability run or the plan does.
* Each hose type is one item of ``ctx.map`` (plain data naming every input), twice (its
  ``life_effect``, then its looks): the types run in parallel and one whose hoses, runs and
  settings did not change is not computed again. The look an unset ``max_failures`` is frozen
  at, and the design behind it, are computed inside the looks' task (:func:`_design_here`): the
  frozen look's fit read from the looks already placed, the design
  (:func:`analyses.sequential.design_for`, cached per process by grid shape and hoses on test) in
  the worker pool beside the other hose types' looks, and with them read from the memo on later
  nights (``benchmarks/bench_decision_stage.py`` measures a cold rebuild as a process;
  docs/decision.md, "The decision stage as a process").
* In the rebuild the even designs' boundaries, which every design reads and which depend on alpha and
  the spending only, are kept in ``warehouse/cache/designs-<key>.npz`` (:func:`keep_designs`): computed
  once, then read by the rebuild and each worker instead of each recomputing them (~1 CPU-s a process);
  a file of other code, libraries or form is never used (docs/decision.md, "Session 23").
"""
from __future__ import annotations

import hashlib
import io
import json
import math
import os
import re
import stat
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from analyses.decision import (GROUP, decide, failure_events, freeze_look, look_estimates, look_fits_of, look_hoses,
                               usable_hoses)
from analyses.hose_life import match_runs
from analyses.life_effect import life_effect
from analyses.sequential import FEW_FAILURES, design_for, design_shape
from analyses.sequential_information import NoDesign
from analyses.sequential_table import adopt_table, design_table, holds_table
from analyses.test_plan import hoses_on_test_s
from pipeline.own_files import read_own_file
from pipeline.raw.logbook import merge_logbooks, read_logbooks
from pipeline.stages import Carrying, Reads, StageContext, StageOutput
from pipeline.stages.decision_items import (_NAT, HOSE_SPEC, RUN_SPEC, _columns, _frame, _item, _ns_list, _pick,  # noqa: F401
                                            hose_type_item)
from pipeline.versions import hash_sources, project_imports

NAME = "decision"
READS = Reads(tables=("hose_life", "durability_runs"), logbooks=True, plan=True)
WRITES = ("life_effect", "life_verdict", "decision_looks", "decision_look_hoses")

EFFECT_COLUMNS = ["hose_type", "n_force", "n_failed_force", "n_distance", "n_failed_distance", "model", "shape",
                  "shape_lower", "shape_upper", "life_ratio", "life_ratio_lower", "life_ratio_upper", "confidence",
                  "p_value", "shape_test_p", "note"]
VERDICT_COLUMNS = ["hose_type", "verdict", "margin", "alpha", "power", "confidence", "spending", "max_failures",
                   "max_failures_from", "plan_from", "failures", "information_fraction", "looks", "life_ratio",
                   "se_log_ratio", "z", "boundary_z", "efficacy_lower", "efficacy_upper", "futility_lower",
                   "futility_upper", "rci_lower", "rci_upper", "decided_at", "decided_at_look", "decided_ratio",
                   "decided_lower", "decided_upper", "note"]
LOOK_COLUMNS = ["hose_type", "look", "event_at", "hose_id", "failures", "n_hoses", "total_km", "information_fraction",
                "life_ratio", "se_log_ratio", "z", "boundary_z", "alpha_spent", "efficacy_lower", "efficacy_upper",
                "futility_lower", "futility_upper", "rci_lower", "rci_upper", "crossed", "decides", "note"]
LOOK_HOSE_COLUMNS = ["hose_type", "look", "hose_id", "adjustment", "distance_km", "failed", "distance_from"]
#: Per-look values of :class:`analyses.sequential.SequentialVerdict` on the log scale, shown as ratios.
_RATIO_FIELDS = ("efficacy_lower", "efficacy_upper", "futility_lower", "futility_upper", "rci_lower", "rci_upper")
NO_PLAN = "no plan"
#: The note of a look after the verdict that crossed: its ``crossed`` is the Wald crossing, which the likelihood
#: check (:func:`analyses.decision.likelihood_check`) does not read once the verdict stands.
AFTER_VERDICT = "after the verdict: crossed on the Wald scale, not checked by the profile likelihood"
def effect_of(item: dict) -> dict:
    """``life_effect``'s row of one hose type (module level: picklable for ``ctx.map``).

    Parameters
    ----------
    item : dict
        :func:`hose_type_item` (its ``hoses`` and ``plan`` are read).

    Returns
    -------
    dict
        The row; ``shape`` is the common Weibull shape [-] the design reads (NaN when NULL).
    """
    hoses = item["hoses"]
    km = np.array(hoses["distance_km"], dtype=np.float64)
    use = np.flatnonzero(km > 0)
    adjustment = [hoses["adjustment"][i] for i in use.tolist()]
    if all(a in GROUP for a in adjustment):   # the lists read directly (no frame: a third of the item's time)
        life, failed = km[use], np.array([hoses["status"][i] == "failed" for i in use.tolist()], dtype=bool)
        group = np.array([GROUP[a] for a in adjustment], dtype=int)
    else:   # an adjustment the fit does not know: as before (split_groups says so)
        life = pd.DataFrame({c: hoses[c] for c in ("adjustment", "distance_km", "status")})
        life = life[life["distance_km"] > 0]
        life, failed, group = (life["distance_km"].to_numpy(float), (life["status"] == "failed").to_numpy(),
                               life["adjustment"].map(GROUP).to_numpy(int))
    le = life_effect(life, failed, group, confidence=item["plan"]["confidence"], alpha=item["plan"]["alpha"])
    row = {c: getattr(le, c) for c in EFFECT_COLUMNS if hasattr(le, c)}
    return {**row, "hose_type": item["hose_type"], "confidence": item["plan"]["confidence"]}


def freeze_of(item: dict) -> dict:
    """The look an unset ``max_failures`` is frozen at (:func:`analyses.decision.freeze_look`), as plain
    data (module level: memoised by ``ctx.map``): ``look`` (None: none yet), ``event_at`` [int ns], ``shape``
    [-] of that look's common-shape fit with the reduced-bias adjustment (the design's), ``failures``: (distance-set, force-set) by then."""
    hoses = usable_hoses(_frame(item["hoses"], HOSE_SPEC))
    return _frozen(hoses, _frame(item["runs"], RUN_SPEC), failure_events(hoses))


def _frozen(hoses: pd.DataFrame, runs: pd.DataFrame, events: pd.DataFrame, in_looks: pd.DataFrame | None = None,
            fits: list | None = None) -> dict:
    """:func:`freeze_of` from the item's frames (``in_looks``: their :func:`analyses.decision.look_hoses`, and
    ``fits`` their :func:`analyses.decision.look_fits_of`, when computed already)."""
    look, fit, failures = freeze_look(hoses, runs, events, in_looks, fits)
    at = None if look is None else _ns_list(events["event_at"].iloc[look - 1:look])[0]
    return {"look": look, "event_at": at, "shape": None if fit is None else float(fit.shape), "failures": failures}


def _design_here(item: dict, hoses: pd.DataFrame, runs: pd.DataFrame, events: pd.DataFrame,
                 in_looks: pd.DataFrame, fits: list | None = None) -> list:
    """The item's :func:`design_of` computed inside its own ``ctx.map`` task (in the worker pool): the frozen
    look read from the looks already placed (:func:`_frozen`), its design by :func:`design_failures`
    (cached per process by :func:`analyses.sequential.design_for`: hose types of one grid shape and hoses
    on test share it in a worker)."""
    frozen = _frozen(hoses, runs, events, in_looks, fits) if item["plan"]["max_failures"] is None else None
    ask = design_item(item["plan"], frozen, item["hoses"])
    if ask is not None:   # the even designs' boundaries from the warehouse's file, once a process (keep_designs)
        use_designs(item.get("designs"), ask["alpha"], ask["spending"])
    designed = {} if ask is None else {json.dumps(ask, sort_keys=True): design_failures(ask)}
    return design_of(item, frozen, designed, ask)


def _ns_floats(values: list) -> np.ndarray:
    """An item's int nanoseconds as floats for :func:`analyses.test_plan.hoses_on_test_s` (NaN: None or NaT's int):
    the order of the times kept, without pandas per hose type (session 24) [ns]."""
    return np.array([np.nan if v is None or v == _NAT else v for v in values], dtype=np.float64)


def design_item(plan: dict, frozen: dict | None, hoses: dict) -> dict | None:
    """What :func:`design_failures` needs when the plan leaves ``max_failures`` unset and a look froze
    it (:func:`freeze_of`), else None; ``hoses``: the item's hose columns, whose installations and ends up
    to the frozen look's time give the hoses on test then (:func:`analyses.test_plan.hoses_on_test`)."""
    if plan["max_failures"] is not None or frozen is None or frozen["look"] is None:
        return None
    by = frozen["event_at"]
    ended = [e if e is not None and e <= by else None for e in hoses["ended_at"]]
    mine = [i for i, t in enumerate(hoses["installed_at"]) if t is None or t <= by]
    on_test = hoses_on_test_s(_ns_floats([hoses["installed_at"][i] for i in mine]), _ns_floats([ended[i] for i in mine]),
                              np.array([GROUP.get(hoses["adjustment"][i], -1) for i in mine], dtype=int))
    # on the design grid: hose types whose shapes round alike share one item (one computation)
    return {k: plan[k] for k in ("margin", "alpha", "power", "spending")} | {"shape": design_shape(frozen["shape"]),
                                                                           "hoses": on_test}


def design_of(item: dict, frozen: dict | None, designed: dict, ask: dict | None = None) -> list:
    """The item's ``design``: [max_failures, "plan" or "design", note, the first look that may decide]
    (``ask``: its :func:`design_item`, when known already; it places every hose in time)."""
    plan = item["plan"]
    if plan["max_failures"] is not None:
        return [plan["max_failures"], "plan", None, 1]
    ask = design_item(plan, frozen, item["hoses"]) if ask is None else ask
    if ask is None:
        d, f = frozen["failures"] if frozen else (0, 0)
        return [None, "design", f"max_failures not frozen yet: designed at the first look with {FEW_FAILURES / 2:g} "
                f"failures of each adjustment (so far {d} distance-set, {f} force-set)", None]
    failures, short = designed[json.dumps(ask, sort_keys=True)]
    at = pd.Timestamp(frozen["event_at"], tz="UTC").isoformat()
    if failures is None:   # no design exists for that look's shape (NoDesign): no look decides
        return [None, "design", f"max_failures not frozen at look {frozen['look']} ({at}): {short}; "
                "max_failures in plan.toml lets the test decide", None]
    note = (f"max_failures frozen at look {frozen['look']} ({at}): designed from that look's common shape "
            f"{frozen['shape']:.3g} (reduced-bias, Abernethy) and {ask['hoses'] or 'rare failures, no'} hose(s) on test per adjustment; "
            f"the {frozen['look'] - 1} look(s) before it do not decide (counted without an estimate)")
    if failures < frozen["look"]:   # a look is a failure: the test cannot end before the look that froze it
        note += f"; the design's {failures} is below the {frozen['look']} failures then: the test ends at that look"
        failures = frozen["look"]
    return [failures, "design", "; ".join(n for n in (note, short) if n), frozen["look"]]


def design_failures(item: dict) -> list:
    """``[max_failures, note]`` of the sequential design (:func:`analyses.sequential.design_for`)
    for a :func:`design_item`, the note saying where the figure is likely short (module level:
    memoised by ``ctx.map``)."""
    try:
        d = design_for(item["margin"], item["alpha"], item["power"], item["spending"], item["shape"], item["hoses"])
    except NoDesign as exc:
        return [None, str(exc)]
    return [int(d.failures), d.note]


def _looks_rows(hose_type: str, est: pd.DataFrame, sv, present: bool) -> list[dict]:
    """``decision_looks`` rows from the estimates and the verdict's per-look values."""
    rows = []
    records = (dict(zip(est.columns, values)) for values in zip(*(est[c].tolist() for c in est.columns)))
    for i, e in enumerate(records):
        lr, se = e["log_ratio"], e["se_log_ratio"]
        e["note"] = e["note"] if isinstance(e["note"], str) else None
        row = {"hose_type": hose_type, "look": int(e["look"]), "event_at": e["event_at"], "hose_id": e["hose_id"],
               "failures": int(e["failures"]), "n_hoses": int(e["n_hoses"]), "total_km": e["total_km"],
               "information_fraction": float(sv.information_fraction[i]), "life_ratio": math.exp(lr),
               "se_log_ratio": se, "z": lr / se, "boundary_z": float(sv.boundary_z[i]),
               "alpha_spent": float(sv.alpha_spent[i]), "crossed": sv.crossed[i] or None,
               "decides": bool(present and sv.decided_at == i), "note": e["note"]}
        row.update({f: math.exp(float(getattr(sv, f)[i])) for f in _RATIO_FIELDS})
        late = []
        if i and sv.information_fraction[i] <= sv.information_fraction[i - 1]:
            late.append("no new information (failures past max_failures): shown, does not decide")
        if sv.crossed[i] and sv.decided_at is not None and i > sv.decided_at:
            late.append(AFTER_VERDICT)
        if late:
            row["note"] = "; ".join(n for n in (e["note"], *late) if n)
        rows.append(row)
    return rows


def _verdict_row(item: dict, looks: list[dict], sv, design: tuple) -> dict:
    """``life_verdict``'s row: the settings, the last look, the deciding look and the note."""
    plan = item["plan"]
    row = {"hose_type": item["hose_type"], **{k: plan.get(k) for k in ("margin", "alpha", "power", "confidence",
                                                                      "spending", "plan_from")},
           "max_failures": design[0], "max_failures_from": design[1], "looks": len(looks), "failures": 0,
           "information_fraction": 0.0}
    notes = [design[2]]
    if looks:
        last = looks[-1]
        row.update({k: last[k] for k in ("failures", "information_fraction", "life_ratio", "se_log_ratio", "z",
                                         "boundary_z", *_RATIO_FIELDS)})
        notes.append(sv.note or None)
    else:
        notes.append("no failure yet: no look")
    verdict = sv.verdict if sv is not None else "undecided"
    if sv is not None and sv.decided_at is not None:
        at = looks[sv.decided_at]
        decided = {"decided_at": at["event_at"], "decided_at_look": at["look"], "decided_ratio": at["life_ratio"],
                   "decided_lower": at["rci_lower"], "decided_upper": at["rci_upper"]}
        if plan["present"]:
            row.update(decided)
        else:
            notes.append(f"without a plan it would have been declared {verdict!r} at look {at['look']}")
    row["verdict"] = verdict if plan["present"] else NO_PLAN
    if not plan["present"]:
        notes.insert(0, "no usable raw/plan.toml: built-in settings, no verdict declared")
    row["note"] = "; ".join(n for n in notes if n) or None
    return row


def decide_hose_type(item: dict) -> dict:
    """The looks, and the verdict over them, of one hose type (module level: picklable for ``ctx.map``).

    Parameters
    ----------
    item : dict
        :func:`hose_type_item` (``hose_type``, ``hoses``: hose_life rows, ``runs``: their matched
        durability runs, ``plan``: the hose type's settings), optionally with ``design``: (max_failures
        or None, ``"plan"`` or ``"design"``, note, the first look that may decide) (:func:`design_of`);
        without it the design is computed here (:func:`_design_here`), in the task, from the same looks.

    Returns
    -------
    dict
        ``life_verdict`` and ``decision_looks`` rows (lists of dicts), ``decision_look_hoses``
        (a DataFrame).
    """
    plan, hose_type = item["plan"], item["hose_type"]
    if "parts" in item:   # the design-free parts from their own memoised map (parts_of: session 26)
        p = item["parts"]
        in_looks, fits, est, left_out = p["in_looks"], p["fits"], p["est"], p["left_out"]
        design = tuple(item["design"])
    else:
        life, runs = _frame(item["hoses"], HOSE_SPEC), _frame(item["runs"], RUN_SPEC)
        hoses = usable_hoses(life)
        events = failure_events(hoses)
        in_looks = look_hoses(hoses, runs, events)
        fits = look_fits_of(in_looks, events)   # every look solved once: the frozen look, the estimates, the intervals
        design = tuple(item["design"] if "design" in item else _design_here(item, hoses, runs, events, in_looks, fits))
        est, left_out = look_estimates(in_looks, events, fits), len(life) - len(hoses)
    sv = decide(est, design[0], plan["margin"], plan["alpha"], plan["spending"], in_looks, design[3] or 1, fits=fits)
    looks = _looks_rows(hose_type, est, sv, plan["present"]) if sv is not None else []
    for row in looks[:design[3] - 1] if design[0] is not None else []:
        row["note"] = "; ".join(n for n in (row["note"], f"before look {design[3]}, where max_failures was frozen: "
                                            "does not decide") if n)
    verdict = _verdict_row(item, looks, sv, design)
    if left_out:
        verdict["note"] = "; ".join(n for n in (verdict["note"], f"{left_out} hose(s) without a known distance or "
                                                "time span left out of the looks") if n)
    return {"life_verdict": [verdict], "decision_looks": looks,
            "decision_look_hoses": None if "parts" in item else in_looks.assign(hose_type=hose_type)}


def parts_of(item: dict) -> dict:
    """What a hose type's looks are before any design (module level, memoised by ``ctx.map`` on its
    :func:`freeze_item`, which no plan change moves): the look an unset ``max_failures`` is frozen at
    (``frozen``: :func:`freeze_of`'s), the hoses in each look (``in_looks``), their common-shape fits (``fits``),
    the estimates (``est``) and the hoses left out (``left_out``). A power change that moves the maximum
    re-runs only :func:`decide_hose_type` on them (session 26)."""
    life, runs = _frame(item["hoses"], HOSE_SPEC), _frame(item["runs"], RUN_SPEC)
    hoses = usable_hoses(life)
    events = failure_events(hoses)
    in_looks = look_hoses(hoses, runs, events)
    fits = look_fits_of(in_looks, events)
    return {"frozen": _frozen(hoses, runs, events, in_looks, fits), "in_looks": in_looks, "fits": fits,
            "est": look_estimates(in_looks, events, fits), "left_out": len(life) - len(hoses)}


def _typed(rows: list[dict], columns: list[str], ints=(), times=(), bools=()) -> pd.DataFrame:
    """A table's frame: its columns in order, BIGINT columns as nullable integers, times in UTC."""
    df = pd.DataFrame(rows, columns=columns)
    for c in ints:
        df[c] = pd.array([None if v is None or pd.isna(v) else int(v) for v in df[c]], dtype="Int64")
    for c in times:
        df[c] = pd.to_datetime(df[c], utc=True)
    for c in bools:
        df[c] = df[c].astype(bool)
    for c in columns:
        vals = df[c].tolist()
        if (c not in (*ints, *times, *bools) and df[c].dtype == object and any(isinstance(v, float) for v in vals)
                and all(isinstance(v, float) or v is None for v in vals)):
            df[c] = pd.to_numeric(df[c]).astype("float64")   # NaN -> NULL
    return df


def hose_type_items(ctx: StageContext) -> list[dict]:
    """One :func:`hose_type_item` per hose type with a hose of each adjustment, sorted by hose type."""
    life = ctx.results.get("hose_life")
    if life is None or life.empty:
        return []
    runs = ctx.results.get("durability_runs")
    runs = pd.DataFrame(columns=["run_id", "hose_id", "started_at", "duration_h", "distance_km"]) \
        if runs is None or runs.empty else runs.copy()
    if len(runs):   # the installations the runs are matched to (none to match: the logbooks are not read again)
        events, _problems = read_logbooks(ctx.raw)    # the durability stage reports the logbooks' problems
        runs["hose_id"] = match_runs(merge_logbooks(events)[0], runs)[0]
    else:
        runs["hose_id"] = pd.Series([], dtype=object)
    type_of = dict(zip(life["hose_id"], life["hose_type"]))
    # every column converted once (the conversions are value by value), then each type's rows picked in the
    # order hose_type_item sorts them: hoses by hose_id, runs by run_id (each unique)
    life = life[life["hose_type"].notna()]
    if "odometer_at" not in life:   # a hose_life without reading times (written before they were kept)
        life = life.assign(odometer_at=pd.NaT)
    life = life.sort_values("hose_id", kind="stable")
    hose_cols, run_cols = _columns(life, HOSE_SPEC), _columns(runs.sort_values("run_id", kind="stable"), RUN_SPEC)
    run_types = [type_of.get(h) for h in run_cols["hose_id"]]
    rows_of: dict = {}
    for i, t in enumerate(life["hose_type"].tolist()):
        rows_of.setdefault(t, []).append(i)
    runs_of: dict = {}
    for i, t in enumerate(run_types):
        runs_of.setdefault(t, []).append(i)
    adjustments = hose_cols["adjustment"]
    items = []
    for hose_type in sorted(rows_of, key=str):
        rows = rows_of[hose_type]
        if set(GROUP) <= {adjustments[i] for i in rows}:
            items.append(_item(str(hose_type), _pick(hose_cols, rows), _pick(run_cols, runs_of.get(hose_type, [])),
                               ctx.plan.for_hose_type(str(hose_type))))
    return items


def design_asks(ctx: StageContext, items: list[dict]) -> tuple[list, list]:
    """Per item its frozen look (:func:`freeze_of`, None when the plan sets ``max_failures``) and its
    :func:`design_item` (None when none is needed)."""
    unset = [it for it in items if it["plan"]["max_failures"] is None]
    found = dict(zip([it["hose_type"] for it in unset],
                     ctx.map(freeze_of, [freeze_item(it) for it in unset], label="decision: freeze") if unset else []))
    frozen = [found.get(it["hose_type"]) for it in items]
    return frozen, [design_item(it["plan"], fr, it["hoses"]) for it, fr in zip(items, frozen)]


#: Folder of the warehouse holding the even designs' boundaries between rebuilds (:func:`keep_designs`).
DESIGNS_DIR = "cache"
#: A designs file: ``designs-<key>.npz``, the key a hash of alpha, spending, the code and the libraries.
DESIGNS_FILE = re.compile(r"designs-[0-9a-f]{32}\.npz")
#: The largest designs file read [bytes] (one of alpha 0.05 holds ~13 MB).
DESIGNS_MAX_BYTES = 64 << 20


def designs_path(warehouse: Path, alpha: float, spending: str) -> Path:
    """The file of the even designs of ``alpha`` and ``spending`` under ``warehouse``: its name hashes them,
    the code that computes them (:mod:`analyses.sequential_table` and the project modules it imports) and
    Python's and numpy's and scipy's versions, so a file of other code or libraries is another file."""
    import scipy

    code = hash_sources(sorted(project_imports(Path(sys.modules["analyses.sequential_table"].__file__))))
    key = json.dumps({"format": 1, "alpha": repr(float(alpha)), "spending": spending, "code": code,
                      "env": [sys.version, np.__version__, scipy.__version__]}, sort_keys=True)
    return Path(warehouse) / DESIGNS_DIR / f"designs-{hashlib.sha256(key.encode()).hexdigest()[:32]}.npz"


def _read_designs(path: Path) -> dict | None:
    """The arrays of a designs file, or None: missing, not a regular file in a real folder (no symlink is followed),
    larger than :data:`DESIGNS_MAX_BYTES`, or not an ``.npz`` of plain arrays (no pickle is loaded)."""
    data = read_own_file(path, DESIGNS_MAX_BYTES)
    if data is None:
        return None
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as npz:
            return {name: npz[name] for name in npz.files}
    except Exception:   # damaged, truncated, another format: computed again
        return None


def use_designs(path: str | Path | None, alpha: float, spending: str) -> bool:
    """Adopt the designs file ``path`` in this process (once; :func:`analyses.sequential_table.adopt_table`
    checks every array); False when there is none to adopt (the designs are then computed as needed)."""
    if path is None:
        return False
    if holds_table(alpha, spending):   # this process has them (a worker forked from one that had): none read
        return True
    table = _read_designs(Path(path))
    return table is not None and adopt_table(table, alpha, spending)


def keep_designs(warehouse: Path, items: list[dict]) -> dict:
    """The designs files of the items whose plan leaves ``max_failures`` to the design, by (alpha, spending):
    each read and adopted here, or else computed here and written (atomically) for the next rebuild, before
    the workers that read them are forked (a worker forked earlier reads the file: :func:`_design_here`).
    Other ``designs-*.npz`` files in the folder (of other settings, code or libraries) are deleted when one
    is written; a folder that cannot be written leaves the designs computed, never a failure."""
    pairs = sorted({(it["plan"]["alpha"], it["plan"]["spending"]) for it in items
                    if it["plan"]["max_failures"] is None})
    paths = {pair: designs_path(warehouse, *pair) for pair in pairs}
    for (alpha, spending), path in paths.items():
        if use_designs(path, alpha, spending):
            continue
        table = design_table(alpha, spending)
        try:
            folder = path.parent
            folder.mkdir(exist_ok=True)
            if not stat.S_ISDIR(os.lstat(folder).st_mode):
                continue
            for old in folder.iterdir():
                if DESIGNS_FILE.fullmatch(old.name) and old not in paths.values() and not old.is_symlink():
                    old.unlink(missing_ok=True)
            tmp = folder / f".{path.name}.tmp-{os.getpid()}"
            tmp.unlink(missing_ok=True)
            with os.fdopen(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0), 0o666),
                           "wb") as fh:
                np.savez(fh, **table)
            os.replace(tmp, path)
        except OSError:
            continue
    return {pair: str(path) for pair, path in paths.items()}


def freeze_item(item: dict) -> dict:
    """What :func:`freeze_of` reads of a :func:`hose_type_item`: its hoses and runs (no plan: the frozen look is the
    data's, so a plan change keeps its memo)."""
    return {"hose_type": item["hose_type"], "hoses": item["hoses"], "runs": item["runs"]}


def designed_in_worker(item: dict) -> list:
    """:func:`design_failures` of a :func:`design_item` in a worker (module level for ``ctx.map``, memoised by
    the design's settings): the even designs' file ``item["designs"]`` (:func:`keep_designs`) adopted first."""
    ask = {k: v for k, v in item.items() if k != "designs"}
    use_designs(item.get("designs"), ask["alpha"], ask["spending"])
    return design_failures(ask)


def looks_item(item: dict, design: list) -> dict:
    """The :func:`decide_hose_type` item of a hose type whose ``design`` (:func:`design_of`) is known: its hoses, runs
    and plan without the power (which only the design reads: a power change that leaves ``max_failures`` as it
    was leaves the looks' item, and so their memo, as it was; session 24). ``life_verdict``'s ``power`` is put
    on its row by :func:`run`."""
    return {"hose_type": item["hose_type"], "hoses": item["hoses"], "runs": item["runs"],
            "plan": {k: v for k, v in item["plan"].items() if k != "power"}, "design": design}


def effect_item(item: dict) -> dict:
    """What :func:`effect_of` reads of a :func:`hose_type_item`: the hoses' adjustment, distance and status, the
    plan's confidence and alpha (so that a plan change of another key, e.g. the power, keeps its memo)."""
    hoses = item["hoses"]
    return {"hose_type": item["hose_type"], "hoses": {c: hoses[c] for c in ("adjustment", "distance_km", "status")},
            "plan": {k: item["plan"][k] for k in ("confidence", "alpha")}}


#: Imported before the decision's workers are forked (:meth:`StageContext.map`'s ``warm``).
WARM = ("scipy.special",)


def run(ctx: StageContext) -> StageOutput:
    out = StageOutput()
    items = hose_type_items(ctx)
    if ctx.memo is not None:   # the rebuild: the designs' boundaries kept in the warehouse between rebuilds
        designs = keep_designs(ctx.warehouse, items)
        items = [it | {"designs": designs[it["plan"]["alpha"], it["plan"]["spending"]]}
                 if it["plan"]["max_failures"] is None else it for it in items]
    # scipy.special loaded once here when a result is computed: the pools' workers are forked from this process
    effects = ctx.map(effect_of, [effect_item(it) for it in items], label="decision: life effect", warm=WARM)
    # the frozen look (the data's, memoised whatever the plan), then the designs (what reads the power),
    # then the looks at the design (memoised when their maximum did not move)
    # the looks' design-free parts and frozen look (the data's, memoised whatever the plan: session 26)
    parts = ctx.map(parts_of, [freeze_item(it) for it in items], label="decision: parts", warm=WARM) if items else []
    frozen = [p["frozen"] if it["plan"]["max_failures"] is None else None for it, p in zip(items, parts)]
    asks = [design_item(it["plan"], fr, it["hoses"]) for it, fr in zip(items, frozen)]
    keys = sorted({json.dumps(a, sort_keys=True) for a in asks if a is not None})
    paths = {json.dumps(a, sort_keys=True): it.get("designs") for it, a in zip(items, asks) if a is not None}
    designed = dict(zip(keys, ctx.map(designed_in_worker, [json.loads(k) | {"designs": paths[k]} for k in keys],
                                      label="decision: designs", warm=WARM) if keys else []))
    results = ctx.map(decide_hose_type, [Carrying(looks_item(it, design_of(it, fr, designed, a)), parts=p)
                                         for it, fr, a, p in zip(items, frozen, asks, parts)], label="decision: looks",
                      warm=WARM)
    for it, res in zip(items, results):
        for row in res["life_verdict"]:
            row["power"] = it["plan"]["power"]
    rows = {t: [r for res in results for r in res[t]] for t in ("life_verdict", "decision_looks")}
    rows["life_effect"] = effects
    hoses = [p["in_looks"].assign(hose_type=it["hose_type"]) for it, p in zip(items, parts) if len(p["in_looks"])]
    out.tables["life_effect"] = _typed(rows["life_effect"], EFFECT_COLUMNS,
                                       ints=("n_force", "n_failed_force", "n_distance", "n_failed_distance"))
    out.tables["life_verdict"] = _typed(rows["life_verdict"], VERDICT_COLUMNS,
                                        ints=("max_failures", "failures", "looks", "decided_at_look"),
                                        times=("decided_at",))
    out.tables["decision_looks"] = _typed(rows["decision_looks"], LOOK_COLUMNS, ints=("look", "failures", "n_hoses"),
                                          times=("event_at",), bools=("decides",))
    lh = pd.concat(hoses, ignore_index=True) if hoses else pd.DataFrame(columns=LOOK_HOSE_COLUMNS)
    lh = lh[LOOK_HOSE_COLUMNS].astype({"look": "int64", "failed": bool, "distance_km": "float64"})
    out.tables["decision_look_hoses"] = lh.astype({"hose_type": object, "hose_id": object, "adjustment": object,
                                                   "distance_from": object})
    return out
