-- PLPA characterisation: leakage maps, static breakaway, viscous friction (seed 000, section 3).

CREATE TABLE leakage_map (
    run_id          VARCHAR NOT NULL,
    hose_id         VARCHAR,
    chamber         VARCHAR,              -- A / B
    adjustment      VARCHAR,              -- distance / force
    z_rollers_mm    DOUBLE,
    spring_force_n  DOUBLE,
    pressure_bar    DOUBLE,               -- plateau mean, gauge
    leak_l_min      DOUBLE                -- plateau mean, l/min ANR
);

CREATE TABLE breakaway (
    run_id            VARCHAR NOT NULL,
    direction         VARCHAR,            -- P / N
    backpressure_bar  DOUBLE,
    force_rate_n_s    DOUBLE,
    breakaway_force_n DOUBLE              -- NULL when the carriage never moved
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
    friction_n        DOUBLE              -- signed
);

CREATE TABLE viscous_fits (
    backpressure_bar  DOUBLE,
    direction         VARCHAR,            -- P / N
    coulomb_n         DOUBLE,
    viscous_n_s_m     DOUBLE,
    nrmse_pct         DOUBLE,
    n_points          BIGINT
);
