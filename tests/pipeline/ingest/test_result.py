"""Ingest results (pipeline.ingest.result): one-line quarantine reasons, the footer's record."""
import pyarrow as pa

from pipeline.ingest.result import IngestError, IngestResult, one_line, read_run_record
from pipeline.raw.metadata import MetadataError
from tests.conftest import STEP_META
from tests.pipeline.ingest.helpers import T, quarantine


def test_q_reader_crash_is_one_line_naming_the_error(raw, warehouse, monkeypatch):
    # a library raising something unexpected on a corrupt file (h5py raises RuntimeError)
    import pipeline.raw.metadata as ingest_mod

    def corrupt(*a, **k):
        raise RuntimeError("Link iteration failed (actual len exceeds EOA)\nsecond line")

    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    monkeypatch.setattr(ingest_mod, "read_export", corrupt)
    err = quarantine(raw, warehouse)
    assert err == "cannot read file: RuntimeError: Link iteration failed (actual len exceeds EOA) second line"


class _ArrowOSError(pa.ArrowException, OSError):
    """An OSError that pyarrow raised (about the file's bytes, so not transient)."""


def test_fail_keeps_a_quarantine_reason_and_names_any_other_error():
    res = IngestResult("c/a.csv")
    res.fail(MetadataError("missing metadata `kind`\n(one of ...)"), prefix="sheet 'S1': ")
    assert (res.error, res.transient) == ("sheet 'S1': missing metadata `kind` (one of ...)", False)
    res = IngestResult("c/a.csv")
    res.fail(PermissionError(13, "Permission denied"))
    assert (res.error, res.transient) == ("cannot read file: PermissionError: [Errno 13] Permission denied", True)
    res = IngestResult("c/a.csv")
    res.fail(_ArrowOSError("bad footer"), unexpected="cannot read")  # pyarrow's: the file, not the disk
    assert (res.error, res.transient) == ("cannot read: _ArrowOSError: bad footer", False)
    res.fail(IngestError("x" * 600))
    assert len(res.error) == 500 and one_line(" a \t b\n") == "a b"


def test_read_run_record_of_a_file_that_is_not_parquet_is_none(tmp_path):
    (tmp_path / "a.parquet").write_bytes(b"not parquet")
    assert read_run_record(tmp_path / "a.parquet") is None and read_run_record(tmp_path / "missing") is None
