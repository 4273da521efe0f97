-- Models: PLPA identification and step response (seed 000), PLA spring and pressure dynamics (seed 001).

CREATE TABLE identification (
    run_id            VARCHAR NOT NULL,
    wn_rad_s          DOUBLE,
    zeta              DOUBLE,
    k_lin_m_v_s       DOUBLE,
    fit_pct           DOUBLE
);

CREATE TABLE step_response (
    run_id                 VARCHAR NOT NULL,
    step_mm                DOUBLE,
    overshoot_pct          DOUBLE,
    settling_time_s        DOUBLE,         -- 2 % band
    rise_time_s            DOUBLE,         -- 10-90 %
    steady_state_error_mm  DOUBLE
);

CREATE TABLE spring_fits (
    chamber           VARCHAR,             -- front / rear
    n_polytropic      DOUBLE,
    ae_m2             DOUBLE,
    epsilon_m2        DOUBLE,
    delta_n_m         DOUBLE,
    n_tests           BIGINT
);

CREATE TABLE spring_tests (
    run_id            VARCHAR NOT NULL,
    chamber           VARCHAR,
    p0_bar_abs        DOUBLE,
    amplitude_mm      DOUBLE,
    frequency_hz      DOUBLE,
    nrmse_pct         DOUBLE
);

CREATE TABLE pressure_dynamics (
    chamber           VARCHAR,
    direction         VARCHAR,             -- charge / discharge
    wn_rad_s          DOUBLE,
    zeta              DOUBLE,
    nrmse_pct         DOUBLE,
    n_steps           BIGINT
);
