-- Durability and hose service life.

CREATE TABLE durability_runs (
    run_id            VARCHAR NOT NULL,
    hose_id           VARCHAR,
    distance_km       DOUBLE,
    strokes           BIGINT,
    duration_h        DOUBLE
);

CREATE TABLE hose_life (
    hose_id           VARCHAR NOT NULL,
    hose_type         VARCHAR,
    adjustment        VARCHAR,
    distance_km       DOUBLE,
    strokes           BIGINT,
    status            VARCHAR,             -- failed / removed / running
    failure_mode      VARCHAR,
    n_runs            BIGINT
);

CREATE TABLE service_life (
    hose_type         VARCHAR,
    adjustment        VARCHAR,
    n_hoses           BIGINT,
    n_failed          BIGINT,
    weibull_shape     DOUBLE,              -- NULL with fewer than two failures
    weibull_scale_km  DOUBLE,
    b10_km            DOUBLE,
    b10_lower_km      DOUBLE,
    b10_upper_km      DOUBLE,
    confidence        DOUBLE
);
