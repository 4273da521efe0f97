-- The decision (issue 23; pipeline/stages/decision.py, pipeline/stages/test_plan.py, analyses/life_effect.py,
-- analyses/decision.py, analyses/sequential.py; docs/decision.md). Ratios are force / distance on the ratio
-- scale unless the name says log. Hose types: those with a hose of each adjustment (force, distance) in hose_life.

-- One row per hose type with both adjustments: the force / distance life ratio, common-shape Weibull
-- (Meeker & Escobar 1998, ch. 17) on hose_life (distance_km > 0; failed = exact, removed/running = censored).
CREATE TABLE life_effect (
    hose_type         VARCHAR,             -- as the hose logbooks name it (hose_life.hose_type)
    n_force           BIGINT,              -- force-set hoses with a known positive distance [-]
    n_failed_force    BIGINT,              -- of which failed [-]
    n_distance        BIGINT,              -- distance-set hoses with a known positive distance [-]
    n_failed_distance BIGINT,              -- of which failed [-]
    model             VARCHAR,             -- whose life_ratio: 'common shape' | 'separate shapes' (shape_test_p
                                           -- < the plan's alpha: ratio of each adjustment's own B10) | NULL
    shape             DOUBLE,              -- common Weibull shape, maximum likelihood [-]
    shape_lower       DOUBLE,              -- lower profile-likelihood bound at confidence (Cox-Reid adjusted) [-]
    shape_upper       DOUBLE,              -- upper profile-likelihood bound [-]; NULL when not reached (search edge)
    life_ratio        DOUBLE,              -- force / distance ratio of B10 (of every quantile under a common shape) [-]
    life_ratio_lower  DOUBLE,              -- lower profile-likelihood bound at confidence [-]
    life_ratio_upper  DOUBLE,              -- upper profile-likelihood bound [-]; NULL when the data do not bound it
    confidence        DOUBLE,              -- two-sided confidence of the bounds (the plan's) [-]
    p_value           DOUBLE,              -- likelihood-ratio test of life_ratio = 1 under model [-]
    shape_test_p      DOUBLE,              -- likelihood-ratio test of a common shape against one per adjustment [-]
    note              VARCHAR              -- NULL when sound, else why values are NULL (fewer than two failures
                                           -- in an adjustment, shape at the search edge, a bound not reached)
);

-- One row per hose type with both adjustments: the sequential verdict read at every failure (Lan & DeMets
-- 1983 alpha spending, repeated confidence intervals; Jennison & Turnbull 2000). Once declared it sticks.
CREATE TABLE life_verdict (
    hose_type         VARCHAR,             -- as the hose logbooks name it (hose_life.hose_type)
    verdict           VARCHAR,             -- 'force longer' | 'distance longer' | 'no practical difference' (the
                                           -- interval inside 1/margin .. margin) | 'undecided' | 'no plan'
                                           -- (no usable raw/plan.toml: every number still computed)
    margin            DOUBLE,              -- smallest life ratio worth acting on (plan) [-]
    alpha             DOUBLE,              -- two-sided error rate of the verdict (plan) [-]
    power             DOUBLE,              -- power at the margin the design is for (plan) [-]
    confidence        DOUBLE,              -- confidence of life_effect's intervals (plan) [-]
    spending          VARCHAR,             -- alpha-spending family: obrien-fleming | pocock (plan)
    max_failures      BIGINT,              -- failures (both adjustments) at which the test ends [-]; designed: frozen
                                           -- at the first look with FEW_FAILURES / 2 failures of each adjustment
                                           -- (note: look k and its event time), NULL until that look
    max_failures_from VARCHAR,             -- 'plan' | 'design' (sequential design at margin, alpha, power, the
                                           -- frozen look's own common shape and the hoses on test by its time)
    plan_from         VARCHAR,             -- where the margin came from: 'hose_type' | 'defaults' | 'built-in'
    failures          BIGINT,              -- failures so far (the last look's) [-]
    information_fraction DOUBLE,           -- failures / max_failures, capped at 1 [-]
    looks             BIGINT,              -- looks so far (one per failure) [-]
    life_ratio        DOUBLE,              -- the last look's common-shape estimate [-]
    se_log_ratio      DOUBLE,              -- its standard error on the log scale [-]
    z                 DOUBLE,              -- ln(life_ratio) / se_log_ratio [-]
    boundary_z        DOUBLE,              -- the last look's efficacy boundary on the z scale [-]
    efficacy_lower    DOUBLE,              -- the last look crosses below this ratio: exp(-boundary_z se) [-]
    efficacy_upper    DOUBLE,              -- and above this one: exp(boundary_z se) [-]
    futility_lower    DOUBLE,              -- 'no practical difference' above this ratio (and below futility_upper) [-];
                                           -- NULL while the interval is wider than the margins
    futility_upper    DOUBLE,              -- 'no practical difference' below this ratio [-]; NULL likewise
    rci_lower         DOUBLE,              -- the last look's repeated confidence interval, lower end (1 - alpha over
                                           -- all looks together; the profile likelihood's, deviance <= b boundary_z^2,
                                           -- b = 1 + 3.8 / failures the Bartlett factor) [-]; NULL when the data
                                           -- do not bound that side
    rci_upper         DOUBLE,              -- the last look's repeated confidence interval, upper end [-]; NULL likewise
    decided_at        TIMESTAMPTZ,         -- event time of the deciding look (UTC); NULL until then
    decided_at_look   BIGINT,              -- the deciding look (1..) [-]
    decided_ratio     DOUBLE,              -- estimate at the deciding look [-]
    decided_lower     DOUBLE,              -- repeated confidence interval at the deciding look, lower end [-]
                                           -- (Bartlett-corrected, as rci_lower: it may reach 1 where the look's
                                           -- crossing, at boundary_z^2, decided; the note then says so)
    decided_upper     DOUBLE,              -- repeated confidence interval at the deciding look, upper end [-]
    note              VARCHAR              -- no plan (and what would have been declared), the look max_failures
                                           -- was frozen at (or that it is not yet), looks without an estimate
                                           -- (also those before the freeze) or new information, looks up
                                           -- to the verdict that crossed on the Wald scale only
);

-- One row per (hose type, look): a look at each failure in logbook time order (ties by hose_id), so the
-- history follows from raw/ alone. Boundaries from the plan's spending function at failures / max_failures.
CREATE TABLE decision_looks (
    hose_type         VARCHAR,             -- as the hose logbooks name it (hose_life.hose_type)
    look              BIGINT,              -- 1.. in event order [-]
    event_at          TIMESTAMPTZ,         -- the failure's time in the logbook (UTC)
    hose_id           VARCHAR,             -- the hose that failed
    failures          BIGINT,              -- failures so far, both adjustments [-]
    n_hoses           BIGINT,              -- hoses installed by event_at, in the look (decision_look_hoses) [-]
    total_km          DOUBLE,              -- their distances at event_at summed [km]
    information_fraction DOUBLE,           -- failures / max_failures, capped at 1 [-]; NULL (and no boundary) while
                                           -- no max_failures is frozen (life_verdict.max_failures)
    life_ratio        DOUBLE,              -- common-shape estimate at this look [-]; NULL when the data cannot tell
    se_log_ratio      DOUBLE,              -- its standard error on the log scale (observed information) [-]
    z                 DOUBLE,              -- ln(life_ratio) / se_log_ratio [-]
    boundary_z        DOUBLE,              -- efficacy boundary on the z scale [-]
    alpha_spent       DOUBLE,              -- two-sided alpha spent by this look [-]
    efficacy_lower    DOUBLE,              -- the look crosses below this ratio [-]
    efficacy_upper    DOUBLE,              -- or above this one [-]
    futility_lower    DOUBLE,              -- 'no practical difference' above this ratio (and below futility_upper) [-];
                                           -- NULL while the interval is wider than the margins
    futility_upper    DOUBLE,              -- 'no practical difference' below this ratio [-]; NULL likewise
    rci_lower         DOUBLE,              -- repeated confidence interval, lower end [-]: the ratios whose profile
                                           -- deviance is <= b boundary_z^2, b = 1 + 3.8 / failures the deviance's
                                           -- Bartlett factor (not the Wald life_ratio x/ exp(boundary_z se)); NULL
                                           -- when the deviance stays below it up to 1e6 x the estimate
    rci_upper         DOUBLE,              -- repeated confidence interval, upper end [-]; NULL likewise
    crossed           VARCHAR,             -- what this look's data showed ('force longer', 'distance longer',
                                           -- 'no practical difference'); NULL if nothing. Up to the verdict: the
                                           -- Wald interval (efficacy_*, futility_*) and the profile likelihood
                                           -- (rci_*) both; after it: the Wald interval alone, not checked, said in
                                           -- note
    decides           BOOLEAN,             -- this look declared the verdict (never with no plan)
    note              VARCHAR              -- why the estimate is NULL, hoses placed by odometer (linear in time),
                                           -- no new information past max_failures, a crossing after the verdict
                                           -- not checked by the profile likelihood, a look before the one
                                           -- max_failures was frozen at (does not decide)
);

-- One row per (hose type, look, hose in the look): each hose installed by the look's event at its distance then.
CREATE TABLE decision_look_hoses (
    hose_type         VARCHAR,             -- as the hose logbooks name it (hose_life.hose_type)
    look              BIGINT,              -- decision_looks.look [-]
    hose_id           VARCHAR,             -- hose_life.hose_id
    adjustment        VARCHAR,             -- force / distance
    distance_km       DOUBLE,              -- distance at the look's event [km]: exact life when failed
    failed            BOOLEAN,             -- failed at or before this look (in look order); else censored here
    distance_from     VARCHAR              -- 'runs' (its durability runs up to then; a run under way counts the
                                           -- elapsed fraction of its duration) | 'odometer, linear in time'
                                           -- (between installation and its end event)
);

-- One row per hose type and target power (the plan's, and 0.9; one row if equal): what it takes to decide
-- (pipeline/stages/test_plan.py; Monte Carlo from the fitted model and the current censored state).
CREATE TABLE test_plan (
    hose_type         VARCHAR,             -- as the hose logbooks name it (hose_life.hose_type)
    target_power      DOUBLE,              -- power aimed at [-]
    failures_needed   BIGINT,              -- max_failures of the sequential design for the margin at alpha and
                                           -- target_power [-]
    failures          BIGINT,              -- failures so far [-]
    power_now         DOUBLE,              -- chance to decide if no hose were added and the test ran to
                                           -- max_failures: life_verdict's (the plan's or the frozen one; while
                                           -- none is frozen, failures_needed at the plan's power) [-];
                                           -- failures_needed follows the current shape (what it takes now).
                                           -- Each simulated look is read as the decision stage reads a look:
                                           -- the common-shape Weibull refitted to the simulated lives, the
                                           -- Wald crossing confirmed by the profile likelihood. Predictive:
                                           -- each replicate draws its own shape and scales from the fit's
                                           -- sampling normal (observed information, log scale), then the lives
                                           -- (expected_decision_date's replicates too); at the estimate alone
                                           -- it was optimistic where it is near 1. NULL with
                                           -- fewer than 5 failures (FEW_FAILURES / 2) in an adjustment: the
                                           -- shape from so few is biased high (0.71 predicted against 0.49
                                           -- realised), the freeze waits as long
    more_hoses_per_adjustment BIGINT,      -- the fewest hoses to add per adjustment for failures_needed to be
                                           -- reachable (running hoses continuing, every hose may run to failure) [-]
    more_km           DOUBLE,              -- expected hose-km (all hoses together) to the failures_needed-th
                                           -- failure with the running hoses and those added hoses all on test
                                           -- at once, no replacement [km]: the scenario of
                                           -- more_hoses_per_adjustment, not the lab's benches' schedule
    benches           BIGINT,              -- benches testing this hose type [-]: the plan's, or the most of its
                                           -- hoses' durability runs at once in the last 30 days
    km_per_day        DOUBLE,              -- testing capacity per bench [km/day]
    capacity_from     VARCHAR,             -- 'plan' | 'measured, last 30 days' (this hose type's runs) | NULL
    expected_decision_date DATE,           -- latest event in the data + the median (over the simulations) of
                                           -- the days the lab's benches take to decide or reach failures_needed:
                                           -- benches at km_per_day, running hoses continuing, a failed hose
                                           -- replaced at once, each look read as the decision stage reads it
                                           -- (refit, Wald crossing, likelihood check) at the design's boundaries
                                           -- for failures_needed; NULL without capacity or fitted model
    n_simulations     BIGINT,              -- Monte Carlo replicates behind power_now (0: not simulated, decided
                                           -- or NULL): batches of 1,000 until mc_se <= 0.01, at most 4,000;
                                           -- more_km uses 4,000, expected_decision_date 200-500 (until its
                                           -- median's Monte Carlo error is <= 5 % of it) [-]
    mc_se             DOUBLE,              -- Monte Carlo standard error of power_now [-]
    note              VARCHAR              -- NULL when sound, else why values are NULL
);
