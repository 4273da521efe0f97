-- Files of earlier warehouses kept for readers that still have them open (pipeline/rebuild/flow.py).
-- A samples file or stage folder that the live warehouse no longer uses is kept for the
-- retention period (`pneubench rebuild --keep-superseded HOURS`, default 24) counted from the
-- rebuild that stopped using it, then collected.
CREATE TABLE superseded_files (
    path            VARCHAR NOT NULL,     -- relative to the warehouse: samples/... file or stages/<stage>/<key>
    superseded_at   TIMESTAMPTZ NOT NULL  -- start of the rebuild that stopped using it
);
