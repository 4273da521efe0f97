"""Time base (pipeline.ingest.timebase): the time column checked, or time from a stated rate."""
import numpy as np
import pytest

from pipeline.ingest.result import IngestError
from pipeline.ingest.timebase import TimeBase, TimeCheck

from tests.conftest import STEP_META
from tests.pipeline.ingest.helpers import T, ingest, quarantine, samples_of


def test_q_time_goes_backwards(raw, warehouse):
    raw.csv("c/a.csv", STEP_META, {"t[s]": [0, 1, 2, 1.5, 3], "x[m]": [0] * 5, "x_ref[m]": [0] * 5})
    assert "time goes backwards at row 4" in quarantine(raw, warehouse)


def test_q_time_missing(raw, warehouse):
    raw.csv("c/a.csv", STEP_META, {"t[s]": ["0", "1", "", "3"], "x[m]": T, "x_ref[m]": T})
    assert "time is missing at row 3" in quarantine(raw, warehouse)


def test_csv_without_time_column_takes_sample_rate_from_the_manifest(raw, warehouse):
    raw.csv("c/a.csv", {"kind": "timeseries", "started_at": "2026-01-01", "rig": "r"},
            {"temperature[degC]": [20.0, 20.5, 21.0, 21.5]})
    raw.write("c/manifest.csv", "file,sample_rate_hz,t0_s\na.csv,0.25,8\n")   # one sample every 4 s
    res = ingest(raw, "c/a.csv", warehouse)
    table = samples_of(res, warehouse)
    assert table.column("t_s").to_pylist() == [8.0, 12.0, 16.0, 20.0]
    assert res.run["sample_rate_hz"] == pytest.approx(0.25)
    assert any("time from `sample_rate_hz`" in w for w in res.run["warnings"])
    assert {"column": "t_s", "channel": "t"}.items() <= next(c for c in res.channels if c["column"] == "t_s").items()


def test_headerless_text_takes_dt_s_from_rig_toml(raw, warehouse):
    raw.write("c/rig.toml", '[read]\ndelimiter = "whitespace"\nheader = false\n'
                            '[channels."1"]\nchannel = "x"\nunit = "mm"\n[channels."2"]\nchannel = "x_ref"\nunit = "mm"\n'
                            '[metadata]\nkind = "step"\nrig = "r"\nstarted_at = "2026-01-01"\ndt_s = 0.002\n')
    raw.write("c/a.txt", "1.0 2.0\n1.5 2.0\n2.0 2.0\n")
    table = samples_of(ingest(raw, "c/a.txt", warehouse), warehouse)
    assert table.column("t_s").to_pylist() == [0.0, 0.002, 0.004]
    assert table.column("x_m").to_pylist() == [1e-3, 1.5e-3, 2e-3]


@pytest.mark.parametrize("scalar, value, expected", [("Fs", 50.0, [0.0, 0.02, 0.04]), ("fs", 4.0, [0.0, 0.25, 0.5]),
                                                      ("dt", 0.5, [0.0, 0.5, 1.0])])
def test_mat_scalar_sample_rate_gives_time(raw, warehouse, scalar, value, expected):
    from tests.pipeline.readers.generators import mat_v5

    (raw.root / "c").mkdir(parents=True)
    mat_v5(raw.root / "c/a.mat", {"x": np.array([1.0, 2.0, 3.0]), "x_ref": np.array([0.0, 0.0, 0.0]),
                                  scalar: value, "units": {"x": "mm", "x_ref": "mm"},
                                  "meta": {"kind": "step", "rig": "r", "started_at": "2026-01-01"}})
    table = samples_of(ingest(raw, "c/a.mat", warehouse), warehouse)
    assert table.column("t_s").to_pylist() == pytest.approx(expected, abs=0)


def test_tdms_without_time_or_waveform_takes_sample_rate_from_metadata(raw, warehouse):
    from tests.pipeline.readers.test_tdms import write_tdms

    write_tdms(raw.root / "c/a.tdms", {"kind": "step", "rig": "r", "started_at": "2026-01-01", "sample_rate_hz": 100.0},
               {"Data": {"x": (np.array([1.0, 2.0, 3.0]), {"unit_string": "mm"}),
                         "x_ref": (np.zeros(3), {"unit_string": "mm"})}})
    table = samples_of(ingest(raw, "c/a.tdms", warehouse), warehouse)
    assert table.column("t_s").to_pylist() == [0.0, 0.01, 0.02]


def test_lvm_time_column_and_a_disagreeing_stated_rate_warn(raw, warehouse):
    from tests.pipeline.readers.generators import LvmSegment, lvm_bytes

    s = LvmSegment({"x": [0.0, 1.0, 2.0, 3.0], "x_ref": [0.0] * 4}, units={"x": "mm", "x_ref": "mm"}, dt=0.01)
    raw.write("c/a.lvm", lvm_bytes([s], x_columns="No", description="kind=step; rig=r; sample_rate_hz=1000"))
    raw.write("c/b.lvm", lvm_bytes([s], x_columns="No", description="kind=step; rig=r; sample_rate_hz=100"))
    a, b = ingest(raw, "c/a.lvm", warehouse), ingest(raw, "c/b.lvm", warehouse)
    assert samples_of(a, warehouse).column("t_s").to_pylist() == pytest.approx([0.0, 0.01, 0.02, 0.03])
    assert any("disagrees with `sample_rate_hz` 1000 Hz" in w for w in a.run["warnings"])
    assert not any("disagrees" in w for w in b.run["warnings"])


@pytest.mark.parametrize("value", ["0", "-5", "fast", "inf"])
def test_q_bad_stated_sample_rate(raw, warehouse, value):
    raw.csv("c/a.csv", {**STEP_META, "sample_rate_hz": value}, {"x[m]": T, "x_ref[m]": T})
    assert "`sample_rate_hz` must be a" in quarantine(raw, warehouse)


def test_time_base_gives_times_of_any_rows():
    assert TimeBase(4.0, None, 8.0, "sample_rate_hz").times(2, 3).tolist() == [8.5, 8.75, 9.0]
    assert TimeBase(None, 0.5, 0.0, "dt_s").times(0, 3).tolist() == [0.0, 0.5, 1.0]


def test_time_check_across_batches_counts_rows_repeats_rate_and_span():
    check = TimeCheck()
    check.update(np.array([0.0, 0.1, 0.2]))
    check.update(np.array([0.2, 0.3]))
    assert (check.n, check.repeats, check.first, check.last) == (5, 1, 0.0, 0.3)
    assert check.sample_rate_hz == pytest.approx(10.0)
    with pytest.raises(IngestError, match=r"^time goes backwards at row 6 \(0.3 s -> 0.25 s\)$"):
        check.update(np.array([0.25]))
