-- Remaining life (issue 24; pipeline/stages/remaining_life.py, analyses/remaining_life.py; docs/decision.md).
-- Models per (hose type, adjustment). Leaks in l/min ANR at the plateau nearest the plan's leak_pressure_bar
-- (within half the plateau spacing), one point per hose and leakage run (the mean over chambers).

-- One row per running hose and method: the distance it has left, median and prediction interval at the plan's
-- confidence (the parameters' uncertainty carried, not only the scatter). NULL with a note when the data cannot tell.
CREATE TABLE hose_rul (
    hose_type         VARCHAR,             -- as the hose logbooks name it (hose_life.hose_type)
    hose_id           VARCHAR,             -- hose_life.hose_id (status running)
    adjustment        VARCHAR,             -- force / distance: the group whose models predict it
    distance_km       DOUBLE,              -- its distance now (hose_life.distance_km) [km]
    method            VARCHAR,             -- 'weibull' (the group's censored life model conditioned on survival to
                                           -- distance_km, integrated over the likelihood: the Weibull and the
                                           -- lognormal mixed by their posterior probabilities, see note) |
                                           -- 'degradation' (its own leak path in the group's pooled random-effects
                                           -- leak-growth model, run to leak_limit_l_min; other failure modes as a
                                           -- competing risk fitted to the logbook's non-leak failures, leak failures
                                           -- censored: the joint model, the first of crossing and rupture; a mode
                                           -- seen once or never: constant hazard, Jeffreys prior on its rate)
    rul_median_km     DOUBLE,              -- median remaining distance [km]
    rul_lower_km      DOUBLE,              -- lower end of the two-sided prediction interval at confidence [km]
    rul_upper_km      DOUBLE,              -- upper end of the prediction interval [km]
    confidence        DOUBLE,              -- two-sided level of the prediction interval (the plan's) [-]
    leak_now_l_min    DOUBLE,              -- its last leak point at leak_pressure_bar [l/min ANR]; NULL without one
    leak_limit_l_min  DOUBLE,              -- the leak that ends a hose's life (plan.toml) [l/min ANR]; NULL when unset
    leak_pressure_bar DOUBLE,              -- the pressure the limit is read at (plan.toml), gauge [bar]; NULL when unset
    n_leak_points     BIGINT,              -- its leak points at that pressure (all, also those under the sensor
                                           -- floor) [-]; NULL when the plan sets no pressure
    note              VARCHAR              -- why the values are NULL (too few leak points, noisy at the sensor
                                           -- floor, a flat or falling path, too few failures, no leak limit in
                                           -- plan.toml); on a 'weibull' row with values, the life families'
                                           -- shares when the lognormal has 5 % or more; else NULL
);

-- One row per (hose type, adjustment, method): the predictions the method would have made for every failed hose
-- at 50 % and 80 % of its life with only the data there was then, against the life it had.
CREATE TABLE rul_backtest (
    hose_type         VARCHAR,             -- as the hose logbooks name it (hose_life.hose_type)
    adjustment        VARCHAR,             -- force / distance
    method            VARCHAR,             -- 'weibull' | 'degradation' (as hose_rul.method)
    n_predictions     BIGINT,              -- backtest predictions with a number (50 % and 80 % of life together) [-]
    coverage          DOUBLE,              -- fraction of their intervals holding the true remaining life [-]
    coverage_at_50    DOUBLE,              -- the same, predictions at 50 % of life only [-]
    coverage_at_80    DOUBLE,              -- the same, predictions at 80 % of life only [-]
    confidence        DOUBLE,              -- nominal level of the intervals (the plan's): coverage should be near it [-]
    median_abs_error_km DOUBLE,            -- median |predicted median - true remaining life| [km]
    note              VARCHAR              -- NULL when sound, else how many had no prediction and the commonest
                                           -- reason, no failed hose to backtest, no leak limit in plan.toml
);

-- One row per hose type with both adjustments and failure definition: the force / distance life ratio and the
-- verdict the decision's rule gives when a failure is defined otherwise than by the logbook.
CREATE TABLE decision_sensitivity (
    hose_type         VARCHAR,             -- as the hose logbooks name it (hose_life.hose_type)
    definition        VARCHAR,             -- 'logbook' (the logbook's failures) | 'leak limit' (first crossing of
                                           -- the plan's limit by the leak path, interpolated between plateaus;
                                           -- never crossed: censored at its last plateau; no leak path: its
                                           -- logbook distance, censored) | 'leak limit x0.5' | 'leak limit x2'
    leak_limit_l_min  DOUBLE,              -- the limit of this definition [l/min ANR]; NULL for logbook
    leak_pressure_bar DOUBLE,              -- the pressure the limit is read at (plan.toml), gauge [bar]
    n_force           BIGINT,              -- force-set hoses with a positive life under this definition [-]
    n_failed_force    BIGINT,              -- of which failed under it [-]
    n_distance        BIGINT,              -- distance-set hoses with a positive life under this definition [-]
    n_failed_distance BIGINT,              -- of which failed under it [-]
    model             VARCHAR,             -- whose life_ratio: the logbook's 'common shape' | 'separate shapes' (as
                                           -- life_effect); the leak-limit definitions' 'lognormal, common sigma'
                                           -- (the crossing law a lognormal wear rate induces; ratio of medians)
    life_ratio        DOUBLE,              -- force / distance ratio of B10 (of every quantile under a common shape) [-]
    life_ratio_lower  DOUBLE,              -- lower profile-likelihood bound at confidence [-]
    life_ratio_upper  DOUBLE,              -- upper profile-likelihood bound [-]; NULL when the data do not bound it
    confidence        DOUBLE,              -- two-sided confidence of the bounds (the plan's) [-]
    verdict           VARCHAR,             -- words of life_verdict.verdict: the decision's rule read once on all of
                                           -- this definition's data now (boundary at failures / max_failures in
                                           -- the plan's design with a look at every failure, profile-likelihood
                                           -- check); 'no plan' without a usable plan.toml
    note              VARCHAR              -- NULL when sound, else hoses censored for want of a leak path, why
                                           -- values are NULL, life_verdict's own verdict where it differs
);
