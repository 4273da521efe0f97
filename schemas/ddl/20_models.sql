-- Models: PLPA identification and step response (seed 000), PLA spring and pressure dynamics (seed 001).
-- Filled by pipeline/stages/models.py. The first columns of each contract table are those of
-- warehouse.md; the others are extras.

CREATE TABLE identification (
    run_id            VARCHAR NOT NULL,
    wn_rad_s          DOUBLE,
    zeta              DOUBLE,
    k_lin_m_v_s       DOUBLE,
    fit_pct           DOUBLE,
    kp_v_m            DOUBLE,              -- gain of the stabilising P controller (metadata)
    id_sample_rate_hz DOUBLE,              -- rate the model was identified at
    n_samples_id      BIGINT,              -- samples at that rate
    note              VARCHAR              -- NULL when sound, else why wn/zeta/k are NULL (no excitation,
                                           -- a parameter at a bound, not identifiable, fit_pct too low)
);

CREATE TABLE step_response (
    run_id                 VARCHAR NOT NULL,
    step_mm                DOUBLE,
    overshoot_pct          DOUBLE,
    settling_time_s        DOUBLE,         -- 2 % band
    rise_time_s            DOUBLE,         -- 10-90 %
    steady_state_error_mm  DOUBLE,         -- signed in the step direction (+: short of the reference)
    position_resolution_mm DOUBLE,         -- quantisation step of the position record the step was measured
                                           -- with (metadata, else estimated; 0: not visibly quantised); a mean
                                           -- of steady_state_error_mm over steps is uncertain by at least
                                           -- resolution / sqrt(12) however many steps it averages
    t_step_s               DOUBLE,         -- time of the reference jump in the run
    settled                BOOLEAN,        -- inside the 2 % band over the last 10 % of the step
    note                   VARCHAR         -- NULL when sound, else why metrics are NULL (step under the
                                           -- position sensor floor, 2 % band finer than it, not settled)
);

CREATE TABLE spring_fits (
    chamber           VARCHAR,             -- front / rear
    n_polytropic      DOUBLE,
    ae_m2             DOUBLE,
    epsilon_m2        DOUBLE,
    delta_n_m         DOUBLE,
    n_tests           BIGINT,
    max_nrmse_pct     DOUBLE,              -- worst spring_tests.nrmse_pct of the chamber
    seed_n_polytropic DOUBLE,              -- seeds of the fit (section 3.2 of seed 001)
    seed_ae_m2        DOUBLE,
    seed_epsilon_m2   DOUBLE,
    seed_delta_n_m    DOUBLE,
    note              VARCHAR              -- NULL when sound, else why the parameters are NULL (a parameter at
                                           -- a bound, not identifiable, RMS of the tests' NRMSE over 2.5 %)
);

CREATE TABLE spring_tests (
    run_id            VARCHAR NOT NULL,
    chamber           VARCHAR,
    p0_bar_abs        DOUBLE,              -- read from the run: pressure at mid-stroke
    amplitude_mm      DOUBLE,
    frequency_hz      DOUBLE,
    nrmse_pct         DOUBLE,              -- kept when the chamber's parameters are NULL (the evidence)
    note              VARCHAR              -- NULL when sound; NRMSE over 2.5 % and residuals over the load
                                           -- cell noise, the chamber's fit not reported, or why not fitted
);

-- Energy dissipated per cycle (loop area) of each spring run: the paper's evidence for
-- structural damping (grows with D^2) and against viscous damping (flat in f).
CREATE TABLE spring_loop_energy (
    run_id              VARCHAR NOT NULL,
    chamber             VARCHAR,
    p0_bar_abs          DOUBLE,
    amplitude_mm        DOUBLE,
    frequency_hz        DOUBLE,
    n_cycles            BIGINT,
    loop_energy_j       DOUBLE,            -- measured
    model_loop_energy_j DOUBLE,            -- fitted model over the same displacement
    structural_energy_j DOUBLE             -- pi delta D^2 of the fit
);

-- Per group of steps: first order (tau_s) or second order (wn_rad_s, zeta; Eq. 11), the one with
-- the lower BIC among the fits that pass the quality gates (the second order by > 6). The other
-- model's columns are NULL; all are NULL with a note when neither passes.
-- Groups (`level`): 'rig' = every step of one (campaign, rig, chamber, direction), all parts and
-- ages pooled (one such row per rig: a campaign without part ids has only these, the table it
-- always had); 'part' = the steps of one part under test (the run's valve_id or hose_id) at one
-- age (the run's age_h / distance_km) on that rig. `chamber` is any name the rig gives it.
-- On the demo's PLA (chambers front / rear), `SELECT * FROM pressure_dynamics WHERE chamber =
-- 'front' AND direction = 'charge'` finds one 'rig' row per (campaign, rig) and that rig's 'part'
-- rows (none when the runs name no part); add `AND level = 'rig'` for the pooled rows only. `campaigns` (the row's campaign) and `n_runs` (runs whose steps it pools) are
-- added by 35_run_columns.sql and filled by the stage.
CREATE TABLE pressure_dynamics (
    chamber           VARCHAR,             -- any name (A / B, front / rear, patient, tube ...)
    direction         VARCHAR,             -- charge / discharge
    wn_rad_s          DOUBLE,              -- second order only
    zeta              DOUBLE,              -- second order only; never at an optimiser bound
    nrmse_pct         DOUBLE,              -- of the chosen model over the fitted steps' pressure
    n_steps           BIGINT,              -- steps fitted (large enough for the pressure sensor)
    tau_s             DOUBLE,              -- first order only: time constant
    model             VARCHAR,             -- first_order / second_order; NULL when none is reported
    note              VARCHAR,             -- NULL when sound, else why the parameters are NULL
    level             VARCHAR,             -- rig (pooled over the rig's parts and ages) / part (one part at one age)
    campaign          VARCHAR,             -- first folder under raw/
    rig               VARCHAR,             -- the run's `rig`
    part_kind         VARCHAR,             -- valve / hose (the run's valve_id, else hose_id); NULL on rig rows
    part_id           VARCHAR,             -- the run's valve_id or hose_id; NULL on rig rows
    part_age_h        DOUBLE,              -- the run's age_h: hours of use of the part; NULL when not stated
    part_distance_km  DOUBLE,              -- the run's distance_km: distance run by the part; NULL when not stated
    wn_change_pct     DOUBLE,              -- part rows: 100 (wn / wn of the part's youngest fitted age - 1)
    zeta_change_pct   DOUBLE,              -- part rows: the same for zeta
    tau_change_pct    DOUBLE               -- part rows: the same for tau_s (changes: same rig, chamber and
                                           -- direction, ages by part_age_h else part_distance_km; NULL for the
                                           -- youngest, when the two ages chose different models, on rig rows)
);

-- One row per set-point step of a pressure_step run, with the NRMSE of its finest group's fit
-- (pressure_dynamics: its part's age when the run names a part, else its rig's).
-- Pressures in bar GAUGE (as the pressure_steps figure's axis).
CREATE TABLE pressure_steps (
    run_id            VARCHAR NOT NULL,
    chamber           VARCHAR,
    direction         VARCHAR,             -- charge / discharge
    t_step_s          DOUBLE,
    p_from_bar        DOUBLE,              -- set-point before the step, bar gauge
    p_to_bar          DOUBLE,              -- set-point after the step, bar gauge
    nrmse_pct         DOUBLE,              -- over this step's own pressure range; NULL when not fitted
    p_start_bar       DOUBLE,              -- measured pressure at the step, bar gauge
    note              VARCHAR              -- why the step is not fitted (under the pressure sensor floor) or NULL
);
