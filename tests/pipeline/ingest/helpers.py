"""Helpers of the ingest tests: a run ingested, its quarantine reason, its samples, metadata of kinds."""
import pyarrow.parquet as pq

from pipeline.ingest.file import ingest_file
from pipeline.raw.tree import RawTree
from tests.conftest import STEP_META

#: A short time column [s].
T = [0.0, 0.1, 0.2, 0.3]

BREAKAWAY = {**STEP_META, "kind": "breakaway", "direction": "P", "backpressure_bar": 0, "force_rate_n_s": 1,
             "hose_area_m2": 4.9e-4}
VISCOUS = {"kind": "viscous", "started_at": "2026-01-01", "rig": "lc", "backpressure_bar": 1.0}


def ingest(raw, rel, warehouse):
    """``raw/<rel>`` ingested into ``warehouse`` (an IngestResult)."""
    return ingest_file(RawTree(raw.root), raw.root / rel, warehouse)


def quarantine(raw, warehouse, rel="c/a.csv"):
    """The one-line reason ``raw/<rel>`` is quarantined (the test fails when it is not)."""
    res = ingest(raw, rel, warehouse)
    assert res.run is None, "expected the file to be quarantined"
    assert "\n" not in res.error
    return res.error


def samples_of(res, warehouse):
    """The samples table of an ingested run (the test fails when it was quarantined)."""
    assert res.error is None, res.error
    return pq.read_table(warehouse / res.run["samples_path"])
