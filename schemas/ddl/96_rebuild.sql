-- The rebuild itself: what the warehouse was built from and what changed in the last rebuild
-- (pipeline/rebuild/flow.py, pipeline/rebuild/state.py). Built inside the same database file, so it is
-- swapped in atomically with the data it describes.

-- One row per rebuild (this one last; earlier rows carried over from the previous warehouse).
CREATE TABLE rebuild_log (
    generation      VARCHAR NOT NULL,     -- id of the rebuild (UTC time + pid)
    started_at      TIMESTAMPTZ,
    finished_at     TIMESTAMPTZ,
    duration_s      DOUBLE,
    mode            VARCHAR,              -- incremental / full / no-op (nothing changed: the previous database carried over)
    executor        VARCHAR,              -- local / dask
    n_files         BIGINT,               -- run files under raw/
    n_runs          BIGINT,
    n_new           BIGINT,
    n_changed       BIGINT,
    n_deleted       BIGINT,
    n_unchanged     BIGINT,
    n_quarantined   BIGINT,               -- rows of `quarantine`
    stages_run      VARCHAR[],            -- stages that ran
    stages_reused   VARCHAR[],            -- stages whose cached outputs were reused
    exit_code       INTEGER,
    inputs_key      VARCHAR,              -- fingerprint of every input's stat, the tree and the code; a rebuild finding the same key takes the no-op path
    seq             BIGINT                -- number of the rebuild, 1, 2, ...: one more than the previous row's; generations are ordered by it, never by wall time (a clock set back)
);

-- One row per input of the last rebuild (run files, manifests, rig.toml, hose logbooks, plan.toml),
-- including the inputs that were deleted since the previous rebuild.
CREATE TABLE rebuild_inputs (
    source_path     VARCHAR NOT NULL,     -- relative to raw/
    role            VARCHAR,              -- run / manifest / rig / logbook / plan (plan.toml)
    status          VARCHAR NOT NULL,     -- new / changed / deleted / unchanged
    reason          VARCHAR,              -- changed because of: content / metadata / code / full
    quarantined     BOOLEAN,
    error           VARCHAR,              -- quarantine reason(s), one line
    run_id          VARCHAR,
    kind            VARCHAR
);

-- What changed in the last rebuild: new, changed, deleted and quarantined inputs.
CREATE VIEW rebuild_changes AS
    SELECT * FROM rebuild_inputs WHERE status <> 'unchanged' OR quarantined ORDER BY status, source_path;

-- Incremental state: one record per raw input (pipeline/rebuild/state.py).
CREATE TABLE ingest_state (
    source_path     VARCHAR NOT NULL,
    role            VARCHAR,              -- run / manifest / rig / logbook / plan (plan.toml)
    size_bytes      BIGINT,
    mtime_ns        BIGINT,               -- -1: modified during the rebuild, hash it next time
    inode           BIGINT,
    source_sha256   VARCHAR,
    meta_hash       VARCHAR,              -- rig.toml + manifest metadata that applies
    code_version    VARCHAR,              -- ingest code + schema version
    result          JSON,                 -- runs row and channels of an ingested run
    error           VARCHAR,              -- quarantine reason of a run file
    samples_paths   VARCHAR[]             -- samples files of the runs in `result` (read without decoding it)
);

-- Incremental state: the cached outputs of every analysis stage (stages/<name>/<key>/).
CREATE TABLE stage_cache (
    stage           VARCHAR NOT NULL,
    input_key       VARCHAR NOT NULL,
    folder          VARCHAR NOT NULL,     -- relative to the warehouse
    kinds_read      VARCHAR[],            -- the kinds of runs the stage declares it reads (READS.kinds)
    all_runs_read   BOOLEAN,              -- always false since stages declare their reads (kept for old warehouses)
    results_read    JSON                  -- earlier tables the stage declares it reads (READS.tables) -> content hash
);

-- The figures of the current warehouse: one row per figure an analysis stage drew.
CREATE TABLE figures (
    stage           VARCHAR,              -- analysis stage that drew it
    name            VARCHAR,              -- figure name within the stage
    path            VARCHAR,              -- PNG file, relative to the warehouse (stages/<stage>/<key>/figures/)
    caption         VARCHAR               -- what the figure shows, as the report captions it
);

-- The content key of every table the last rebuild wrote (pipeline/rebuild/assemble.py): the next
-- rebuild copies this database and writes again only the tables whose key changed.
CREATE TABLE table_keys (
    table_name      VARCHAR NOT NULL,     -- table written by the rebuild; '*' is the row of the build's version
    content_key     VARCHAR NOT NULL      -- hash of the frame written (rows, columns, types), then ':' and the table's row count and sum of row hashes as stored ('*': version of the DDL, the assembly code and DuckDB)
);
