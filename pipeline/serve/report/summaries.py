"""Per analysis, the summary a reader compares its figures to: the papers' values beside the
lab's (paper value, measured value with its standard uncertainty, difference; the values from
:mod:`schemas.papers`), and the tables that sum an analysis up (seal and leak per roller
setting, friction fits, service life, hoses). Each ``summary_*`` takes the database and returns
HTML, "" when its tables are not there."""
from __future__ import annotations

import math

from pipeline.serve.report.db import ReportDB
from pipeline.serve.report.markup import esc, fmt, significant
from pipeline.serve.report.tables import FLOOR_COLUMN, coarsest_floor_l_min, html_table
from schemas.papers import (PLA_NRMSE_LIMIT_PCT, PLA_TABLE1, PLA_TABLE2, PLA_TABLE3_NRMSE_MAX_PCT,
                            PLA_TABLE3_NRMSE_MIN_PCT, PLPA_FIG12, PLPA_FIG15, PLPA_TABLE2)


def _mean_se(values) -> tuple[float | None, float | None, int]:
    """(mean, standard error, n) of the finite values (the error needs two)."""
    v = [float(x) for x in values if x is not None and not (isinstance(x, float) and math.isnan(x))]
    if not v:
        return None, None, 0
    m = sum(v) / len(v)
    if len(v) < 2:
        return m, None, 1
    sd = math.sqrt(sum((x - m) ** 2 for x in v) / (len(v) - 1))
    return m, sd / math.sqrt(len(v)), len(v)


NUM_CELL = ' class="num"'


def _cmp_row(label: str, unit: str, paper, measured, unc, how: str = "", judge: bool = True) -> str:
    """One row of a paper-vs-lab table: paper value, measured ± uncertainty, difference."""
    m = "—" if measured is None else fmt(measured) + (f" ± {fmt(unc, 2)}" if unc is not None else "")
    if paper is None or measured is None:
        diff, cls = "—", ""
    else:
        d = measured - paper
        rel = f" ({100 * d / paper:+.1f} %)" if paper else ""
        diff = f"{'+' if d >= 0 else ''}{fmt(d, 3)}{rel}"
        # green: within 2 standard uncertainties or 5 % of the paper; red: further; plain for a paper value of
        # zero (no scale to judge a difference by: the sensor's resolution is on the run pages)
        if not paper or not judge:
            cls = ""
        elif (unc is not None and abs(d) <= 2 * unc) or (paper and abs(d / paper) < 0.05):
            cls = ' class="num diff-ok"'
        else:
            cls = ' class="num diff-bad"'
    return (f"<tr><td>{esc(label)}</td><td>{esc(unit)}</td><td class=\"num\">{'—' if paper is None else fmt(paper)}</td>"
            f'<td class="num">{m}</td><td{cls or NUM_CELL}>{diff}</td><td>{esc(how)}</td></tr>')


def _cmp_table(caption: str, rows: list[str]) -> str:
    """A paper-vs-lab table with ``caption`` and its rows of :func:`_cmp_row`."""
    return (f'<div class="wrap"><table class="paper"><caption style="text-align:left;font-weight:600;padding:4px 0">'
            f"{esc(caption)}</caption><thead><tr><th>quantity</th><th>unit</th><th>paper</th>"
            "<th>measured ± std. uncertainty</th><th>difference<br><small>measured − paper</small></th>"
            f"<th>from</th></tr></thead><tbody>{''.join(rows)}</tbody></table></div>")


def _q(db: ReportDB, sql: str, *tables: str) -> list[tuple]:
    """The rows of ``sql``, none when one of ``tables`` is not there."""
    if not all(db.has(t) for t in tables):
        return []
    return db.con.execute(sql).fetchall()


def summary_identification(db: ReportDB) -> str:
    """PLPA Table 2: the identified plant parameters, paper vs lab."""
    rows = _q(db, "SELECT wn_rad_s, zeta, k_lin_m_v_s FROM identification", "identification")
    if not rows:
        return ""
    out = []
    for k, (col, label, unit) in enumerate((("wn_rad_s", "natural frequency ωn", "rad/s"),
                                           ("zeta", "damping ratio ζ", ""),
                                           ("k_lin_m_v_s", "gain k_lin", "m/(V s)"))):
        m, se, n = _mean_se([r[k] for r in rows])
        out.append(_cmp_row(label, unit, PLPA_TABLE2[col], m, se,
                            f"mean of {n} identification run{'s' if n != 1 else ''} ± s.e."))
    return _cmp_table("PLPA Table 2: identified plant parameters, paper vs lab", out)


def summary_breakaway(db: ReportDB) -> str:
    """PLPA Fig. 12: breakaway forces and their ratio, paper vs lab, with the mean force per backpressure."""
    out = []
    r0 = _q(db, "SELECT breakaway_force_n FROM breakaway WHERE backpressure_bar < 0.5", "breakaway")
    r1 = _q(db, "SELECT breakaway_force_n FROM breakaway WHERE backpressure_bar >= 0.5", "breakaway")
    for label, rows, key in (("breakaway force at 0 bar backpressure", r0, "mean_0bar_n"),
                             ("breakaway force at ≥ 1 bar backpressure", r1, "mean_ge1bar_n")):
        m, se, n = _mean_se([r[0] for r in rows])
        if n:
            out.append(_cmp_row(label, "N", PLPA_FIG12[key], m, se, f"mean of {n} events ± s.e."))
    f = {r[0]: r[1:] for r in _q(db, "SELECT finding, estimate, ci_low, ci_high, confidence, n FROM breakaway_findings "
                                      "WHERE direction = 'all'", "breakaway_findings")}
    for key, label, unit, paper in (("backpressure_ratio", "ratio 0 bar / ≥ 1 bar", "", PLPA_FIG12["ratio"]),
                                    ("force_rate_slope", "effect of the force rate (slope)", "N per N/s",
                                     PLPA_FIG12["rate_slope"])):
        if key in f and f[key][0] is not None:
            est, lo, hi, conf, n = f[key]
            se = (hi - lo) / (2 * 1.96) if lo is not None and hi is not None else None
            out.append(_cmp_row(label, unit, paper, est, se,
                                f"breakaway_findings, {n} events; {100 * (conf or 0.95):.0f} % CI "
                                f"{fmt(lo, 3)}–{fmt(hi, 3)}" if lo is not None else "breakaway_findings"))
    if not out:
        return ""
    table = _cmp_table("PLPA Fig. 12: breakaway forces, paper vs lab (paper: about twice at 0 bar, no rate effect)", out)
    summary = _q(db, "SELECT backpressure_bar, direction, sum(n) AS n, sum(n * mean_force_n) / sum(n) AS mean_force_n, "
                     "max(std_force_n) AS largest_std_force_n FROM breakaway_summary GROUP BY ALL ORDER BY 1, 2",
                 "breakaway_summary")
    cols = ["backpressure_bar", "direction", "n", "mean_force_n", "largest_std_force_n"]
    return table + ("<h4>Mean breakaway force per backpressure and direction (all rates)</h4>"
                    + html_table(cols, summary, 40) if summary else "")


def summary_step(db: ReportDB) -> str:
    """PLPA Fig. 15: the closed-loop step, paper vs lab.

    The overshoot's and the steady-state error's uncertainties are the steps' standard error
    combined with the position record's resolution as a Type B standard uncertainty
    (``resolution / sqrt(12)``, GUM F.2.2.1; the largest of the steps averaged, in % of the step
    for the overshoot): repeating a step does not average out the count an encoder-closed loop
    settles within, so six identical steps do not make a 5 um encoder tell a micrometre."""
    res = "position_resolution_mm" if "position_resolution_mm" in db.columns("step_response") else "NULL::DOUBLE"
    rows = _q(db, f"SELECT overshoot_pct, settling_time_s, steady_state_error_mm, {res}, step_mm FROM step_response",
              "step_response")
    if not rows:
        return ""
    out = []
    for k, (col, label, unit) in enumerate((("overshoot_pct", "overshoot", "%"),
                                           ("settling_time_s", "settling time (2 % band)", "s"),
                                           ("steady_state_error_mm", "steady-state error", "mm"))):
        m, se, n = _mean_se([r[k] for r in rows])
        source = f"mean of {n} steps ± s.e."
        if col != "settling_time_s" and m is not None:
            used = [r for r in rows if r[k] is not None and not math.isnan(r[k])]
            if col == "overshoot_pct":  # the resolution in % of each step
                res_in_unit = [100.0 * r[3] / abs(r[4]) if r[3] is not None and r[4] else None for r in used]
            else:
                res_in_unit = [r[3] for r in used]
            se, source = _with_resolution(se, res_in_unit, [r[3] for r in used], n)
        out.append(_cmp_row(label, unit, PLPA_FIG15[col], m, se, source))
    return _cmp_table("PLPA Fig. 15: closed-loop 20 mm step under PID, paper vs lab "
                      "(paper: about 1.2 % overshoot, about 4 s to the 2 % band, zero steady-state error)", out)


def _with_resolution(se: float | None, res_in_unit, res_mm, n: int) -> tuple[float | None, str]:
    """The standard uncertainty of a mean of ``n`` steps' values and its caption: the steps' standard
    error ``se`` and the largest of the steps' position resolutions expressed in the value's unit
    (``res_in_unit``) as ``resolution / sqrt(12)``, combined in quadrature; ``res_mm``: the same
    resolutions [mm], for the caption. No resolution known (an older warehouse): the standard error
    alone, said so."""
    known = [float(r) for r in res_in_unit if r is not None and math.isfinite(float(r))]
    if not known:
        return se, f"mean of {n} steps ± s.e. (the position sensor's resolution not known: not included)"
    u = math.sqrt((se or 0.0) ** 2 + (max(known) / math.sqrt(12.0)) ** 2)
    mm = max(float(r) for r in res_mm if r is not None and math.isfinite(float(r)))
    return u, (f"mean of {n} steps; ± s.e. and the position resolution {significant(mm * 1e3, 3)} µm "
               f"as resolution/√12 (GUM)")


def summary_leakage(db: ReportDB) -> str:
    """Seal pressure and leak at 5 and 6 bar per roller setting, from characterisation runs only
    (runs naming a hose are worn-hose checks and are left out)."""
    if not db.has("leakage_map"):
        return ""
    hose = "coalesce(hose_id, '') = ''" if "hose_id" in db.columns("leakage_map") else "true"
    sensors = "sensors" if "sensors" in db.columns("leakage_map") else "NULL::VARCHAR"
    env = db.has("seal_envelope")
    sql = f"""
        WITH m AS (SELECT chamber, adjustment, z_rollers_mm, spring_force_n, run_id, leak_l_min,
                          {sensors} AS sensors, round(pressure_bar) AS nominal_bar FROM leakage_map WHERE {hose}),
        s AS (SELECT chamber, adjustment, z_rollers_mm, spring_force_n,
                     avg(leak_l_min) FILTER (WHERE nominal_bar = 5) AS leak_at_5_bar_l_min,
                     avg(leak_l_min) FILTER (WHERE nominal_bar = 6) AS leak_at_6_bar_l_min,
                     list(DISTINCT sensors) FILTER (WHERE nominal_bar IN (5, 6)) AS leak_floor_l_min,
                     count(DISTINCT run_id) AS n_runs
              FROM m GROUP BY ALL)
        SELECT s.chamber, s.adjustment, coalesce(s.z_rollers_mm, s.spring_force_n) AS setting,
               CASE WHEN s.adjustment = 'distance' THEN 'mm' ELSE 'N' END AS setting_unit,
               {'e.sealed_up_to_bar, e.first_leak_bar,' if env else ''}
               s.leak_at_5_bar_l_min, s.leak_at_6_bar_l_min, s.leak_floor_l_min, s.n_runs
        FROM s {'LEFT JOIN seal_envelope e ON e.chamber = s.chamber AND e.adjustment = s.adjustment AND '
                'e.z_rollers_mm IS NOT DISTINCT FROM s.z_rollers_mm AND '
                'e.spring_force_n IS NOT DISTINCT FROM s.spring_force_n' if env else ''}
        ORDER BY s.chamber, s.adjustment, setting"""
    cols, rows = db.rows(sql)
    if not rows:
        return ""
    # the floor of a mean over runs: the coarsest flow sensor among them (leak cells under it read "< floor")
    j = cols.index(FLOOR_COLUMN)
    rows = [(*r[:j], coarsest_floor_l_min(r[j]), *r[j + 1:]) for r in rows]
    return ("<h4>Seal and leak per roller setting (characterisation runs only; worn-hose checks left out)</h4>"
            + html_table(cols, rows, 60))


def summary_viscous(db: ReportDB) -> str:
    """The Coulomb + viscous fits per backpressure and direction, and the transition near zero velocity."""
    if not db.has("viscous_fits"):
        return ""
    want = [c for c in ("backpressure_bar", "direction", "coulomb_n", "coulomb_se_n", "viscous_n_s_m",
                        "viscous_se_n_s_m", "nrmse_pct", "n_points", "note") if c in db.columns("viscous_fits")]
    cols, rows = db.rows(f"SELECT {', '.join(want)} FROM viscous_fits ORDER BY backpressure_bar, direction")
    out = "<h4>Coulomb + viscous fit per backpressure and direction</h4>" + html_table(cols, rows, 40)
    if db.has("viscous_transition") and db.count("viscous_transition"):
        vt = [c for c in ("backpressure_bar", "transition_velocity_mm_s", "stribeck_amplitude_n",
                          "stribeck_p_value", "stribeck_dip", "n_points") if c in db.columns("viscous_transition")]
        cols, rows = db.rows(f"SELECT {', '.join(vt)} FROM viscous_transition ORDER BY backpressure_bar")
        out += "<h4>Near zero velocity: tanh transition and Stribeck test</h4>" + html_table(cols, rows, 20)
    return out


def summary_spring(db: ReportDB) -> str:
    """PLA Tables 1 and 3: the spring model's parameters and its NRMSE over the tests, paper vs lab."""
    return _spring_parameters(db) + _spring_nrmse(db)


def _spring_parameters(db: ReportDB) -> str:
    """PLA Table 1: the spring model's parameters per chamber, paper vs lab."""
    fits = {r[0]: r[1:] for r in _q(db, "SELECT chamber, n_polytropic, ae_m2, epsilon_m2, delta_n_m, n_tests "
                                        "FROM spring_fits", "spring_fits")}
    se_cols = {c: next((x for x in db.columns("spring_fits") if x.startswith(c.split("_")[0] + "_se")), None)
               for c in ("n_polytropic", "ae_m2", "epsilon_m2", "delta_n_m")}
    rows = []
    labels = {"n_polytropic": ("polytropic index n", ""), "ae_m2": ("effective area Ae", "m²"),
              "epsilon_m2": ("ε (Coulomb-like term)", "m²"), "delta_n_m": ("δ (structural damping)", "N/m")}
    for chamber in ("front", "rear"):
        if chamber not in fits:
            continue
        ses = {}
        for c, sc in se_cols.items():
            if sc:
                ses[c] = db.con.execute(f'SELECT "{sc}" FROM spring_fits WHERE chamber = ?', [chamber]).fetchone()[0]
        for k, c in enumerate(("n_polytropic", "ae_m2", "epsilon_m2", "delta_n_m")):
            label, unit = labels[c]
            rows.append(_cmp_row(f"{chamber}: {label}", unit, PLA_TABLE1[chamber][c], fits[chamber][k],
                                 ses.get(c), f"spring_fits, {fits[chamber][4]} tests"
                                 + ("" if ses.get(c) is not None else " (the fit gives no standard error)")))
    return _cmp_table("PLA Table 1: spring model parameters, paper vs lab", rows) if rows else ""


def _spring_nrmse(db: ReportDB) -> str:
    """PLA Table 3: the spring model's NRMSE range per chamber and how many tests reach the paper's bound."""
    nr = _q(db, "SELECT chamber, min(nrmse_pct), max(nrmse_pct), count(nrmse_pct), "
                f"count(*) FILTER (WHERE nrmse_pct >= {PLA_NRMSE_LIMIT_PCT}) "
                "FROM spring_tests GROUP BY chamber ORDER BY chamber", "spring_tests")
    if not nr:
        return ""
    rows = []
    for chamber, lo, hi, n, above in nr:
        rows.append(_cmp_row(f"{chamber}: smallest NRMSE", "%", PLA_TABLE3_NRMSE_MIN_PCT, lo, None, f"{n} spring tests",
                             judge=False))
        rows.append(_cmp_row(f"{chamber}: largest NRMSE", "%", PLA_TABLE3_NRMSE_MAX_PCT, hi, None,
                             f"{above} of {n} tests at or above {PLA_NRMSE_LIMIT_PCT:g} % (the paper's bound)",
                             judge=False))
    return _cmp_table("PLA Table 3: NRMSE of the spring model over the 120 tests, paper range vs lab", rows)


def summary_pressure(db: ReportDB) -> str:
    """PLA Table 2: pressure dynamics per chamber and direction, paper vs lab, and per part and age."""
    grouped = db.has("pressure_dynamics") and "level" in db.columns("pressure_dynamics")
    # the paper's PLA chambers, one pooled row per rig (level 'rig'); other rigs' chambers are not the paper's
    if grouped:
        sql = ("SELECT chamber, direction, wn_rad_s, zeta, nrmse_pct, n_steps, rig, campaign FROM pressure_dynamics "
               "WHERE level = 'rig' AND chamber IN ('front', 'rear') ORDER BY chamber, direction, campaign, rig")
    else:
        sql = ("SELECT chamber, direction, wn_rad_s, zeta, nrmse_pct, n_steps, NULL, NULL FROM pressure_dynamics "
               "ORDER BY chamber, direction")
    rows = _q(db, sql, "pressure_dynamics")
    several = len({(r[6], r[7]) for r in rows}) > 1
    out = []
    for chamber, direction, wn, zeta, nrmse, n, rig, campaign in rows:
        p = PLA_TABLE2.get(direction)
        if p is None:
            continue
        who = f"{chamber} ({rig}, {campaign})" if several else chamber
        out.append(_cmp_row(f"{who}, {direction}: ωn", "rad/s", p["wn_rad_s"], wn, None,
                            f"{n} steps, NRMSE {fmt(nrmse, 3)} %"))
        out.append(_cmp_row(f"{who}, {direction}: ξ", "", p["zeta"], zeta, None, f"{n} steps"))
    html_out = _cmp_table("PLA Table 2: pressure dynamics (Eq. 11), paper vs lab", out) if out else ""
    if grouped:
        want = ["rig", "part_kind", "part_id", "chamber", "direction", "part_age_h", "part_distance_km", "model",
                "wn_rad_s", "zeta", "tau_s", "wn_change_pct", "zeta_change_pct", "tau_change_pct", "n_steps", "note"]
        cols, prow = db.rows(f"SELECT {', '.join(want)} FROM pressure_dynamics WHERE level = 'part' ORDER BY rig, "
                             "part_kind, part_id, chamber, direction, part_age_h NULLS LAST, "
                             "part_distance_km NULLS LAST")
        if prow:
            html_out += ("<h4>Per part and age: pressure dynamics of each valve / hose under test, and the change "
                         "from its youngest age</h4>" + html_table(cols, prow, 40))
    return html_out


#: The service-life table as the report shows it: the Weibull fit (MLE with its bounds, the rank
#: regression beside it), then the plan's B-life and the reliability at its mission distance.
SERVICE_LIFE_FIT = ("hose_type", "adjustment", "n_hoses", "n_failed", "n_suspended", "weibull_shape", "shape_lower",
                    "shape_upper", "weibull_scale_km", "scale_lower_km", "scale_upper_km", "mrr_shape",
                    "mrr_scale_km", "preferred_method", "campaigns", "note")
SERVICE_LIFE_LIFE = ("hose_type", "adjustment", "confidence", "b_life_pct", "b_life_km", "b_life_lower_km",
                     "b_life_upper_km", "mrr_b_life_km", "mission_km", "reliability_at_mission",
                     "reliability_at_mission_lower", "reliability_at_mission_upper", "bounds_note")
#: A warehouse built before the plan's B-life (issue 25, item 17): its B10 table as it was.
SERVICE_LIFE_BEFORE = ("hose_type", "adjustment", "n_hoses", "n_failed", "n_suspended", "weibull_shape",
                       "weibull_scale_km", "b10_km", "b10_lower_km", "b10_upper_km", "confidence", "campaigns", "note")


def summary_service_life(db: ReportDB) -> str:
    """Weibull life per hose type and roller adjustment (MLE with profile-likelihood bounds, median-rank
    regression beside it), the plan's B-life and the reliability at its mission, and the test between
    the adjustments."""
    if not db.has("service_life"):
        return ""
    have = db.columns("service_life")
    order = " FROM service_life ORDER BY hose_type, adjustment"
    if "b_life_km" not in have:
        cols, rows = db.rows(f"SELECT {', '.join(c for c in SERVICE_LIFE_BEFORE if c in have)}{order}")
        out = "<h4>Weibull life and B10 per hose type and roller adjustment</h4>" + html_table(cols, rows, 20)
    else:
        cols, rows = db.rows(f"SELECT {', '.join(c for c in SERVICE_LIFE_FIT if c in have)}{order}")
        out = ("<h4>Weibull life per hose type and roller adjustment: maximum likelihood with its bounds, "
               "median-rank regression beside it</h4>" + html_table(cols, rows, 20))
        cols, rows = db.rows(f"SELECT {', '.join(c for c in SERVICE_LIFE_LIFE if c in have)}{order}")
        out += ("<h4>B-life and reliability at the mission distance (the plan's b_life, mission_km and "
                "confidence)</h4>" + html_table(cols, rows, 20)
                + '<p class="more">Bounds: two-sided, likelihood ratio (profile likelihood). preferred_method: '
                  "the point estimate to quote: median-rank regression with few failures, maximum likelihood "
                  "with many (Abernethy 2006, ch. 5; the rule in docs/analyses.md, \"Hose service life\").</p>")
    if db.has("service_life_test") and db.count("service_life_test"):
        cols, rows = db.rows("SELECT * FROM service_life_test")
        out += "<h4>Force- vs distance-set rollers: likelihood-ratio test</h4>" + html_table(cols, rows, 20)
    return out


def summary_hoses(db: ReportDB) -> str:
    """Every hose: its setting, status, failure mode and distance."""
    if not db.has("hose_life"):
        return ""
    want = [c for c in ("hose_id", "adjustment", "z_rollers_mm", "spring_force_n", "status", "failure_mode",
                        "distance_km", "distance_source", "n_runs", "campaigns") if c in db.columns("hose_life")]
    cols, rows = db.rows(f"SELECT {', '.join(want)} FROM hose_life ORDER BY hose_id")
    return "<h4>Hoses</h4>" + html_table(cols, rows, 60)


