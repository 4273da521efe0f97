"""The ``decision`` profile: many independent hose types with a known life ratio, for calibrating
the verdict of issue 23 ("The decision") end to end.

Each hose type has a true force / distance life ratio (the scenario's), a Weibull shape common to
both adjustments (or, for a share of the types, one shape per adjustment, the ratio then being
that of the B10 lives), a distance-set scale, and its own benches. The benches run at a constant
``km_per_day``: a bench runs one hose at a time and the next hose is installed when one fails or
is removed, so installations are staggered and a hose's distance is linear in time between its
installation and its end. Hoses are known by their logbook odometer only (``hoses.csv``
``distance_km`` on ``failed`` / ``removed``, no durability runs), so the campaign is cheap to
write and to rebuild, and a look's distances interpolated linearly in time are exact.

Censoring (right): a share of the hoses is ``removed`` at a distance drawn independently of its
life (a bench needed elsewhere); a hose type's test stops at its cutoff, half a day after the
failure that brings its failures to the number it runs to. With ``run_to`` (a callable given the
logbook as it stands at each failure, returning the ``max_failures`` the decision stage froze, or
None while none is: ``benchmarks.bench_decision`` supplies the stage's own, which the simulator
may not import) that is the frozen ``max_failures``, capped at ``cap`` times the closed-form
design (the truth says which stopped it); without it, ``slack`` times the failures the sequential
design needs (closed form, Jennison & Turnbull 2000, ch. 7). The hoses on the benches at the cutoff are ``running``:
the lab reads their odometer then, which the logbook format records as a removal and a
reinstallation one minute later (a pause, not a suspension: ``docs/bench-exports.md``), so
their distance so far is known and their status stays ``running``.

Scenarios: ``no-difference`` (ratio 1), ``at-margin`` (ratio = the plan's margin),
``above-margin`` (ratio = margin ** ``above``), ``mixed`` (the three in turn). The plan.toml at the
top of the tree is the profile's settings (``[defaults]``). Truth (per hose type: ratio, shapes,
scales, scenario; per hose: installation, end, status, distance) goes to ``truth.json``.
Seeded: hose type ``j`` draws from its own generator ``(seed, j)``, so a type does not depend on
how many others there are. References: Meeker & Escobar 1998 (Weibull lives, censoring),
Jennison & Turnbull 2000 (group sequential designs), Lan & DeMets 1983 (alpha spending).
"""
from __future__ import annotations

import heapq
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime, timedelta
from statistics import NormalDist

import numpy as np

from pipeline.simulator.plan import iso

#: The campaign folder the profile writes its logbook into.
DECISION_CAMPAIGN = "decision-2026"
#: The scenarios and their true force / distance life ratio as a function of the margin.
SCENARIOS = ("no-difference", "at-margin", "above-margin", "mixed")
START = datetime(2025, 1, 6, 7, 0)
ADJUSTMENTS = ("distance", "force")
_LN_B10 = -math.log(0.9)   # -ln(1 - 0.10): B10 = scale * _LN_B10 ** (1 / shape)


@dataclass(frozen=True)
class DecisionProfile:
    """A ``decision`` campaign's settings: its hose types, scenario, plan and benches.

    ``benches`` per hose type (half of them force-set), ``km_per_day`` [km/day] each;
    ``shapes`` the range of the common Weibull shape [-]; ``scales_km`` the range (log-uniform)
    of the distance-set scale [km]; ``separate_shapes`` the share of hose types whose force-set
    shape is ``shape_split`` times the distance-set one; ``removed`` the share of hoses removed at
    a distance drawn independently of their life; ``slack`` the failures a type runs to over its
    design's; ``above`` the exponent of the margin in ``above-margin``. ``max_failures`` None
    leaves it out of plan.toml (the design's number, test_plan's, is used). ``run_to``: called at
    each failure with the type's logbook rows as they stand (hoses on the benches read then, see
    :func:`logbook_now`) and its truth, returns the failures to run to (the stage's frozen
    ``max_failures``) or None while unknown; then ``cap`` times the closed-form design bounds the run.
    """

    hose_types: int = 300
    scenario: str = "mixed"
    margin: float = 1.5
    alpha: float = 0.05
    power: float = 0.8
    confidence: float = 0.9
    spending: str = "obrien-fleming"
    max_failures: int | None = None
    benches: int = 8
    km_per_day: float = 20.0
    shapes: tuple = (2.0, 3.0)
    scales_km: tuple = (40.0, 400.0)
    separate_shapes: float = 0.1
    shape_split: float = 1.6
    removed: float = 0.1
    slack: float = 1.5
    above: float = 1.5
    run_to: Callable | None = field(default=None, compare=False)
    cap: float = 4.0

    def ratio(self, scenario: str) -> float:
        """The true force / distance life ratio of ``scenario`` [-]."""
        return {"no-difference": 1.0, "at-margin": self.margin, "above-margin": self.margin ** self.above}[scenario]


def plan_toml(p: DecisionProfile) -> str:
    """The profile's ``plan.toml``: its settings as the lab's ``[defaults]``."""
    lines = ["# the decision profile's test plan (pneubench simulate --profile decision)", "[defaults]",
             f"margin = {p.margin!r}", f"alpha = {p.alpha!r}", f"power = {p.power!r}",
             f"confidence = {p.confidence!r}", f'spending = "{p.spending}"', f"benches = {p.benches}",
             f"km_per_day = {p.km_per_day!r}"]
    if p.max_failures is not None:
        lines.append(f"max_failures = {p.max_failures}")
    return "\n".join(lines) + "\n"


def design_failures(margin: float, alpha: float, power: float, shape: float) -> int:
    """Failures a sequential design needs, approximately [-]: the fixed-sample number
    ``4 (z_{1-alpha/2} + z_power)^2 / (shape ln margin)^2`` (Schoenfeld 1981) inflated by 1.1
    (O'Brien-Fleming at a look per failure needs ~1.07, Jennison & Turnbull 2000, ch. 7).
    Only sizes the simulated test; the stages compute the exact number."""
    z = NormalDist().inv_cdf(1 - alpha / 2) + NormalDist().inv_cdf(power)
    return math.ceil(1.1 * 4 * z * z / (shape * math.log(margin)) ** 2)


def hose_type_truth(j: int, p: DecisionProfile, rng: np.random.Generator) -> dict:
    """Hose type ``j``'s truth: scenario, ratio, shapes, scales [km], B10s [km], target failures."""
    scenario = SCENARIOS[j % 3] if p.scenario == "mixed" else p.scenario
    ratio = p.ratio(scenario)
    shape = float(rng.uniform(*p.shapes))
    scale_d = float(math.exp(rng.uniform(math.log(p.scales_km[0]), math.log(p.scales_km[1]))))
    separate = bool(rng.random() < p.separate_shapes)
    shape_f = shape * p.shape_split if separate else shape
    b10_d = scale_d * _LN_B10 ** (1 / shape)
    scale_f = ratio * b10_d / _LN_B10 ** (1 / shape_f)
    return {"hose_type": f"SIM-{j + 1:04d}", "scenario": scenario, "life_ratio": ratio,
            "separate_shapes": separate, "shape": None if separate else shape,
            "shape_distance": shape, "shape_force": shape_f,
            "scale_distance_km": scale_d, "scale_force_km": scale_f,
            "b10_distance_km": b10_d, "b10_force_km": ratio * b10_d,
            "target_failures": math.ceil((p.cap if p.run_to else p.slack)
                                         * design_failures(p.margin, p.alpha, p.power, shape)),
            "benches": p.benches, "km_per_day": p.km_per_day}


@dataclass
class _Hose:
    """One hose on a bench: when it was installed, its drawn life and removal distance [km]."""

    hose_id: str
    adjustment: str
    installed: datetime
    life_km: float
    removal_km: float

    def end(self, km_per_day: float) -> tuple[datetime, str]:
        """When and how it ends if nothing stops the test first (to the whole second)."""
        km, how = (self.life_km, "failed") if self.life_km <= self.removal_km else (self.removal_km, "removed")
        return self.installed + timedelta(seconds=round(km / km_per_day * 86400.0)), how


def _new_hose(truth: dict, n: int, adj: str, when: datetime, p: DecisionProfile, rng: np.random.Generator) -> _Hose:
    """The ``n``-th hose of a type, installed at ``when`` on a bench set by ``adj``."""
    shape, scale = truth[f"shape_{adj}"], truth[f"scale_{adj}_km"]
    life = float(scale * rng.weibull(shape))
    removal = float(truth["scale_distance_km"] * rng.uniform(0.05, 1.5)) if rng.random() < p.removed else math.inf
    return _Hose(f"{truth['hose_type']}-H{n:03d}", adj, when, life, removal)


def run_benches(truth: dict, p: DecisionProfile, rng: np.random.Generator) -> tuple[list[dict], list[dict]]:
    """Run a hose type's benches until the failures it runs to (and half a day more): its logbook
    rows and its hoses (truth: installation, end, status, distance [km]). Sets ``truth["stopped_by"]``:
    ``max_failures`` (``run_to``'s number reached), ``cap`` (``target_failures`` reached first, with
    ``run_to``) or ``slack`` (without ``run_to``); ``truth["run_to"]``: ``run_to``'s number or None."""
    v = p.km_per_day
    queue, hoses, rows, failures, n = [], [], [], 0, 0
    for b in range(p.benches):  # benches start a day apart: staggered from the first day
        n += 1
        h = _new_hose(truth, n, ADJUSTMENTS[b % 2], START + timedelta(days=b), p, rng)
        heapq.heappush(queue, (*h.end(v), n, b, h))
    cutoff, truth["run_to"] = None, None
    truth["stopped_by"] = "cap" if p.run_to else "slack"
    while queue:
        at, how, k, b, h = heapq.heappop(queue)
        if cutoff is not None and at > cutoff:
            heapq.heappush(queue, (at, how, k, b, h))
            break
        hoses.append(_ended(h, at, how, v, rows))
        failures += how == "failed"
        if cutoff is None and how == "failed" and p.run_to and truth["run_to"] is None:
            truth["run_to"] = p.run_to(logbook_now(rows, queue, at, v), truth)
        if cutoff is None and how == "failed" and (failures >= truth["target_failures"] or (
                truth["run_to"] is not None and failures >= truth["run_to"])):
            cutoff = at + timedelta(hours=12)
            if truth["run_to"] is not None and failures >= truth["run_to"]:
                truth["stopped_by"] = "max_failures"
        n += 1
        nxt = _new_hose(truth, n, h.adjustment, at + timedelta(hours=1), p, rng)
        heapq.heappush(queue, (*nxt.end(v), n, b, nxt))
    for *_, h in sorted(queue, key=lambda q: q[2]):
        if h.installed < cutoff:
            hoses.append(_running(h, cutoff, v, rows))
    return rows, hoses


def logbook_now(rows: list[dict], queue: list, at: datetime, v: float) -> list[dict]:
    """The logbook as it stands at ``at`` (a failure): the rows so far, and every hose on a bench
    installed by then read a minute later as at the cutoff (:func:`_running`), sorted as the campaign
    writes them."""
    now = list(rows)
    for *_, h in sorted(queue, key=lambda q: q[2]):
        if h.installed < at:
            _running(h, at + timedelta(minutes=1), v, now)
    return sorted(now, key=lambda r: (r["at"], r["hose_id"]))


def _installed_row(h: _Hose, when: datetime) -> dict:
    """The logbook row of the hose's installation at ``when``."""
    return {"hose_id": h.hose_id, "event": "installed", "at": iso(when), "hose_type": truth_name(h),
            "adjustment": h.adjustment}


def truth_name(h: _Hose) -> str:
    """The hose type a hose belongs to (its id's prefix)."""
    return h.hose_id.rsplit("-H", 1)[0]


def _km(h: _Hose, at: datetime, v: float) -> float:
    """The hose's odometer at ``at`` [km]: linear in time from its installation."""
    return (at - h.installed).total_seconds() / 86400.0 * v


def _ended(h: _Hose, at: datetime, how: str, v: float, rows: list[dict]) -> dict:
    """A hose that failed or was removed before the cutoff: its logbook rows and truth."""
    km = _km(h, at, v)
    rows.append(_installed_row(h, h.installed))
    end = {"hose_id": h.hose_id, "event": how, "at": iso(at), "distance_km": km}
    if how == "failed":
        end["failure_mode"] = "rupture"
    else:
        end["notes"] = "bench needed for another test"
    rows.append(end)
    return {"hose_id": h.hose_id, "hose_type": truth_name(h), "adjustment": h.adjustment,
            "installed_at": iso(h.installed), "ended_at": iso(at), "status": how, "distance_km": km,
            "life_km_drawn": h.life_km}


def _running(h: _Hose, cutoff: datetime, v: float, rows: list[dict]) -> dict:
    """A hose still on its bench at the cutoff: installed, its odometer read at the cutoff (a
    removal and a reinstallation a minute later: a pause), still running."""
    km = _km(h, cutoff, v)
    rows.append(_installed_row(h, h.installed))
    rows.append({"hose_id": h.hose_id, "event": "removed", "at": iso(cutoff), "distance_km": km,
                 "notes": "odometer read; test continues"})
    rows.append({**_installed_row(h, cutoff + timedelta(minutes=1)), "notes": "reinstalled after the reading"})
    return {"hose_id": h.hose_id, "hose_type": truth_name(h), "adjustment": h.adjustment,
            "installed_at": iso(h.installed), "ended_at": None, "odometer_at": iso(cutoff), "status": "running",
            "distance_km": km, "life_km_drawn": h.life_km}


def simulate_decision(seed: int, p: DecisionProfile) -> tuple[list[dict], str, dict]:
    """Every hose type of a ``decision`` campaign: the logbook rows (of ``DECISION_CAMPAIGN``),
    the plan.toml text and the truth (settings, per hose type, per hose)."""
    if p.scenario not in SCENARIOS:
        raise ValueError(f"unknown scenario {p.scenario!r} (choose from {', '.join(SCENARIOS)})")
    rows, types, hoses = [], {}, {}
    for j in range(p.hose_types):
        rng = np.random.default_rng([int(seed), 23, j])
        truth = hose_type_truth(j, p, rng)
        type_rows, type_hoses = run_benches(truth, p, rng)
        rows += type_rows
        truth.update(n_hoses=len(type_hoses), **{f"n_{s}": sum(h["status"] == s for h in type_hoses)
                                                 for s in ("failed", "removed", "running")})
        types[truth["hose_type"]] = truth
        hoses.update({h["hose_id"]: h for h in type_hoses})
    settings = {k: getattr(p, k) for k in p.__dataclass_fields__ if k != "run_to"}
    settings["run_to"] = None if p.run_to is None else getattr(p.run_to, "__qualname__", type(p.run_to).__qualname__)
    truth = {"generator": "pneubench simulator", "seed": seed, "profile": "decision", "settings": settings,
             "plan": "plan.toml", "logbook": f"{DECISION_CAMPAIGN}/hoses.csv", "hose_types": types, "hoses": hoses}
    return rows, plan_toml(p), truth
