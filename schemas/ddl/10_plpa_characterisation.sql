-- PLPA characterisation: leakage maps, static breakaway, viscous friction (seed 000, section 3).
-- Contract tables (warehouse.md) first; columns after the contract ones are extras of this project.

CREATE TABLE leakage_map (
    run_id          VARCHAR NOT NULL,
    hose_id         VARCHAR,
    chamber         VARCHAR,              -- A / B
    adjustment      VARCHAR,              -- distance / force
    z_rollers_mm    DOUBLE,
    spring_force_n  DOUBLE,
    pressure_bar    DOUBLE,               -- plateau mean, gauge
    leak_l_min      DOUBLE,               -- plateau mean, l/min ANR
    plateau         BIGINT,               -- 0, 1, ... in time order within the run
    t_start_s       DOUBLE,               -- steady part used (transients excluded)
    t_end_s         DOUBLE,
    n_samples       BIGINT,
    leak_std_l_min  DOUBLE,               -- sample scatter of the leak over the plateau
    leak_se_l_min   DOUBLE,               -- standard error of the plateau's mean leak (block means)
    sensors         VARCHAR,              -- pressure and flow sensors used (resolution, noise, source)
    campaign        VARCHAR               -- the run's campaign (stages add_run_columns; here for seal_envelope_at)
);

CREATE TABLE breakaway (
    run_id            VARCHAR NOT NULL,
    direction         VARCHAR,            -- P / N
    backpressure_bar  DOUBLE,
    force_rate_n_s    DOUBLE,
    breakaway_force_n DOUBLE,             -- magnitude; NULL when no motion the position sensor can tell
    onset_t_s         DOUBLE,             -- detected motion onset (last sample before breakaway)
    measured_rate_n_s DOUBLE,             -- drive-force rate over the whole ramp (start to onset, hinge fit)
    measured_rate_se_n_s DOUBLE,          -- its standard error
    x_resolution_m    DOUBLE,             -- position sensor used for the onset: resolution
    x_noise_m         DOUBLE,             -- and noise sigma
    sensor_source     VARCHAR,            -- metadata / estimated / metadata+estimated
    note              VARCHAR             -- NULL when sound, else why a value is NULL
);

CREATE TABLE breakaway_summary (
    direction         VARCHAR,
    backpressure_bar  DOUBLE,
    force_rate_n_s    DOUBLE,
    n                 BIGINT,
    mean_force_n      DOUBLE,
    std_force_n       DOUBLE
);

CREATE TABLE viscous_points (
    run_id            VARCHAR NOT NULL,
    backpressure_bar  DOUBLE,
    velocity_m_s      DOUBLE,             -- signed
    friction_n        DOUBLE,             -- signed
    direction         VARCHAR,            -- P (v > 0) / N (v < 0)
    pass_index        BIGINT,
    t_start_s         DOUBLE,
    t_end_s           DOUBLE,
    n_samples         BIGINT,
    friction_std_n    DOUBLE,
    accel_m_s2        DOUBLE,             -- residual acceleration over the pass (diagnostic)
    force_source      VARCHAR,            -- 'f' (load cell / stated force balance) or 'pressures' ((p_a - p_b) A)
    velocity_se_m_s   DOUBLE,             -- standard error of the pass velocity
    x_resolution_m    DOUBLE,             -- position sensor the passes were detected with: resolution
    x_noise_m         DOUBLE,             -- and noise sigma
    sensor_source     VARCHAR             -- metadata / estimated / metadata+estimated
);

CREATE TABLE viscous_fits (
    backpressure_bar  DOUBLE,
    direction         VARCHAR,            -- P / N
    coulomb_n         DOUBLE,             -- magnitude for both directions
    viscous_n_s_m     DOUBLE,
    nrmse_pct         DOUBLE,
    n_points          BIGINT,
    coulomb_se_n      DOUBLE,
    viscous_se_n_s_m  DOUBLE,
    min_speed_m_s     DOUBLE,             -- slower points left out of the fit
    n_speed_levels    BIGINT,             -- distinct speed levels among the points (>= 2 to fit)
    note              VARCHAR             -- NULL when sound, else why coulomb/viscous are NULL
);

-- Seal envelope per roller setting: highest tested pressure with leak below threshold, from the
-- setting's characterisation runs (runs naming no hose_id); a setting with only hose checks
-- (runs naming a hose_id) falls back to them (runs_used = 'hose_checks'). analyses/leakage.py.
CREATE TABLE seal_envelope (
    chamber           VARCHAR,
    adjustment        VARCHAR,
    z_rollers_mm      DOUBLE,
    spring_force_n    DOUBLE,
    spring_force_pct  DOUBLE,             -- of 1300 N
    threshold_l_min   DOUBLE,
    sealed_up_to_bar  DOUBLE,             -- NULL: leaking from the lowest tested pressure
    first_leak_bar    DOUBLE,             -- NULL: no tested pressure leaks
    max_tested_bar    DOUBLE,
    sealed_at_max     BOOLEAN,
    max_leak_l_min    DOUBLE,
    n_pressures       BIGINT,
    runs_used         VARCHAR,            -- characterisation / hose_checks (no characterisation run)
    n_runs            BIGINT,
    note              VARCHAR             -- NULL when sound; else why sealed_up_to/first_leak are NULL
);

-- Section 3.2.1 findings as numbers: backpressure_ratio (0 bar / >= 1 bar) and
-- force_rate_slope [N per N/s], per direction P, N and all.
CREATE TABLE breakaway_findings (
    finding           VARCHAR,
    direction         VARCHAR,
    estimate          DOUBLE,
    ci_low            DOUBLE,
    ci_high           DOUBLE,
    confidence        DOUBLE,
    p_value           DOUBLE,
    n                 BIGINT,
    unit              VARCHAR,
    significant       BOOLEAN,
    note              VARCHAR             -- NULL when the estimate stands, else why it is NULL
);

-- Near-zero friction per backpressure: tanh transition velocity and the Stribeck test.
CREATE TABLE viscous_transition (
    backpressure_bar          DOUBLE,
    coulomb_n                 DOUBLE,
    viscous_n_s_m             DOUBLE,
    transition_velocity_mm_s  DOUBLE,
    transition_ci_low_mm_s    DOUBLE,               -- lower confidence bound of `transition_velocity_mm_s`
    transition_ci_high_mm_s   DOUBLE,               -- upper confidence bound of `transition_velocity_mm_s`
    nrmse_pct                 DOUBLE,
    n_points                  BIGINT,
    stribeck_amplitude_n      DOUBLE,
    stribeck_amplitude_se_n   DOUBLE,               -- standard error (least-squares covariance)
    stribeck_velocity_mm_s    DOUBLE,
    stribeck_p_value          DOUBLE,
    stribeck_dip              BOOLEAN,
    note                      VARCHAR       -- NULL when sound, else why values are NULL
);

-- Friction from the whole motion record of a viscous run: inverse-dynamics least squares
-- F_drive = M a + Fv v + Fc sign(v) + offset on zero-phase filtered, decimated data
-- (analyses/friction_dynamic.py). Each parameter has its standard error (<name>_se_<unit>); a
-- parameter the record cannot separate is NULL and note says which and why.
CREATE TABLE friction_dynamic (
    run_id            VARCHAR NOT NULL,
    backpressure_bar  DOUBLE,
    mass_kg           DOUBLE,
    coulomb_n         DOUBLE,
    viscous_n_s_m     DOUBLE,
    offset_n          DOUBLE,
    mass_se_kg        DOUBLE,
    coulomb_se_n      DOUBLE,
    viscous_se_n_s_m  DOUBLE,
    offset_se_n       DOUBLE,
    nrmse_pct         DOUBLE,             -- filtered drive force vs model over the rows used
    n_samples         BIGINT,             -- rows used (after filtering, decimation, rest removed)
    cond              DOUBLE,             -- scaled condition number of the design
    cutoff_hz         DOUBLE,             -- low-pass cut-off chosen from the data
    lag_s             DOUBLE,             -- lag of the drive force behind the motion (negative: it leads);
                                          -- within a sample period it is compensated, longer it voids the
                                          -- mass when compensating it would move the mass beyond mass_se_kg
    lag_se_s          DOUBLE,             -- standard error of lag_s
    force_source      VARCHAR,            -- 'f' or 'pressures'
    x_resolution_m    DOUBLE,
    x_noise_m         DOUBLE,
    sensor_source     VARCHAR,
    note              VARCHAR
);

-- The seal envelope at any leak threshold [l/min ANR], computed from leakage_map like the
-- seal_envelope table (same columns, same characterisation-run rule, same 0.1 bar nominal
-- pressures, repeat runs averaged per nominal pressure):
--     SELECT * FROM seal_envelope_at(0.1);
-- Created after leakage_map; macros are bound when called, so it sees the loaded data.
CREATE MACRO seal_envelope_at(leak_threshold) AS TABLE
WITH m AS (
    SELECT run_id, chamber, adjustment, z_rollers_mm, spring_force_n, leak_l_min,
           coalesce(leak_se_l_min, 0.0) AS leak_se,
           CAST(leak_threshold AS DOUBLE) AS threshold_l_min,
           round_even(pressure_bar / 0.1::DOUBLE, 0) * 0.1::DOUBLE AS nominal_bar,
           coalesce(hose_id, '') <> '' AS hose_check, campaign
    FROM leakage_map
    WHERE pressure_bar IS NOT NULL AND leak_l_min IS NOT NULL AND NOT isnan(pressure_bar) AND NOT isnan(leak_l_min)
),
used AS (   -- characterisation runs; hose checks only for a setting that has nothing else
    SELECT * FROM m
    QUALIFY NOT hose_check
         OR bool_and(hose_check) OVER (PARTITION BY chamber, adjustment, z_rollers_mm, spring_force_n)
),
levels AS ( -- leak per tested (nominal) pressure, repeat runs averaged, and its standard error
    SELECT *, avg(leak_l_min) OVER (PARTITION BY chamber, adjustment, z_rollers_mm, spring_force_n, nominal_bar)
              AS level_leak_l_min,
              sqrt(sum(leak_se * leak_se) OVER (PARTITION BY chamber, adjustment, z_rollers_mm, spring_force_n, nominal_bar))
              / count(*) OVER (PARTITION BY chamber, adjustment, z_rollers_mm, spring_force_n, nominal_bar)
              AS level_se
    FROM used
),
first AS (
    SELECT *, min(CASE WHEN level_leak_l_min >= threshold_l_min THEN nominal_bar END)
              OVER (PARTITION BY chamber, adjustment, z_rollers_mm, spring_force_n) AS first_leak_raw,
              min(CASE WHEN level_se > 0 AND abs(level_leak_l_min - threshold_l_min) <= 2.0 * level_se
                       THEN nominal_bar END)
              OVER (PARTITION BY chamber, adjustment, z_rollers_mm, spring_force_n) AS undecided_bar
    FROM levels
),
decided AS ( -- a level within 2 standard errors of the threshold, at or below the first leak: undecided
    SELECT *, undecided_bar IS NOT NULL AND (first_leak_raw IS NULL OR undecided_bar <= first_leak_raw) AS undecided,
              CASE WHEN undecided_bar IS NOT NULL AND (first_leak_raw IS NULL OR undecided_bar <= first_leak_raw)
                   THEN NULL ELSE first_leak_raw END AS first_leak_bar
    FROM first
)
SELECT chamber, adjustment, z_rollers_mm, spring_force_n,
       100.0::DOUBLE * spring_force_n / 1300.0::DOUBLE AS spring_force_pct,
       any_value(threshold_l_min) AS threshold_l_min,
       CASE WHEN any_value(undecided) THEN NULL
            ELSE max(CASE WHEN first_leak_bar IS NULL OR nominal_bar < first_leak_bar THEN nominal_bar END)
       END AS sealed_up_to_bar,
       any_value(first_leak_bar) AS first_leak_bar,
       max(nominal_bar) AS max_tested_bar,
       CASE WHEN any_value(undecided) THEN NULL ELSE any_value(first_leak_bar) IS NULL END AS sealed_at_max,
       max(level_leak_l_min) AS max_leak_l_min,
       count(DISTINCT nominal_bar) AS n_pressures,
       CASE WHEN bool_and(hose_check) THEN 'hose_checks' ELSE 'characterisation' END AS runs_used,
       count(DISTINCT run_id) AS n_runs,
       CASE WHEN any_value(undecided)
            THEN 'the leak at ' || printf('%.1f', any_value(undecided_bar)) || ' bar cannot be told from the threshold '
                 || '(within 2 standard errors)'
       END AS note,
       list_sort(list_distinct(list(campaign) FILTER (WHERE campaign IS NOT NULL))) AS campaigns   -- as the table (35_run_columns)
FROM decided
GROUP BY chamber, adjustment, z_rollers_mm, spring_force_n
ORDER BY chamber, adjustment, z_rollers_mm, spring_force_n;
