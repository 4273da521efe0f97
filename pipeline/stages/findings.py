"""Stage: the conclusions of the two seed papers, checked on the lab's latest data.

One row per finding in the ``findings`` table (``schemas/ddl/95_findings.sql``), and one per hose
type for the decision (``life_verdict:<hose type>``, :func:`life_verdicts`): the measured
value, its standard uncertainty, the criterion, and whether it holds (NULL and "no data" when
nothing measures it). The numbers come from the tables of the earlier stages (``ctx.results``):
their own statistics are reused (``breakaway_findings``, ``seal_envelope``,
``viscous_transition``, the standard errors of ``viscous_fits``); only when such a table is
missing is it derived here from the contract tables with the same ``analyses`` functions.

The rebuild adds ``previous_holds``, ``change`` and ``changed_at`` by comparing with the previous
warehouse (``change`` / ``changed_at`` stay while ``holds`` stays the same); the morning report
puts a finding whose result changed in the last 24 hours first.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
import pandas as pd

from analyses import breakaway as bk
from analyses import service_life as sl
from analyses import viscous_friction as vfr
from analyses.leakage import LEAK_THRESHOLD_L_MIN, characterisation_rows
from analyses.numerics import chi2_sf, two_sided_z
from schemas.papers import (PLA_CITATION, PLA_NRMSE_LIMIT_PCT, PLPA_BREAKAWAY_RATIO_BAND, PLPA_CITATION,
                            PLPA_SPRING_FORCE_MAX_N)
from pipeline.stages import Reads, StageContext, StageOutput, UndeclaredRead
from pipeline.stages.values import finite_float

NAME = "findings"
READS = Reads(tables=("breakaway_findings", "breakaway", "leakage_map", "seal_envelope", "viscous_fits",
                      "viscous_transition", "viscous_points", "spring_tests", "hose_life", "service_life_test",
                      "life_verdict", "life_effect"))
WRITES = ("findings",)

PLPA = f"PLPA: {PLPA_CITATION}"
PLA = f"PLA: {PLA_CITATION}"

#: Significance level of the "no effect" tests.
ALPHA = 0.05
#: An effect smaller than this fraction of the quantity counts as none, whatever the p-value.
NEGLIGIBLE = 0.10
#: Tolerance on a tested (plateau) pressure [bar].
PRESSURE_TOL_BAR = 0.25

COLUMNS = ["finding_id", "ord", "paper", "statement", "measured", "uncertainty", "unit", "criterion", "holds",
           "n", "p_value", "detail", "source_tables"]


def _table(ctx: StageContext, name: str) -> pd.DataFrame | None:
    df = ctx.results.get(name)
    return df if df is not None and not df.empty else None


@dataclass(frozen=True)
class Claim:
    """What a finding states, fixed by its check: its id, the paper's claim and how it is judged."""

    finding_id: str
    statement: str
    #: the paper, as "PLPA: <citation>"
    paper: str
    #: unit of the measured value
    unit: str
    criterion: str


def _row(claim: Claim, source: str, measured=None, uncertainty=None, holds=None, n=0, p_value=None,
         detail="no data") -> dict:
    """A ``findings`` row: the claim, what was measured from ``source`` (tables) and whether it holds."""
    return {"finding_id": claim.finding_id, "paper": claim.paper, "statement": claim.statement,
            "measured": finite_float(measured), "uncertainty": finite_float(uncertainty), "unit": claim.unit,
            "criterion": claim.criterion, "holds": None if holds is None else bool(holds), "n": int(n or 0),
            "p_value": finite_float(p_value), "detail": detail, "source_tables": source}


# -- breakaway (seed 000, section 3.2.1) -------------------------------------------------------------
def _breakaway_stat(ctx: StageContext, finding: str) -> tuple[dict | None, str]:
    """The ``all``-directions row of ``breakaway_findings`` (or the same statistic from ``breakaway``)."""
    bf = _table(ctx, "breakaway_findings")
    if bf is not None and "finding" in bf.columns:
        sel = bf[(bf["finding"] == finding) & (bf["direction"].astype(str) == "all")]
        if not sel.empty:
            return sel.iloc[0].to_dict(), "breakaway_findings"
    events = _table(ctx, "breakaway")
    if events is None:
        return None, "breakaway"
    func = bk.backpressure_ratio if finding == "backpressure_ratio" else bk.force_rate_slope
    r = func(events, None, 0.95)
    return {**r, "confidence": 0.95}, "breakaway"


def _std_from_ci(r: dict, log: bool = False) -> float | None:
    lo, hi, est, conf = finite_float(r.get("ci_low")), finite_float(r.get("ci_high")), finite_float(r.get("estimate")), finite_float(r.get("confidence"))
    if lo is None or hi is None or est is None:
        return None
    z = two_sided_z(conf or 0.95)
    if log and lo > 0 and hi > 0:
        return est * (math.log(hi) - math.log(lo)) / (2 * z)
    return (hi - lo) / (2 * z)


def breakaway_ratio(ctx: StageContext) -> dict:
    lo, hi = PLPA_BREAKAWAY_RATIO_BAND
    claim = Claim("breakaway_0bar_twice", "Breakaway force at 0 bar backpressure is about twice that at >= 1 bar",
                  PLPA, "ratio", f"ratio of means within {lo:g}-{hi:g}")
    r, source = _breakaway_stat(ctx, "backpressure_ratio")
    if r is None or finite_float(r.get("estimate")) is None:
        return _row(claim, source)
    est = finite_float(r["estimate"])
    ci = (f"{100 * (finite_float(r.get('confidence')) or 0.95):.0f} % CI {finite_float(r.get('ci_low')):.3g}-{finite_float(r.get('ci_high')):.3g}"
          if finite_float(r.get("ci_low")) is not None else "no CI")
    return _row(claim, source, est, _std_from_ci(r, log=True), lo <= est <= hi, r.get("n"), r.get("p_value"),
                f"mean breakaway force at 0 bar / mean at >= 1 bar, both directions; {ci}")


def breakaway_rate(ctx: StageContext) -> dict:
    claim = Claim("breakaway_rate_no_effect", "The force rate has no effect on the breakaway force", PLPA, "N/(N/s)",
                  f"slope not significant (p >= {ALPHA:g}) or its effect over the tested rates < "
                  f"{100 * NEGLIGIBLE:.0f} % of the mean force")
    r, source = _breakaway_stat(ctx, "force_rate_slope")
    if r is None or finite_float(r.get("estimate")) is None:
        return _row(claim, source)
    slope, p = finite_float(r["estimate"]), finite_float(r.get("p_value"))
    events = _table(ctx, "breakaway")
    effect_ok, extra = False, ""
    if events is not None:
        ev = events.dropna(subset=["breakaway_force_n", "force_rate_n_s"])
        if not ev.empty:
            span = float(ev["force_rate_n_s"].max() - ev["force_rate_n_s"].min())
            mean = float(ev["breakaway_force_n"].abs().mean())
            effect = abs(slope) * span
            effect_ok = mean > 0 and effect < NEGLIGIBLE * mean
            extra = f"; effect over {span:g} N/s of rate: {effect:.3g} N vs mean force {mean:.3g} N"
    holds = (p is not None and p >= ALPHA) or effect_ok
    return _row(claim, source, slope, _std_from_ci(r), holds, r.get("n"), p,
                "common slope of breakaway force on force rate, one intercept per direction and backpressure"
                + extra)


# -- leakage (seed 000, section 3.1) -------------------------------------------------------------------
def leak_free(ctx: StageContext, pct: float, up_to_bar: float) -> dict:
    threshold = LEAK_THRESHOLD_L_MIN
    claim = Claim(f"no_leak_{int(pct)}pct_{int(up_to_bar)}bar",
                  f"No leak up to {up_to_bar:g} bar with the rollers set to >= {pct:g} % spring force", PLPA, "l/min",
                  f"largest plateau leak up to {up_to_bar:g} bar below {threshold:g} l/min (ANR)")
    lm = _table(ctx, "leakage_map")
    if lm is None or "spring_force_n" not in lm.columns:
        return _row(claim, "leakage_map")
    lm = characterisation_rows(lm)  # the paper's claim is about the setting, not about worn hoses
    force = pd.to_numeric(lm["spring_force_n"], errors="coerce")
    adj = lm["adjustment"].astype(str) if "adjustment" in lm.columns else pd.Series("force", index=lm.index)
    sel = lm[(adj == "force") & (force >= pct / 100 * PLPA_SPRING_FORCE_MAX_N - 1.0)].dropna(subset=["pressure_bar", "leak_l_min"])
    if sel.empty:
        return _row(claim, "leakage_map", detail=f"no data: no leakage run at >= {pct:g} % spring force")
    if sel["pressure_bar"].max() < up_to_bar - PRESSURE_TOL_BAR:
        return _row(claim, "leakage_map", n=len(sel),
                    detail=f"no data: runs at >= {pct:g} % spring force were tested only up to "
                           f"{sel['pressure_bar'].max():.2f} bar")
    low = sel[sel["pressure_bar"] <= up_to_bar + PRESSURE_TOL_BAR]
    i = low["leak_l_min"].idxmax()
    worst = low.loc[i]
    unc = finite_float(worst.get("leak_std_l_min")) if "leak_std_l_min" in low.columns else None
    detail = (f"{len(low)} plateaus of {low['run_id'].nunique()} runs; worst {worst['leak_l_min']:.3g} l/min at "
              f"{worst['pressure_bar']:.2f} bar ({worst['spring_force_n']:g} N, run {worst['run_id']})")
    env = _table(ctx, "seal_envelope")
    source = "leakage_map"
    if env is not None and "spring_force_pct" in env.columns:
        e = env[pd.to_numeric(env["spring_force_pct"], errors="coerce") >= pct - 0.1]
        if not e.empty:
            sealed = pd.to_numeric(e["sealed_up_to_bar"], errors="coerce").fillna(0.0)
            detail += f"; seal envelope: sealed up to >= {sealed.min():.2f} bar in every such setting"
            source = "leakage_map, seal_envelope"
    return _row(claim, source, worst["leak_l_min"], unc, float(worst["leak_l_min"]) < threshold, len(low),
                None, detail)


# -- viscous friction (seed 000, section 3.2.2) ------------------------------------------------------------
def viscous_backpressure(ctx: StageContext) -> dict:
    claim = Claim("viscous_independent_of_backpressure_1_3bar",
                  "Viscous friction does not depend on the backpressure between 1 and 3 bar", PLPA, "%",
                  f"viscous coefficients homogeneous (chi-square p >= {ALPHA:g}) or spread < {100 * NEGLIGIBLE:.0f} % "
                  "of their mean")
    vf = _table(ctx, "viscous_fits")
    if vf is None:
        return _row(claim, "viscous_fits")
    bp = pd.to_numeric(vf["backpressure_bar"], errors="coerce")
    sel = vf[(bp >= 1 - 0.05) & (bp <= 3 + 0.05)].dropna(subset=["viscous_n_s_m"])
    if sel["backpressure_bar"].nunique() < 2:
        return _row(claim, "viscous_fits", n=len(sel),
                    detail="no data: fewer than two backpressures between 1 and 3 bar")
    spreads, uncs, chi2, dof, parts = [], [], 0.0, 0, []
    has_se = "viscous_se_n_s_m" in sel.columns and sel["viscous_se_n_s_m"].notna().all()
    for d, g in sel.groupby("direction", sort=True):
        k = g["viscous_n_s_m"].to_numpy(float)
        if k.size < 2:
            continue
        mean = float(np.mean(k))
        spreads.append(100 * (k.max() - k.min()) / abs(mean))
        if has_se:
            se = g["viscous_se_n_s_m"].to_numpy(float)
            w = 1 / np.maximum(se, 1e-12) ** 2
            kw = float(np.sum(w * k) / np.sum(w))
            chi2 += float(np.sum(w * (k - kw) ** 2))
            dof += k.size - 1
            uncs.append(100 * math.sqrt(se[np.argmax(k)] ** 2 + se[np.argmin(k)] ** 2) / abs(mean))
        else:
            uncs.append(100 * float(np.std(k, ddof=1)) / abs(mean))
        parts.append(f"{d}: {', '.join(f'{v:.3g}' for v in k)} N s/m")
    if not spreads:
        return _row(claim, "viscous_fits", n=len(sel), detail="no data: one backpressure per direction")
    i = int(np.argmax(spreads))
    p = chi2_sf(chi2, dof) if has_se and dof > 0 else None
    holds = (p is not None and p >= ALPHA) or spreads[i] < 100 * NEGLIGIBLE
    return _row(claim, "viscous_fits", spreads[i], uncs[i], holds, int(sel["n_points"].sum()) if "n_points" in sel else len(sel),
                p, "largest spread (max - min) / mean of the viscous coefficient across 1-3 bar, per direction; "
                + "; ".join(parts))


def _stribeck_se(row: pd.Series) -> tuple[float | None, str]:
    """Standard error of the fitted Stribeck amplitude of one ``viscous_transition`` row [N], and how."""
    se = finite_float(row.get("stribeck_amplitude_se_n"))
    if se is not None:
        return se, ("uncertainty: standard error of the fitted amplitude (least-squares covariance of the "
                    f"Stribeck fit at v_st = {finite_float(row.get('stribeck_velocity_mm_s')) or float('nan'):.3g} mm/s)")
    return None, "uncertainty: not available (the fit gave no covariance)"


def stribeck(ctx: StageContext) -> dict:
    claim = Claim("no_stribeck_dip", "No Stribeck dip: friction falls steeply but monotonically near zero velocity", PLPA,
                  "N", "no backpressure shows a significant Stribeck term")
    vt = _table(ctx, "viscous_transition")
    source = "viscous_transition"
    if vt is None:
        pts = _table(ctx, "viscous_points")
        if pts is None:
            return _row(claim, "viscous_transition")
        vt = vfr.viscous_transition(pts)
        source = "viscous_points"
        if vt.empty:
            return _row(claim, source, detail="no data: no near-zero velocity passes on both sides of zero")
    vt = vt.dropna(subset=["stribeck_dip"])
    if vt.empty:
        return _row(claim, source, detail="no data: too few near-zero velocity points for the test")
    amp = pd.to_numeric(vt["stribeck_amplitude_n"], errors="coerce")
    if amp.isna().all():  # the test stands, but no amplitude could be estimated (see the note column)
        return _row(claim, source, None, None, vt[vt["stribeck_dip"].astype(bool)].empty,
                    int(pd.to_numeric(vt["n_points"], errors="coerce").sum()),
                    pd.to_numeric(vt["stribeck_p_value"], errors="coerce").min(),
                    "no Stribeck amplitude could be estimated (viscous_transition.note); the dip test stands")
    i = amp.idxmax()
    dips = vt[vt["stribeck_dip"].astype(bool)]
    p = pd.to_numeric(vt["stribeck_p_value"], errors="coerce").min()
    se, how = _stribeck_se(vt.loc[i])
    detail = (f"largest fitted Stribeck amplitude {amp[i]:.3g} N at {vt.loc[i, 'backpressure_bar']:g} bar; "
              f"{len(dips)} of {len(vt)} backpressures with a significant dip; {how}")
    return _row(claim, source, amp[i], se, dips.empty, int(pd.to_numeric(vt["n_points"], errors="coerce").sum()),
                p, detail)


# -- PLA spring model (seed 001, Table 3) -----------------------------------------------------------------
def bootstrap_se_of_max(values) -> float | None:
    """Standard deviation of the bootstrap distribution of the maximum, computed exactly.

    A resample of ``n`` values drawn with replacement has its maximum at or below the k-th
    smallest value with probability ``(k / n) ** n``; no random resampling is needed.

    Parameters
    ----------
    values : array_like
        The observed values (NaN ignored).

    Returns
    -------
    float or None
        The standard error [same unit], None with fewer than two values.
    """
    x = np.sort(np.asarray(values, dtype=float))
    x = x[np.isfinite(x)]
    n = x.size
    if n < 2:
        return None
    cdf = (np.arange(1, n + 1) / n) ** n
    pmf = np.diff(cdf, prepend=0.0)
    mean = float(pmf @ x)
    return math.sqrt(max(float(pmf @ (x - mean) ** 2), 0.0))


def spring_nrmse(ctx: StageContext) -> dict:
    claim = Claim("spring_nrmse_below_2_5pct", "The polytropic spring model fits every spring test with NRMSE below 2.5 %",
                  PLA, "%", f"largest NRMSE of the spring tests < {PLA_NRMSE_LIMIT_PCT:g} %")
    st = _table(ctx, "spring_tests")
    if st is None:
        return _row(claim, "spring_tests")
    v = pd.to_numeric(st["nrmse_pct"], errors="coerce").dropna()
    if v.empty:
        return _row(claim, "spring_tests", detail="no data: no spring test could be fitted")
    above = int((v >= PLA_NRMSE_LIMIT_PCT).sum())
    se = bootstrap_se_of_max(v)
    how = ("uncertainty: bootstrap standard error of the largest NRMSE over the tests (exact, resampling the tests)"
           if se is not None else "uncertainty: not available from one test")
    return _row(claim, "spring_tests", v.max(), se, above == 0, len(v), None,
                f"{above} of {len(v)} tests at or above {PLA_NRMSE_LIMIT_PCT:g} %; median {v.median():.3g} %, "
                f"range {v.min():.3g}-{v.max():.3g} %; {how}")


# -- hose durability (seed 000's hypothesis) ------------------------------------------------------------------
def _life_groups(hl: pd.DataFrame, hose_type=None) -> dict:
    if hose_type is not None and "hose_type" in hl.columns:
        hl = hl[hl["hose_type"].astype(str) == str(hose_type)]
    groups = {}
    for adj in ("force", "distance"):
        g = hl[(hl["adjustment"].astype(str) == adj)].dropna(subset=["distance_km"])
        groups[adj] = (g["distance_km"].to_numpy(float), (g["status"].astype(str) == "failed").to_numpy())
    return groups


def force_outlives_distance(ctx: StageContext) -> dict:
    claim = Claim("force_set_hoses_outlive_distance_set",
                  "Hoses with force-set rollers outlive hoses with distance-set rollers", PLPA, "ratio",
                  f"Weibull characteristic life force / distance > 1 and the lives differ (LR test p < {ALPHA:g}), "
                  "in every hose type tested both ways")
    hl = _table(ctx, "hose_life")
    test = _table(ctx, "service_life_test")
    if test is not None and {"scale_force_km", "scale_distance_km", "p_value"} <= set(test.columns):
        t = test.dropna(subset=["scale_force_km", "scale_distance_km"])
        t = t[(t["scale_force_km"] > 0) & (t["scale_distance_km"] > 0)]
        if not t.empty:
            ratios = (t["scale_force_km"] / t["scale_distance_km"]).to_numpy(float)
            i = int(np.argmin(ratios))
            worst = t.iloc[i]
            unc = None
            if hl is not None and "adjustment" in hl.columns:
                groups = _life_groups(hl, worst.get("hose_type"))
                fits = _weibull_fits(ctx, groups)
                if all(f.ok for f in fits.values()):
                    unc = _ratio_uncertainty(groups, fits, ratios[i])
            p = pd.to_numeric(t["p_value"], errors="coerce")
            holds = bool((ratios > 1).all() and p.notna().all() and (p < ALPHA).all())
            n = int(t[["n_force", "n_distance"]].to_numpy().sum()) if {"n_force", "n_distance"} <= set(t.columns) else 0
            detail = "; ".join(
                f"{r.get('hose_type')}: scale {r['scale_force_km']:.3g} km (force, {r.get('n_failed_force')}/"
                f"{r.get('n_force')} failed) vs {r['scale_distance_km']:.3g} km (distance, "
                f"{r.get('n_failed_distance')}/{r.get('n_distance')} failed), LR p = {finite_float(r['p_value']) or float('nan'):.3g}"
                for _, r in t.iterrows())
            return _row(claim, "service_life_test, hose_life", ratios[i], unc, holds, n, p.max(), detail)
    if hl is None or "adjustment" not in hl.columns:
        return _row(claim, "service_life_test, hose_life")
    groups = _life_groups(hl)
    n = sum(len(v[0]) for v in groups.values())
    fails = {k: int(v[1].sum()) for k, v in groups.items()}
    if min(fails.values()) < 2:
        return _row(claim, "hose_life", n=n, detail=f"no data: fewer than two failures in a group "
                                                     f"(force {fails['force']}, distance {fails['distance']})")
    fits = _weibull_fits(ctx, groups)
    if not all(f.ok for f in fits.values()):
        return _row(claim, "hose_life", n=n, detail="no data: the Weibull fit did not converge")
    ratio = fits["force"].scale / fits["distance"].scale
    p = finite_float(sl.weibull_lr_test(groups).get("p_value"))
    detail = (f"all hose types pooled: scale {fits['force'].scale:.3g} km (force, {fits['force'].n_failed}/"
              f"{fits['force'].n} failed) vs {fits['distance'].scale:.3g} km (distance, {fits['distance'].n_failed}/"
              f"{fits['distance'].n} failed)")
    return _row(claim, "hose_life", ratio, _ratio_uncertainty(groups, fits, ratio),
                ratio > 1 and p is not None and p < ALPHA, n, p, detail)


def weibull_fit_item(item: tuple) -> sl.WeibullFit:
    """``(lives [km], failed)`` -> :func:`analyses.service_life.weibull_fit`, for ``ctx.map``: memoised
    by the lives themselves, so a change of another table (a spring test) neither refits the hoses'
    lives nor imports ``scipy.stats`` for them (~1.5 CPU-s of such a change, issue 26)."""
    life, failed = item
    return sl.weibull_fit(np.asarray(life, dtype=float), np.asarray(failed, dtype=bool))


def _weibull_fits(ctx: StageContext, groups: dict) -> dict:
    """Each group's Weibull fit (:func:`weibull_fit_item`), groups as :func:`_life_groups` gives them."""
    keys = list(groups)
    items = [([float(v) for v in groups[k][0]], [bool(v) for v in groups[k][1]]) for k in keys]
    return dict(zip(keys, ctx.map(weibull_fit_item, items, label=f"{NAME}: Weibull fits")))


def _ratio_uncertainty(groups, fits, ratio) -> float | None:
    """Standard uncertainty of the scale ratio (delta method, observed information of each fit)."""

    var = 0.0
    for k, (x, f) in groups.items():
        fit = fits[k]
        lk, ls = math.log(fit.shape), math.log(fit.scale)
        h = 1e-3

        def ll(a, b):
            return sl.weibull_loglik(math.exp(a), math.exp(b), x, f)

        try:
            f0 = ll(lk, ls)
            haa = (ll(lk + h, ls) - 2 * f0 + ll(lk - h, ls)) / h**2
            hbb = (ll(lk, ls + h) - 2 * f0 + ll(lk, ls - h)) / h**2
            hab = (ll(lk + h, ls + h) - ll(lk + h, ls - h) - ll(lk - h, ls + h) + ll(lk - h, ls - h)) / (4 * h**2)
            cov = np.linalg.inv(-np.array([[haa, hab], [hab, hbb]]))
        except (np.linalg.LinAlgError, ValueError, OverflowError):
            return None
        if not np.isfinite(cov[1, 1]) or cov[1, 1] <= 0:
            return None
        var += float(cov[1, 1])
    return ratio * math.sqrt(var)


# -- the decision per hose type (issue 23) ------------------------------------------------------------------
#: The verdicts that hold / do not hold the claim "force-set hoses live longer"; the others ("undecided",
#: "no plan") leave it NULL: the sequential test has not declared anything.
VERDICT_HOLDS = {"force longer": True, "distance longer": False, "no practical difference": False}


def _verdict_claim(hose_type: str, v: dict) -> Claim:
    """The claim of one hose type's verdict finding, with the plan's margin, alpha and spending."""
    margin, alpha = finite_float(v.get("margin")), finite_float(v.get("alpha"))
    plan = ", ".join(x for x in (f"margin {margin:g}" if margin is not None else "",
                                 f"alpha {alpha:g} over all looks" if alpha is not None else "",
                                 f"{v.get('spending')} spending" if v.get("spending") else "") if x)
    return Claim(f"life_verdict:{hose_type}",
                 f"{hose_type} hoses live longer with force-set rollers than with distance-set ones (the decision)",
                 PLPA, "ratio", "sequential verdict 'force longer': a repeated confidence interval of the life ratio "
                 f"force / distance above 1 at a look ({plan or 'plan unknown'}); 'distance longer' or "
                 "'no practical difference' do not hold; undecided or without plan.toml: not yet checkable")


def _count(value) -> str:
    """A count as text (``14``, not ``14.0`` of a float column with NULLs); ``?`` when absent."""
    x = finite_float(value)
    return "?" if x is None else f"{x:.0f}"


def _verdict_detail(v: dict, e: dict) -> str:
    """How one hose type's verdict was reached, in one line (NULL numbers said to be absent)."""
    failures, top = _count(v.get("failures")), _count(v.get("max_failures"))
    parts = [f"verdict '{v.get('verdict')}' after {failures} of {top} failures"
             f" ({v.get('max_failures_from') or 'maximum of unknown origin'}, margin from {v.get('plan_from')})"]
    if v.get("verdict") == "no plan":
        parts.append("no plan.toml: numbers with the built-in defaults, no verdict declared")
    if v.get("decided_at") is not None:
        parts.append(f"decided at look {_count(v.get('decided_at_look'))} ({v['decided_at']:%Y-%m-%d}): ratio "
                     f"{finite_float(v.get('decided_ratio')) or float('nan'):.3g}, repeated CI "
                     f"{finite_float(v.get('decided_lower')) or float('nan'):.3g}-"
                     f"{finite_float(v.get('decided_upper')) or float('nan'):.3g}")
    if finite_float(e.get("life_ratio")) is None:
        parts.append("no life ratio: " + str(e.get("note") or v.get("note") or "life_effect has no estimate"))
    else:
        parts.append(f"life ratio {e['life_ratio']:.3g} ({100 * (finite_float(e.get('confidence')) or 0.9):.0f} % "
                     f"profile-likelihood CI {finite_float(e.get('life_ratio_lower')) or float('nan'):.3g}-"
                     f"{finite_float(e.get('life_ratio_upper')) or float('nan'):.3g}, {e.get('model')}), "
                     f"{_count(e.get('n_failed_force'))}/{_count(e.get('n_force'))} force-set and "
                     f"{_count(e.get('n_failed_distance'))}/{_count(e.get('n_distance'))} distance-set hoses failed")
    if v.get("note"):
        parts.append(str(v["note"]))
    return "; ".join(parts)


def _verdict_row(v: dict, e: dict) -> dict:
    """The finding of one hose type's verdict: measured = life_effect's ratio with its standard
    uncertainty from the profile-likelihood interval (log scale); holds from the verdict."""
    claim = _verdict_claim(str(v["hose_type"]), v)
    ratio = finite_float(e.get("life_ratio"))
    unc = _std_from_ci({"estimate": ratio, "ci_low": e.get("life_ratio_lower"), "ci_high": e.get("life_ratio_upper"),
                        "confidence": e.get("confidence")}, log=True) if ratio is not None else None
    return _row(claim, "life_verdict, life_effect", ratio, unc, VERDICT_HOLDS.get(v.get("verdict")),
                v.get("failures"), None, _verdict_detail(v, e))


def _nulls(record: dict) -> dict:
    """A table row with its missing values (NaN, NaT, pd.NA) as None."""
    return {k: (None if pd.api.types.is_scalar(x) and not isinstance(x, str) and pd.isna(x) else x)
            for k, x in record.items()}


def life_verdicts(ctx: StageContext) -> list[dict]:
    """One finding per hose type of ``life_verdict`` (none before the decision stage ran), each
    computed alone: a hose type whose row cannot be read gives holds NULL and the error."""
    verdicts = _table(ctx, "life_verdict")
    if verdicts is None:
        return []
    effects = _table(ctx, "life_effect")
    by_type = ({str(r["hose_type"]): _nulls(r) for r in effects.to_dict("records")} if effects is not None
               and "hose_type" in effects.columns else {})
    rows = []
    for v in sorted(verdicts.to_dict("records"), key=lambda r: str(r["hose_type"])):
        v = _nulls(v)
        try:
            rows.append(_verdict_row(v, by_type.get(str(v["hose_type"]), {})))
        except UndeclaredRead:
            raise
        except Exception as exc:
            row = _row(_verdict_claim(str(v["hose_type"]), {}), "life_verdict, life_effect")
            rows.append({**row, "detail": "could not be computed: " + " ".join(f"{type(exc).__name__}: {exc}".split())})
    return rows


#: The checks, each with the finding_id it declares: a check that raises still gives a row under
#: its own id (holds NULL, the error in detail), so a change of its result stays trackable.
CHECKS: tuple[tuple[str, Callable[[StageContext], dict]], ...] = (
    ("breakaway_0bar_twice", breakaway_ratio),
    ("breakaway_rate_no_effect", breakaway_rate),
    ("no_leak_33pct_5bar", lambda ctx: leak_free(ctx, 33, 5)),
    ("no_leak_66pct_6bar", lambda ctx: leak_free(ctx, 66, 6)),
    ("viscous_independent_of_backpressure_1_3bar", viscous_backpressure),
    ("no_stribeck_dip", stribeck),
    ("spring_nrmse_below_2_5pct", spring_nrmse),
    ("force_set_hoses_outlive_distance_set", force_outlives_distance),
)


def _failed_row(finding_id: str, check, exc: Exception) -> dict:
    """The row of a check that raised: its statement (from its no-data row), holds NULL, the error."""
    error = " ".join(f"{type(exc).__name__}: {exc}".split())
    try:
        row = check(StageContext(raw=None, warehouse=None, runs=pd.DataFrame(), results={}))
    except Exception:
        row = _row(Claim(finding_id, "(finding could not be computed)", "", "", ""), "")
    return {**_row(Claim(finding_id, row["statement"], row["paper"], row["unit"], row["criterion"]), row["source_tables"]),
            "detail": f"could not be computed: {error}"}


def run(ctx: StageContext) -> StageOutput:
    rows = []
    for i, (finding_id, check) in enumerate(CHECKS):
        try:
            row = check(ctx)
            if row["finding_id"] != finding_id:
                raise ValueError(f"check returned finding_id {row['finding_id']!r}, declared {finding_id!r}")
        except UndeclaredRead:  # a bug of the stage's READS, not a finding without data: fail the rebuild
            raise
        except Exception as exc:  # a finding that cannot be computed is NULL with the error, never a crash
            row = _failed_row(finding_id, check, exc)
        row["ord"] = i + 1
        rows.append(row)
    for row in life_verdicts(ctx):  # after the papers' findings, by hose type
        row["ord"] = len(rows) + 1
        rows.append(row)
    df = pd.DataFrame(rows, columns=COLUMNS)
    df["holds"] = df["holds"].astype("boolean")
    df["n"] = df["n"].astype("int64")
    return StageOutput(tables={"findings": df})
