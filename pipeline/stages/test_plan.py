"""Stage: the test plan (issue 23), what it takes each hose type's durability test to decide.

One ``test_plan`` row per hose type with hoses of both adjustments in ``hose_life`` and per
target power (the plan's, and 0.9; one row when they are equal), from :mod:`analyses.test_plan`:

* ``failures_needed``: :func:`analyses.sequential.design_for` for the plan's margin, alpha,
  spending and the target power, at ``life_effect.shape`` (1.0 when NULL, noted) and the hose
  type's hoses on test per adjustment (:func:`analyses.test_plan.hoses_on_test`, from every hose's
  installation and end; failures rare when none is known): the same number the decision stage
  uses as ``max_failures`` when the plan leaves it unset.
* ``power_now``: Monte Carlo from the fitted common-shape Weibull and the current censored state,
  run to the decision stage's ``max_failures`` (``life_verdict``: the plan's, or the design's frozen
  at a look, :func:`analyses.decision.freeze_look`; while none is frozen, ``failures_needed`` at
  the plan's power, noted); the same for both rows of a hose type. ``failures_needed`` keeps
  following the current shape: it answers "what would it take now".
* ``more_hoses_per_adjustment``, ``more_km`` (the fewest hoses and their km, all on test at once:
  :func:`analyses.test_plan.more_testing`), and ``expected_decision_date`` = the latest event in
  the data (not the wall clock: the same raw/ gives the same table) plus the days the lab's
  ``benches`` (failed hoses replaced) take to decide or reach ``failures_needed``
  (:func:`analyses.bench_schedule.bench_schedule`'s median hose-km over ``benches * km_per_day``), the
  capacity from the plan or measured from the hose type's own durability runs of the last 30 days
  (``capacity_from``; known before the simulations, which need the benches; until session 20 it was
  measured from every hose type's runs together, the lab's benches given to each type).

Seeds: no stage is handed a digest of its inputs, so each hose type's simulations are seeded from
a sha256 of its own ``hose_life`` rows (id, adjustment, status, distance), its plan settings but the
power and ``max_failures`` (since session 24: they reach the simulations through the designs only) and
its ``life_effect`` shape: a hose type whose data did not change keeps its figures, whatever
else changed. Each hose type is an item of three maps of ``ctx.map`` (the stage's worker pool, memoised per
item across rebuilds): its designs (one per target power: :func:`needed_of`), its ``power_now``
(:func:`power_of`, keyed by the maximum it runs to) and its schedules and ``more_testing``
(:func:`plan_hose_type`, one item per row since session 25, keyed by the row's ``failures_needed``), so that a plan
change of the power re-runs only what it moved (the 0.9 rows' simulations stay in the memo); since session 27 the
boundaries of every maximum those run to come from a fourth map (:func:`boundaries_of`, once per maximum, memoised),
carried by the items (:class:`~pipeline.stages.context.Carrying`, under ``boundaries``: one list per
maximum an item runs to, None where there is none), not computed again in each worker (up to 1.4-2.1 CPU-s a worker
after a power change at 200 hose types before; ~1 CPU-s once now, for the new maxima). Since session 22 the replicates come in batches until the figure's Monte Carlo
error is small enough (``power_now``: mc_se <= 0.01, ``n_simulations`` what was drawn; the date: its
median's error <= 5 %). Sessions 22-24 read a hose type's two rows on one set of the benches' replicates
(:func:`analyses.bench_schedule.bench_schedules`); since session 25 each row draws its own (to its own
``failures_needed``), always alone (the same bytes whatever the memo holds), so that the 0.9 row outlives a power
change.
"""
from __future__ import annotations

import functools
import hashlib
import json
import math

import numpy as np
import pandas as pd

from analyses.life_effect import SEPARATE, common_shape_fit
from analyses.sequential import design_for, design_shape
from analyses.sequential_boundaries import efficacy_boundaries
from analyses.sequential_information import NoDesign
from analyses.bench_schedule import SCHEDULE_SIMULATIONS, BenchSchedule, bench_schedules
from analyses.test_plan import (CAPACITY_DAYS, N_SIMULATIONS, HoseState, MoreTesting, decision_date,
                                epoch_seconds, hoses_on_test_s, measured_capacity, more_testing, power_now,
                                target_powers)
from pipeline.stages import Carrying, Reads, StageContext, StageOutput

NAME = "test_plan"
READS = Reads(kinds=("durability",), tables=("hose_life", "durability_runs", "life_effect", "life_verdict"),
              logbooks=True, plan=True)
WRITES = ("test_plan",)

COLUMNS = ["hose_type", "target_power", "failures_needed", "failures", "power_now", "more_hoses_per_adjustment",
           "more_km", "benches", "km_per_day", "capacity_from", "expected_decision_date", "n_simulations", "mc_se",
           "note"]
CAPACITY_PLAN, CAPACITY_MEASURED = "plan", f"measured, last {CAPACITY_DAYS} days"
_SETTINGS = ("margin", "alpha", "power", "spending", "max_failures")


def _number(v) -> float | None:
    """A finite float, or None (NULL, NaN, missing)."""
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


def hose_items(life: pd.DataFrame, effect: pd.DataFrame | None, plan, verdict: pd.DataFrame | None = None) -> list[dict]:
    """One plain-data item per hose type with both adjustments: its hoses, plan and seed; ``max_failures``
    the decision stage's (``verdict``: ``life_verdict``; the plan's where it has no row)."""
    if life is None or len(life) == 0:
        return []
    life = life[life["adjustment"].isin(("force", "distance")) & life["hose_type"].notna()]
    shapes, models = {}, {}
    if effect is not None and len(effect):
        shapes = {t: _number(s) for t, s in zip(effect["hose_type"], effect["shape"])}
        models = dict(zip(effect["hose_type"], effect.get("model", pd.Series([None] * len(effect)))))
    frozen = {}
    if verdict is not None and len(verdict):
        frozen = {t: None if pd.isna(m) else int(m) for t, m in zip(verdict["hose_type"], verdict["max_failures"])}
    secs = {c: epoch_seconds(life[c]) for c in ("installed_at", "ended_at") if c in life}
    life = life.assign(**{f"_{c}_s": v for c, v in secs.items()})   # every hose's times converted once
    items = []
    for htype, g in life.groupby("hose_type", sort=True):
        if set(g["adjustment"]) != {"force", "distance"}:
            continue
        g = g.sort_values("hose_id", kind="stable")
        dist = pd.to_numeric(g["distance_km"], errors="coerce").to_numpy(float)
        running = (g["status"] == "running").to_numpy()
        keep = (np.isfinite(dist) & (dist > 0)) | running   # a failed hose of unknown life tells nothing
        s = plan.for_hose_type(htype)
        item = {"hose_type": str(htype), "hose_id": [str(h) for h in g["hose_id"][keep]],
                "distance": [float(x) if np.isfinite(x) else 0.0 for x in dist[keep]],
                "failed": (g["status"] == "failed").to_numpy()[keep].tolist(), "running": running[keep].tolist(),
                "group": (g["adjustment"] == "force").to_numpy()[keep].astype(int).tolist(),
                "shape": shapes.get(htype), "model": models.get(htype) if isinstance(models.get(htype), str) else None,
                "settings": {k: getattr(s, k) for k in _SETTINGS} | {"max_failures": frozen.get(htype, s.max_failures)},
                "n_simulations": N_SIMULATIONS,
                "hoses_on_test": _on_test(g)}
        # the seed: everything but the power and the maximum, which reach the simulations through the designs only
        # (session 24: a power change that leaves a hose type's failures_needed, or its maximum, as they were leaves
        # its schedules, or its power_now, as they were, memo included)
        unpowered = dict(item, settings={k: v for k, v in item["settings"].items() if k not in ("power", "max_failures")})
        item["seed"] = int(hashlib.sha256(json.dumps(unpowered, sort_keys=True).encode()).hexdigest()[:16], 16)
        items.append(item)
    return items


def _on_test(g: pd.DataFrame) -> int | None:
    """The hose type's hoses on test per adjustment (:func:`analyses.test_plan.hoses_on_test`), from all
    its hoses (also those whose life is unknown: they held a bench); their times in seconds as
    :func:`hose_items` converted them (columns ``_installed_at_s``, ``_ended_at_s``)."""
    if "_installed_at_s" not in g or "_ended_at_s" not in g:
        return None
    return hoses_on_test_s(g["_installed_at_s"].to_numpy(float), g["_ended_at_s"].to_numpy(float),
                           (g["adjustment"] == "force").to_numpy(int))


def needed_of(item: dict) -> list:
    """``[failures_needed or None, note]`` of one design (module level for ``ctx.map``, memoised): ``item``:
    ``margin``, ``alpha``, ``power`` (ONE target power), ``spending``, ``shape`` [-], ``hoses`` (as :func:`design`).
    One item per target power, so that a change of the plan's power leaves the designs at
    :data:`analyses.test_plan.TARGET_POWER` in the memo (session 24)."""
    try:
        d = design_for(item["margin"], item["alpha"], item["power"], item["spending"], item["shape"], item["hoses"])
        return [int(d.failures), d.note]
    except NoDesign as exc:   # NULL with the reason, never a number the design does not give
        return [None, str(exc)]


def design(item: dict) -> dict:
    """One sequential design (module level for ``ctx.map``): ``failures_needed`` per target power
    and the efficacy boundaries of the test as planned (one per failure up to ``max_failures``).

    ``item``: ``margin``, ``alpha``, ``power``, ``spending``, ``max_failures`` (``life_verdict``'s;
    None: the design's at ``power`` and the current shape), ``shape`` [-] and ``hoses``: hoses on test per adjustment [-] (None: failures rare).
    Hose types that share a design share its cost (the boundaries of up to hundreds of looks, computed
    once per number of looks, alpha and spending in a process: :mod:`analyses.sequential`).
    """
    needed = {p: needed_of(dict(item, power=p)) for p in target_powers(item["power"])}
    m = item["max_failures"] or needed[item["power"]][0]
    c = efficacy_boundaries(np.arange(1, m + 1) / m, item["alpha"], item["spending"]) if m else []
    return {"failures_needed": [[p, *v] for p, v in needed.items()], "boundaries": [float(x) for x in c]}


def _design_item(item: dict) -> dict:
    """The design a hose type's item needs (shape 1.0 when life_effect has none)."""
    s = item["settings"]
    return {"margin": s["margin"], "alpha": s["alpha"], "power": s["power"], "spending": s["spending"],
            "max_failures": s["max_failures"],  # the shape on the design grid: types that round alike share it
            "shape": 1.0 if item["shape"] is None else design_shape(item["shape"]), "hoses": item["hoses_on_test"]}


def _needed_items(item: dict) -> list[dict]:
    """The :func:`needed_of` items of a hose type, one per target power (:func:`analyses.test_plan.target_powers`)."""
    d = _design_item(item)
    return [{k: d[k] for k in ("margin", "alpha", "spending", "shape", "hoses")} | {"power": p}
            for p in target_powers(d["power"])]


#: What :func:`plan_hose_type` reads of a :func:`hose_items` item (with ``needed`` and ``benches``): not the plan's
#: power, nor the target powers, which the stage puts on the rows (session 24).
_PLAN_KEYS = ("hose_type", "distance", "failed", "running", "group", "n_simulations", "seed")


def plan_work(item: dict, needed: list, benches) -> dict:
    """The :func:`plan_hose_type` item of a hose type: its hoses and seed, the plan's margin, alpha and spending,
    ``needed`` (``[failures_needed or None, note]`` per target power, in :func:`analyses.test_plan.target_powers`'
    order) and ``benches``."""
    s = item["settings"]
    return {k: item[k] for k in _PLAN_KEYS} | {"settings": {k: s[k] for k in ("margin", "alpha", "spending")},
                                               "needed": needed, "benches": benches}


def power_work(item: dict, needed: list) -> dict:
    """The :func:`power_of` item of a hose type: its hoses and seed, the plan's margin, alpha and spending and
    ``maximum``, the looks ``power_now`` runs to (the frozen ``max_failures``, else ``failures_needed`` at the
    plan's power, ``needed[0]``): a power change that leaves the maximum keeps its memo (session 24)."""
    s = item["settings"]
    return {k: item[k] for k in ("hose_type", "distance", "failed", "running", "group", "n_simulations", "seed")} | {
        "settings": {k: s[k] for k in ("margin", "alpha", "spending")}, "maximum": s["max_failures"] or needed[0][0]}


def _state(item: dict) -> HoseState:
    return HoseState(np.array(item["distance"], float), np.array(item["failed"], bool),
                     np.array(item["running"], bool), np.array(item["group"], int))


def power_of(item: dict) -> list:
    """``[power_now, mc_se, n_simulations, note]`` of one hose type (module level for ``ctx.map``, memoised):
    :func:`analyses.test_plan.power_now` run to the item's ``maximum`` (:func:`power_work`), at the boundaries the
    item carries (``boundaries``: :class:`~pipeline.stages.context.Carrying`), else computed here."""
    s = item["settings"]
    state = _state(item)
    if not item["maximum"]:
        return [math.nan, math.nan, 0, "no maximum: the design does not exist (failures_needed)"]
    fit = common_shape_fit(state.distance, state.failed, state.group)
    now = power_now(state, fit, _given_boundaries(item, 0, item["maximum"]), s["margin"], item["n_simulations"],
                    item["seed"])
    return [now.power, now.mc_se, now.n_simulations, now.note]


def head_notes(item: dict, now_note: str | None) -> list[str]:
    """The notes every row of a :func:`hose_items` item opens with (the shape, the maximum, the model, then
    ``power_now``'s)."""
    notes = [] if item["shape"] is not None else ["failures_needed at shape 1.0: life_effect has no common shape"]
    if item["settings"]["max_failures"] is None:
        notes.append("power_now runs to failures_needed at the plan's power: no max_failures frozen yet (life_verdict)")
    if item["model"] == SEPARATE:
        notes.append("the simulations assume a common shape; life_effect finds the shapes differ")
    return notes + ([f"power_now: {now_note}"] if now_note else [])


def plan_hose_type(item: dict) -> list[dict]:
    """The ``test_plan`` rows of one hose type without ``power_now`` (:func:`power_of`), the bench capacity and the
    target power: one row per entry of ``needed``, in its order, its ``note`` the list of the row's own notes (the
    stage opens it with :func:`head_notes`); module level for ``ctx.map``.

    ``item``: :func:`plan_work` (the hose type's hoses, what the plan's designs give, its benches).
    """
    state = _state(item)
    fit = common_shape_fit(state.distance, state.failed, state.group)
    rows = []
    schedules = _schedules(item, state, fit, [needed for needed, _ in item["needed"]])
    for (needed, short), sched in zip(item["needed"], schedules):
        more = more_testing(state, fit, needed, item["n_simulations"], item["seed"]) if needed is not None \
            else MoreTesting(None, math.nan, None)
        rows.append({"hose_type": item["hose_type"], "failures_needed": needed, "failures": sum(state.failures),
                     "more_hoses_per_adjustment": more.hoses_per_adjustment, "more_km": more.km,
                     "decision_km": sched.hose_km,
                     "note": [f"failures_needed: {short}"] * bool(short)
                     + ([f"more_km: {more.note}"] if more.note else [])
                     + ([f"expected_decision_date: {sched.note}"] if sched.note else [])})
    return rows


@functools.lru_cache(maxsize=1024)
def _boundaries(looks: int, alpha: float, spending: str) -> np.ndarray:
    """:func:`analyses.sequential_boundaries.efficacy_boundaries` of ``looks`` equally spaced looks [-], once per process
    (hose types whose second target power needs the same maximum share it); read-only."""
    c = efficacy_boundaries(np.arange(1, looks + 1) / looks, alpha, spending)
    c.setflags(write=False)
    return c


def boundaries_of(item: dict) -> list[float]:
    """The efficacy boundaries of ``item["looks"]`` equally spaced looks at ``alpha`` and ``spending`` [-] (module level
    for ``ctx.map``, memoised: a power change computes only the maxima no hose type had before; session 27)."""
    return [float(x) for x in _boundaries(item["looks"], item["alpha"], item["spending"])]


def _given_boundaries(item: dict, i: int, looks: int) -> np.ndarray:
    """The ``i``-th boundaries an item carries (``boundaries``), else :func:`_boundaries` of ``looks`` here
    (the same floats)."""
    given = item.get("boundaries")
    if given is not None and given[i] is not None:
        return np.asarray(given[i], float)
    s = item["settings"]
    return _boundaries(looks, s["alpha"], s["spending"])


def _boundary_key(looks, settings: dict) -> str | None:
    """The :func:`boundaries_of` item of ``looks`` at a work item's alpha and spending, as JSON (None: no maximum)."""
    if not looks:
        return None
    return json.dumps({"looks": int(looks), "alpha": settings["alpha"], "spending": settings["spending"]},
                      sort_keys=True)


def _schedules(item: dict, state: HoseState, fit, needed: list) -> list[BenchSchedule]:
    """The lab's benches (``item["benches"]``) run to a decision or ``needed`` failures, one schedule per row,
    each read at the boundaries of the design whose maximum is its ``needed`` (the test's own when it is
    life_verdict's); the rows' schedules share their replicates (:func:`analyses.bench_schedule.bench_schedules`)."""
    out = [BenchSchedule(math.nan, None)] * len(needed)
    todo = [i for i, m in enumerate(needed) if m is not None and item.get("benches")]
    if not todo:
        return out
    s = item["settings"]
    bounds = [_given_boundaries(item, i, needed[i]) for i in todo]
    for i, sched in zip(todo, bench_schedules(state, fit, bounds, s["margin"], item["benches"], SCHEDULE_SIMULATIONS,
                                              item["seed"])):
        out[i] = sched
    return out


def _cost(item: dict) -> int:
    """A hose type's item's work, roughly [-]: its hoses times the most looks its simulations read (the
    schedules' maxima, the test's own boundaries)."""
    needed = [n for n, _ in item["needed"] if n is not None]
    return len(item["distance"]) * max([item.get("maximum") or 0, *needed])


def latest_event(life: pd.DataFrame, runs: pd.DataFrame):
    """The latest event in the data (a run's end, a logbook event): the stage's "today", or None."""
    times = []
    if runs is not None and len(runs):
        start = pd.to_datetime(runs["started_at"], utc=True)
        times.append(start + pd.to_timedelta(pd.to_numeric(runs["duration_h"], errors="coerce").fillna(0.0), unit="h"))
    for col in ("installed_at", "ended_at"):
        if life is not None and col in life:
            times.append(pd.to_datetime(life[col], utc=True))
    latest = pd.concat(times).max() if times else pd.NaT
    return None if pd.isna(latest) else latest


def measured_by_type(life: pd.DataFrame, runs: pd.DataFrame, today, hose_types) -> dict:
    """Per hose type, the bench capacity measured from ITS hoses' durability runs of the last
    ``CAPACITY_DAYS`` days (:func:`analyses.test_plan.measured_capacity`: benches, km_per_day, note): the
    benches testing that hose type, as ``benches`` means, not the lab's runs of every type together."""
    if today is None:
        return {t: (None, None, "no event time in the data") for t in hose_types}
    if runs is None or life is None or len(runs) == 0 or "hose_id" not in runs:
        return {t: measured_capacity(None, today) for t in hose_types}
    type_of = dict(zip(life["hose_id"].astype(str), life["hose_type"]))
    of_type = runs["hose_id"].astype(str).map(type_of)
    found = {t: g for t, g in runs.groupby(of_type.to_numpy(), sort=False)}    # each type's runs, in their order
    return {t: measured_capacity(found.get(t, runs.iloc[:0]), today) for t in hose_types}


def _bench_capacity(settings, measured: tuple) -> tuple:
    """(benches, km_per_day, capacity_from) of a hose type: the plan's, else measured."""
    benches, km_day, _ = measured
    if settings.benches is not None and settings.km_per_day is not None:
        return settings.benches, settings.km_per_day, CAPACITY_PLAN
    if benches is None:
        return None, None, None
    if settings.benches is not None or settings.km_per_day is not None:   # one of the two from the plan
        total = benches * km_day
        benches = settings.benches or max(1, round(total / settings.km_per_day))
        km_day = settings.km_per_day or total / benches
    return benches, km_day, CAPACITY_MEASURED


def _capacity(row: dict, settings, measured: tuple, today) -> dict:
    """Bench capacity of a row (the plan's, else measured) and the expected decision date."""
    benches, km_day, source = _bench_capacity(settings, measured)
    extra = [] if source == CAPACITY_PLAN or measured[2] is None else [measured[2]]
    if today is None:
        extra.append("no event time in the data: no expected_decision_date")
    date = decision_date(today, row.get("decision_km", math.nan), benches, km_day) if today else None
    row = dict(row, benches=benches, km_per_day=km_day, capacity_from=source, expected_decision_date=date)
    row["note"] = "; ".join([n for n in (row["note"], *extra) if n]) or None
    return row


def plan_table(ctx: StageContext) -> pd.DataFrame:
    """The ``test_plan`` table (module docstring)."""
    life, runs = ctx.results.get("hose_life"), ctx.results.get("durability_runs")
    today = latest_event(life, runs)
    items = hose_items(life, ctx.results.get("life_effect"), ctx.plan, ctx.results.get("life_verdict"))
    measured = measured_by_type(life, runs, today, [i["hose_type"] for i in items])
    asks = [[json.dumps(a, sort_keys=True) for a in _needed_items(i)] for i in items]
    keys = sorted({k for ks in asks for k in ks})   # one per (design, target power): the 0.9 ones outlive a power change
    needed = dict(zip(keys, ctx.map(needed_of, [json.loads(k) for k in keys], label="test plan designs")))
    powers = [target_powers(i["settings"]["power"]) for i in items]
    need = [[needed[k] for k in ks] for ks in asks]
    work = [plan_work(i, n, _bench_capacity(ctx.plan.for_hose_type(i["hose_type"]), measured[i["hose_type"]])[0])
            for i, n in zip(items, need)]
    # power_now and the schedules are memoised apart: a power change moves the maximum of some hose types and the
    # failures_needed of others (session 24)
    # the costliest hose types first: the workers' last chunks are then the cheap ones (session 23)
    order = sorted(range(len(work)), key=lambda i: -_cost(work[i]))
    powers_work = {i: power_work(items[i], need[i]) for i in order}
    # one item per row (session 25): a power change that moves the plan's failures_needed re-runs that row's
    # schedule and more_testing only, the 0.9 row's come from the memo; rows with the same item computed once
    rows_of = {}
    for w in work:
        for n in w["needed"]:
            rows_of.setdefault(json.dumps(dict(w, needed=[n]), sort_keys=True), dict(w, needed=[n]))
    keys = sorted(rows_of, key=lambda k: (-_cost(rows_of[k]), k))
    # every maximum's boundaries once, memoised (session 27): the items carry them (Carrying)
    asked = {_boundary_key(p["maximum"], p["settings"]) for p in powers_work.values()} | {
        _boundary_key(r["needed"][0][0], r["settings"]) for r in rows_of.values()}
    asked = sorted((k for k in asked if k is not None), key=lambda k: (-json.loads(k)["looks"], k))
    bounds = dict(zip(asked, ctx.map(boundaries_of, [json.loads(k) for k in asked], label="test plan: boundaries")
                      if asked else []))
    now = [None] * len(work)
    for i, res in zip(order, ctx.map(power_of, [Carrying(powers_work[i], boundaries=[bounds.get(
            _boundary_key(powers_work[i]["maximum"], powers_work[i]["settings"]))]) for i in order],
                                     label="test plan: power_now") if work else []):
        now[i] = res
    done = dict(zip(keys, ctx.map(plan_hose_type, [Carrying(rows_of[k], boundaries=[bounds.get(
        _boundary_key(rows_of[k]["needed"][0][0], rows_of[k]["settings"]))]) for k in keys], label="test plan")
                    if keys else []))
    results = [[done[json.dumps(dict(w, needed=[n]), sort_keys=True)][0] for n in w["needed"]] for w in work]
    rows = []
    for item, res, ps, pn in zip(items, results, powers, now):
        head = head_notes(item, pn[3])
        for r, p in zip(res, ps):
            r = dict(r, target_power=p, power_now=pn[0], mc_se=pn[1], n_simulations=pn[2],
                     note="; ".join(head + r["note"]) or None)
            rows.append(_capacity(r, ctx.plan.for_hose_type(item["hose_type"]), measured[item["hose_type"]], today))
    df = pd.DataFrame(rows, columns=COLUMNS)
    for c in ("failures_needed", "failures", "more_hoses_per_adjustment", "benches", "n_simulations"):
        df[c] = df[c].astype("Int64")
    for c in ("target_power", "power_now", "more_km", "km_per_day", "mc_se"):
        df[c] = pd.to_numeric(df[c]).astype("float64")
    return df


def run(ctx: StageContext) -> StageOutput:
    out = StageOutput()
    out.tables["test_plan"] = plan_table(ctx)
    return out
