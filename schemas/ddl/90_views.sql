-- Ready views for the morning queries. They only use contract columns of tables created by the
-- DDL files loaded before this one (views are evaluated when queried, so they see the data).
-- "What changed in the last rebuild" lives with the rebuild tables (96_rebuild.sql).

-- The most recent run of every kind (by started_at, then run_id), with its headline result in
-- words: what did the bench last do, and what came out of it? Leakage: the largest plateau leak,
-- the pressure of that plateau (on equal leaks the lowest such pressure) and the plateau count.
-- Breakaway: the forces in onset order. Step: the step count and the largest overshoot and
-- settling time over all steps ("up to": they may be of different steps). Pressure_step: the step
-- count, the set-point range and how many steps were fitted (not their NRMSE: it is the pooled
-- fit's, so it would move with every run of the group; pressure_dynamics has it). The result is
-- NULL for timeseries runs (catalogued, never analysed: no stage table has rows for them) and for
-- a run its stage wrote no row for.
CREATE VIEW latest_results AS
WITH latest AS (
    SELECT * FROM runs
    QUALIFY row_number() OVER (PARTITION BY kind ORDER BY started_at DESC NULLS LAST, run_id DESC) = 1
),
results AS (
    SELECT run_id, 'max leak ' || round(max(leak_l_min), 3) || ' l/min at '
           || round(first(pressure_bar ORDER BY leak_l_min DESC NULLS LAST, pressure_bar NULLS LAST), 2)
           || ' bar, ' || count(*) || ' plateaus' AS result
    FROM leakage_map GROUP BY run_id
    UNION ALL
    SELECT run_id, 'breakaway ' || coalesce(string_agg(round(breakaway_force_n, 2)::VARCHAR, ', '
                                                       ORDER BY onset_t_s NULLS LAST), 'none') || ' N'
    FROM breakaway GROUP BY run_id
    UNION ALL
    SELECT run_id, count(*) || ' constant-velocity passes, |v| up to ' || round(max(abs(velocity_m_s)), 3) || ' m/s'
    FROM viscous_points GROUP BY run_id
    UNION ALL
    SELECT run_id, 'wn ' || round(any_value(wn_rad_s), 2) || ' rad/s, zeta ' || round(any_value(zeta), 3)
           || ', k ' || round(any_value(k_lin_m_v_s), 3) || ' m/(V s), fit ' || round(any_value(fit_pct), 1) || ' %'
    FROM identification GROUP BY run_id
    UNION ALL
    SELECT run_id, count(*) || ' steps, overshoot up to ' || round(max(overshoot_pct), 2) || ' %, settling up to '
           || round(max(settling_time_s), 2) || ' s'
    FROM step_response GROUP BY run_id
    UNION ALL
    SELECT run_id, count(*) || ' steps between ' || round(least(min(p_from_bar), min(p_to_bar)), 2) || ' and '
           || round(greatest(max(p_from_bar), max(p_to_bar)), 2) || ' bar gauge, ' || count(nrmse_pct) || ' fitted'
    FROM pressure_steps GROUP BY run_id
    UNION ALL
    SELECT run_id, 'NRMSE ' || round(any_value(nrmse_pct), 2) || ' %' FROM spring_tests GROUP BY run_id
    UNION ALL
    SELECT run_id, round(any_value(distance_km), 4) || ' km, ' || any_value(strokes) || ' strokes, '
           || round(any_value(duration_h), 2) || ' h'
    FROM durability_runs GROUP BY run_id
)
SELECT l.kind, l.run_id, l.campaign, l.rig, l.started_at, l.n_samples, l.duration_s,
       json_extract_string(l.params, '$.hose_id') AS hose_id,
       r.result, l.warnings, l.source_path
FROM latest l LEFT JOIN results r USING (run_id)
ORDER BY l.kind;

-- One row per campaign (first folder under raw/): what is in it, when it ran, how much of it
-- could be used, and what it did to hoses.
CREATE VIEW campaign_summary AS
WITH r AS (
    SELECT campaign,
           count(*) AS n_runs,
           list_sort(list_distinct(list(kind))) AS kinds,
           min(started_at) AS first_run_at,
           max(started_at) AS last_run_at,
           sum(n_samples) AS n_samples,
           round(sum(duration_s) / 3600.0, 3) AS data_h,
           count(*) FILTER (WHERE len(warnings) > 0) AS n_runs_with_warnings
    FROM runs GROUP BY campaign
),
q AS (SELECT campaign, count(*) AS n_quarantined FROM quarantine WHERE campaign IS NOT NULL GROUP BY campaign),
d AS (SELECT campaign, sum(distance_km) AS durability_km, sum(strokes) AS durability_strokes
      FROM durability_runs GROUP BY campaign),
h AS (SELECT c.campaign, count(*) AS n_hoses,
             count(*) FILTER (WHERE status = 'failed') AS n_hoses_failed
      FROM hose_life, unnest(campaigns) AS c(campaign) GROUP BY c.campaign),
k AS (SELECT campaign FROM r UNION SELECT campaign FROM q UNION SELECT campaign FROM h)
SELECT k.campaign,
       coalesce(r.n_runs, 0) AS n_runs, r.kinds, r.first_run_at, r.last_run_at, r.n_samples, r.data_h,
       coalesce(r.n_runs_with_warnings, 0) AS n_runs_with_warnings,
       coalesce(q.n_quarantined, 0) AS n_quarantined,
       d.durability_km, d.durability_strokes,
       coalesce(h.n_hoses, 0) AS n_hoses, coalesce(h.n_hoses_failed, 0) AS n_hoses_failed
FROM k LEFT JOIN r USING (campaign) LEFT JOIN q USING (campaign) LEFT JOIN d USING (campaign)
       LEFT JOIN h USING (campaign)
ORDER BY k.campaign;

-- Every run that names a hose (durability, leakage, ...), in time order per hose, with the
-- hose's distance when the run started (durability distance of its earlier runs).
CREATE VIEW hose_runs AS
WITH named AS (
    SELECT json_extract_string(r.params, '$.hose_id') AS hose_id, r.run_id, r.kind, r.campaign, r.started_at,
           r.duration_s, d.distance_km, d.strokes, r.warnings
    FROM runs r LEFT JOIN durability_runs d USING (run_id)
    WHERE json_extract_string(r.params, '$.hose_id') IS NOT NULL
)
SELECT hose_id, run_id, kind, campaign, started_at, duration_s, distance_km, strokes,
       coalesce(sum(CASE WHEN kind = 'durability' THEN distance_km END) OVER (
           PARTITION BY hose_id ORDER BY started_at, run_id
           ROWS BETWEEN UNBOUNDED PRECEDING AND 1 PRECEDING), 0) AS hose_km_before,
       warnings
FROM named
ORDER BY hose_id, started_at, run_id;

-- One row per hose (from the logbooks and the runs): its life and how many runs of each kind
-- it saw. Runs are counted by the hose_id they name, whatever their time (hose_life.n_runs counts
-- only durability runs inside an installation).
CREATE VIEW runs_per_hose AS
WITH c AS (
    SELECT hose_id,
           count(*) AS n_runs,
           count(*) FILTER (WHERE kind = 'durability') AS n_durability_runs,
           count(*) FILTER (WHERE kind = 'leakage') AS n_leakage_runs,
           min(started_at) AS first_run_at,
           max(started_at) AS last_run_at,
           list_sort(list_distinct(list(campaign))) AS run_campaigns
    FROM hose_runs GROUP BY hose_id
),
ids AS (SELECT hose_id FROM hose_life UNION SELECT hose_id FROM c)
SELECT ids.hose_id, h.hose_type, h.adjustment, h.status, h.failure_mode, h.distance_km, h.strokes,
       coalesce(c.n_runs, 0) AS n_runs, coalesce(c.n_durability_runs, 0) AS n_durability_runs,
       coalesce(c.n_leakage_runs, 0) AS n_leakage_runs, h.n_runs AS n_life_runs,
       c.first_run_at, c.last_run_at, c.run_campaigns, h.campaigns AS logbook_campaigns, h.warnings
FROM ids LEFT JOIN hose_life h USING (hose_id) LEFT JOIN c USING (hose_id)
ORDER BY ids.hose_id;
