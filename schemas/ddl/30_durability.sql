-- Durability and hose service life (pipeline/stages/durability.py, analyses/durability.py,
-- analyses/service_life.py, pipeline/raw/logbook.py). Contract columns first (warehouse.md), then ours.

-- One row per durability run. Distance = sum of stroke lengths between turning points found
-- with a reversal deadband (deadband_mm); strokes are one-way travels (a cycle is two).
CREATE TABLE durability_runs (
    run_id            VARCHAR NOT NULL,
    hose_id           VARCHAR,
    distance_km       DOUBLE,              -- NULL when the run could not be analysed or its strokes are not
                                           -- detectable (note; see runs.warnings)
    strokes           BIGINT,
    duration_h        DOUBLE,
    campaign          VARCHAR,
    started_at        TIMESTAMPTZ,
    n_samples         BIGINT,
    mean_speed_m_s    DOUBLE,              -- distance / duration
    mean_stroke_mm    DOUBLE,
    dp_friction_bar   DOUBLE,              -- mean over strokes of direction * mean(p_a - p_b)
    friction_n        DOUBLE,              -- dp_friction_bar * hose_area_m2, when the run gives the area
    deadband_mm       DOUBLE,              -- reversal deadband used: 20 x the position sensor floor
    note              VARCHAR              -- NULL when sound, else why distance/strokes are NULL
);

-- One row per stroke of a durability run: the trend of friction and speed over a hose's life.
CREATE TABLE durability_strokes (
    run_id            VARCHAR NOT NULL,
    hose_id           VARCHAR,
    stroke            BIGINT,              -- 0-based index in the run
    direction         INTEGER,             -- +1 toward +x, -1 toward -x
    t_start_s         DOUBLE,              -- turning point the stroke starts from (run time)
    t_end_s           DOUBLE,
    length_mm         DOUBLE,
    mean_speed_m_s    DOUBLE,              -- length / (t_end - t_start)
    dp_mean_bar       DOUBLE,              -- mean of p_a - p_b over the stroke
    dp_friction_bar   DOUBLE,              -- direction * dp_mean_bar: friction indicator
    friction_n        DOUBLE,              -- dp_friction_bar * hose_area_m2 (NULL without the area)
    n_samples         BIGINT
);

-- One row per hose of the merged logbooks (and per hose named by runs but in no logbook).
CREATE TABLE hose_life (
    hose_id           VARCHAR NOT NULL,
    hose_type         VARCHAR,
    adjustment        VARCHAR,
    distance_km       DOUBLE,              -- runs if any cover the hose, else odometer, else 0 (running) / NULL
    strokes           BIGINT,              -- NULL without analysed runs
    status            VARCHAR,             -- failed / removed / running
    failure_mode      VARCHAR,
    n_runs            BIGINT,
    z_rollers_mm      DOUBLE,
    spring_force_n    DOUBLE,
    runs_km           DOUBLE,              -- distance of its durability runs (NULL without runs)
    odometer_km       DOUBLE,              -- distance_km of its latest failed/removed logbook event
    distance_source   VARCHAR,             -- runs / odometer / none
    installed_at      TIMESTAMPTZ,         -- first installation
    ended_at          TIMESTAMPTZ,         -- failed/removed time, NULL while running
    n_installations   BIGINT,              -- > 1 when reinstalled (life continues)
    campaigns         VARCHAR[],           -- campaigns whose logbooks mention it
    wall_thickness_mm DOUBLE,              -- last inspection
    warnings          VARCHAR[],           -- e.g. runs and odometer disagree by more than 2 %
    odometer_at       TIMESTAMPTZ          -- time of the logbook event that gave odometer_km (NULL without one)
);

-- One row per (hose_type, adjustment): the table a Weibull++ user expects. Weibull by maximum
-- likelihood (MLE) with right-censoring; every bound two-sided, likelihood ratio (profile
-- likelihood, Meeker & Escobar 1998 ch. 8) at the plan's confidence; median-rank regression
-- (MRR: rank regression on X, Benard's median ranks, Johnson's adjusted ranks) beside it.
CREATE TABLE service_life (
    hose_type         VARCHAR,
    adjustment        VARCHAR,
    n_hoses           BIGINT,
    n_failed          BIGINT,
    weibull_shape     DOUBLE,              -- MLE shape (beta); NULL with fewer than two failures
    weibull_scale_km  DOUBLE,              -- MLE scale (eta: the distance by which 63.2 % have failed)
    b10_km            DOUBLE,              -- distance by which 10 % have failed (MLE)
    b10_lower_km      DOUBLE,              -- lower bound of `b10_km` at `confidence`
    b10_upper_km      DOUBLE,              -- upper bound of `b10_km` at `confidence`
    confidence        DOUBLE,              -- two-sided confidence of every bound: the plan's `confidence`
    n_suspended       BIGINT,              -- removed + running hoses
    b10_method        VARCHAR,             -- how the bounds were computed
    loglik            DOUBLE,              -- log-likelihood at the Weibull MLE
    note              VARCHAR,             -- NULL when sound, else why the Weibull columns are NULL
                                           -- (fewer than two failures, shape MLE at the search bound)
    shape_lower       DOUBLE,              -- lower bound of `weibull_shape` at `confidence`
    shape_upper       DOUBLE,              -- upper bound of `weibull_shape` at `confidence`
    scale_lower_km    DOUBLE,              -- lower bound of `weibull_scale_km` at `confidence`
    scale_upper_km    DOUBLE,              -- upper bound of `weibull_scale_km` at `confidence`
    b_life_pct        DOUBLE,              -- the B-life's percent failed: the plan's `b_life` (default 10: B10)
    b_life_km         DOUBLE,              -- distance by which b_life_pct % have failed (MLE)
    b_life_lower_km   DOUBLE,              -- lower bound of `b_life_km` at `confidence`
    b_life_upper_km   DOUBLE,              -- upper bound of `b_life_km` at `confidence`
    mission_km        DOUBLE,              -- the plan's `mission_km`; NULL when the plan states none
    reliability_at_mission DOUBLE,         -- fraction surviving mission_km, exp(-(mission/scale)^shape) (MLE)
    reliability_at_mission_lower DOUBLE,   -- lower bound of `reliability_at_mission` at `confidence`
    reliability_at_mission_upper DOUBLE,   -- upper bound of `reliability_at_mission` at `confidence`
    mrr_shape         DOUBLE,              -- median-rank regression's shape
    mrr_scale_km      DOUBLE,              -- median-rank regression's scale
    mrr_b_life_km     DOUBLE,              -- median-rank regression's B-life (at b_life_pct)
    preferred_method  VARCHAR,             -- MRR (2-20 failures) or MLE (more): the point estimate to quote
                                           -- (Abernethy 2006, ch. 5); the bounds are the likelihood's either way
    bounds_note       VARCHAR              -- NULL when every bound exists, else which the data do not reach
);

-- Kaplan-Meier survival per (hose_type, adjustment): one row per distinct hose distance.
CREATE TABLE hose_survival (
    hose_type         VARCHAR,
    adjustment        VARCHAR,
    distance_km       DOUBLE,
    n_at_risk         BIGINT,
    n_failed          BIGINT,
    n_censored        BIGINT,
    survival          DOUBLE,              -- just after distance_km
    std_err           DOUBLE               -- Greenwood
);

-- Per hose type: do force-set and distance-set hoses differ? Likelihood-ratio test of one common
-- Weibull against one per setting (chi-square, df = 2). NULL when a setting has < 2 failures.
CREATE TABLE service_life_test (
    hose_type         VARCHAR,
    n_force           BIGINT,
    n_failed_force    BIGINT,
    n_distance        BIGINT,
    n_failed_distance BIGINT,
    shape_force       DOUBLE,
    scale_force_km    DOUBLE,
    shape_distance    DOUBLE,
    scale_distance_km DOUBLE,
    lr                DOUBLE,
    df                BIGINT,
    p_value           DOUBLE
);

-- Leakage plateaus (leakage_map) of runs naming a hose, placed at the hose's distance when the
-- leakage run started (durability runs of that hose that started before it).
CREATE TABLE hose_leak_growth (
    hose_id           VARCHAR NOT NULL,
    run_id            VARCHAR NOT NULL,
    started_at        TIMESTAMPTZ,
    distance_km       DOUBLE,
    adjustment        VARCHAR,
    chamber           VARCHAR,
    pressure_bar      DOUBLE,
    leak_l_min        DOUBLE,
    hose_status       VARCHAR
);
