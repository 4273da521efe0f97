-- Core tables of the warehouse contract (docs/warehouse.md).
-- Column names end in their unit; a value without a unit has no suffix.

CREATE TABLE runs (
    run_id          VARCHAR PRIMARY KEY,   -- unique in the warehouse
    kind            VARCHAR NOT NULL,      -- test kind (bench-exports.md)
    campaign        VARCHAR NOT NULL,      -- first folder under raw/
    rig             VARCHAR,
    started_at      TIMESTAMPTZ,           -- UTC when the export had no offset
    source_path     VARCHAR NOT NULL,      -- relative to raw/
    source_sha256   VARCHAR NOT NULL,
    n_samples       BIGINT NOT NULL,
    sample_rate_hz  DOUBLE,                -- median rate of the time channel
    params          JSON,                  -- every metadata key of the run, typed
    warnings        VARCHAR[],             -- one entry per warning, empty when none
    format          VARCHAR,               -- csv, lvm, tdms, mat, excel, mdf
    duration_s      DOUBLE,                -- last minus first sample time
    samples_path    VARCHAR                -- the run's samples Parquet file
);

CREATE TABLE quarantine (
    source_path     VARCHAR NOT NULL,      -- relative to raw/
    error           VARCHAR NOT NULL,      -- one line: what is wrong and where
    line            BIGINT,                -- line of the file, where one is to blame
    campaign        VARCHAR,
    stage           VARCHAR                -- ingest, logbook, or the analysis that refused it
);

-- Files under raw/ that are neither a supported export nor a known side file (manifest.csv,
-- hoses.csv, rig.toml, *.tdms_index, dotfiles, README*): not runs, not errors, but said.
CREATE TABLE skipped_files (
    source_path     VARCHAR NOT NULL,      -- relative to raw/
    campaign        VARCHAR,
    reason          VARCHAR NOT NULL       -- e.g. "not a supported format: .docx"
);

-- One row per channel of every run: how the raw export named it and in which unit it came.
CREATE TABLE channels (
    run_id          VARCHAR NOT NULL,
    "column"        VARCHAR NOT NULL,      -- column in samples_<kind>
    channel         VARCHAR,               -- canonical channel, NULL when not canonical
    raw_name        VARCHAR,
    raw_unit        VARCHAR,
    unit            VARCHAR,               -- unit of the stored values
    type            VARCHAR                -- DOUBLE, or VARCHAR for a text channel, in this run's samples file
                                           -- (samples_<kind> has a channel that is text in any of its runs as VARCHAR)
);
