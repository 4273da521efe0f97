"""What refuses a run (pipeline.ingest.checks): channels and metadata its kind needs, chamber, plausible ranges."""
import json

import numpy as np
import pyarrow.parquet as pq
import pytest

from pipeline.ingest.checks import check_channels, check_metadata
from pipeline.ingest.result import IngestError
from pipeline.ingest.timebase import TimeBase

from tests.conftest import STEP_META
from tests.pipeline.ingest.helpers import BREAKAWAY, T, VISCOUS, ingest, quarantine


def test_q_missing_channel(raw, warehouse):
    raw.csv("c/a.csv", {**STEP_META, "kind": "breakaway", "direction": "P", "backpressure_bar": 0,
                        "force_rate_n_s": 1, "hose_area_m2": 4.9e-4}, {"t[s]": T, "p_a[bar]": T, "p_b[bar]": T})
    assert "missing channel `x`" in quarantine(raw, warehouse)


def test_q_missing_required_metadata(raw, warehouse):
    raw.csv("c/a.csv", {"kind": "durability", "rig": "r"}, {"t[s]": T, "x[m]": T, "p_a[bar]": T, "p_b[bar]": T})
    err = quarantine(raw, warehouse)
    assert "missing metadata `started_at`, `hose_id`" in err


def test_q_wrong_chamber_for_rig(raw, warehouse):
    # the spring model needs to know which side of the piston (its pressure and force signs)
    raw.csv("c/a.csv", {**STEP_META, "kind": "spring", "chamber": "A", "amplitude_mm": 5, "frequency_hz": 1},
            {"t[s]": T, "d[mm]": T, "f[N]": T, "p[bar]": T})
    assert "`chamber` must be one of front, rear" in quarantine(raw, warehouse)


@pytest.mark.parametrize("chamber,stored", [("patient", "patient"), ("Tube 2", "Tube 2"), ("REAR", "rear"),
                                            ("a", "A")])
def test_a_pressure_step_chamber_is_any_name_and_known_names_keep_their_spelling(raw, warehouse, chamber, stored):
    """Another rig's chamber names (a ventilator's `patient` line) are kept as written; the
    project's own names are stored in their spelling, whatever the case (issue 25 item 3)."""
    raw.csv("c/a.csv", {**STEP_META, "kind": "pressure_step", "chamber": chamber, "valve_id": "RPV-2",
                        "age_h": "594"}, {"t[s]": T, "p[bar]": T, "p_ref[bar]": T})
    res = ingest(raw, "c/a.csv", warehouse)
    assert res.error is None, res.error
    params = res.run["params"] if isinstance(res.run["params"], dict) else json.loads(res.run["params"])
    assert params["chamber"] == stored and params["valve_id"] == "RPV-2" and params["age_h"] == 594.0


def test_q_no_time_and_no_stated_rate_says_how_to_fix(raw, warehouse):
    raw.csv("c/a.csv", STEP_META, {"x[m]": T, "x_ref[m]": T})
    err = quarantine(raw, warehouse)
    assert "missing channel `t`" in err and "sample_rate_hz" in err


def test_q_lookalike_needed_by_the_kind_says_how_to_map_it(raw, warehouse):
    raw.csv("c/a.csv", {**STEP_META, "kind": "spring", "chamber": "front", "amplitude_mm": 5, "frequency_hz": 1},
            {"t[s]": T, "d[mm]": T, "F[g]": T, "p[bar]": T})
    err = quarantine(raw, warehouse)
    assert "missing channel `f`" in err
    assert '[channels."F"] channel = "f" unit = "N"' in err


def test_q_missing_channel_names_the_derived_channel_that_could_not_be_computed(raw, warehouse):
    raw.write("c/rig.toml", '[metadata]\nhose_area_m2 = 4.9e-4\n[derived]\nf = "f_cell - p_b * hose_area_m2"\n')
    raw.csv("c/a.csv", VISCOUS, {"t[s]": T, "x[mm]": T, "load[N]": T})
    err = quarantine(raw, warehouse)
    assert "missing channel" in err
    assert "derived channel `f` not computed: no channel or numeric metadata `f_cell`, `p_b`" in err


# -- plausibility of stated values (schemas.kinds.PLAUSIBLE) ---------------------------------------
def test_q_ambient_pressure_in_hpa_written_as_pa_is_refused_not_shifted(raw, warehouse):
    """Issue 21 item 15: `p_atm_pa = 1013.25` (hPa written as Pa) with `bara` channels moved every
    pressure by about 1 bar without a word. A lab at 500 m (95 kPa) stays read right."""
    cols = {"t[s]": T, "x[mm]": T, "x_ref[mm]": T, "p_a[bara]": [1.0, 2.0, 3.0, 4.0]}
    raw.csv("c/a.csv", {**STEP_META, "p_atm_pa": "1013.25"}, cols)
    assert quarantine(raw, warehouse) == (
        "metadata `p_atm_pa` = 1013.25 Pa is outside its plausible range 50000 to 110000 Pa (ambient air "
        "pressure from 5,400 m altitude (Everest base camp, about 53 kPa) to below sea level (Dead Sea shore "
        "about 107 kPa, record high 108.4 kPa); hPa written as Pa is 100 times too small)")
    raw.csv("c/b.csv", {**STEP_META, "p_atm_pa": "95000"}, cols)
    res = ingest(raw, "c/b.csv", warehouse)
    assert res.error is None
    assert pq.read_table(warehouse / res.run["samples_path"]).column("p_a_pa").to_pylist() == [
        5000.0, 105000.0, 205000.0, 305000.0]


@pytest.mark.parametrize("key,value,shown,range_text", [
    ("hose_area_m2", "490", "490 m2", "1e-07 to 1 m2"),               # mm2 written as m2
    ("hose_area_m2", "-4.9e-4", "-0.00049 m2", "1e-07 to 1 m2"),
    ("backpressure_bar", "200000", "200000 bar", "-1.1 to 100 bar"),   # Pa written as bar
    ("backpressure_bar", "-3", "-3 bar", "-1.1 to 100 bar"),           # below a vacuum
    ("force_rate_n_s", "0", "0 N/s", "0.001 to 1e+06 N/s"),
    ("temperature_c", "293.15", "293.15 degC", "-100 to 250 degC"),    # kelvin written as degC
    ("p0_bar_abs", "-0.5", "-0.5 bar", "0 to 101 bar"),
    ("sample_rate_hz", "5e12", "5e+12 Hz", "0.0001 to 1e+09 Hz"),
    ("amplitude_mm", "0", "0 mm", "0.0001 to 10000 mm"),
])
def test_q_metadata_outside_its_plausible_range(raw, warehouse, key, value, shown, range_text):
    raw.csv("c/a.csv", {**BREAKAWAY, key: value}, {"t[s]": T, "p_a[bar]": T, "p_b[bar]": T, "x[m]": T})
    err = quarantine(raw, warehouse)
    assert err.startswith(f"metadata `{key}` = {shown} is outside its plausible range {range_text} (")


def test_plausible_values_at_both_ends_of_a_range_are_kept(raw, warehouse):
    meta = {**BREAKAWAY, "p_atm_pa": 53000, "backpressure_bar": -1.0, "hose_area_m2": 7.9e-7,
            "temperature_c": -40, "force_rate_n_s": 5000}
    raw.csv("c/a.csv", meta, {"t[s]": T, "p_a[bar]": T, "p_b[bar]": T, "x[m]": T})
    res = ingest(raw, "c/a.csv", warehouse)
    assert res.error is None
    assert res.run["params"]["p_atm_pa"] == 53000.0 and res.run["params"]["hose_area_m2"] == 7.9e-7


def test_q_mat_scalar_rate_outside_the_sample_rate_range(raw, warehouse):
    from tests.pipeline.readers.generators import mat_v5

    (raw.root / "c").mkdir(parents=True)
    mat_v5(raw.root / "c/a.mat", {"x": np.array([1.0, 2.0, 3.0]), "x_ref": np.array([0.0, 0.0, 0.0]),
                                  "dt": 1e-12, "units": {"x": "mm", "x_ref": "mm"},    # ps: a unit slip
                                  "meta": {"kind": "step", "rig": "r", "started_at": "2026-01-01"}})
    assert quarantine(raw, warehouse, "c/a.mat").startswith(
        "MAT scalar `dt` = 1e-12 s is outside its plausible range 1e-09 to 10000 s (")


def test_check_channels_hints_at_a_lookalike_and_a_derived_channel_not_computed():
    looks = {"c2": ("F", "f", "g")}
    with pytest.raises(IngestError) as err:
        check_channels("viscous", {"t", "x"}, looks, ["derived channel `f` not computed: no channel `p_b`"])
    assert str(err.value).startswith("missing channel `f` (kind viscous needs ")
    assert "; column `F` is in `g`, not a force" in str(err.value)
    assert str(err.value).endswith("; derived channel `f` not computed: no channel `p_b`")
    check_channels("step", {"t", "x", "x_ref"}, {}, [])


def test_check_metadata_holds_a_mat_scalar_rate_to_the_sample_rate_range():
    meta = {"kind": "timeseries", "run_id": "c/a", "started_at": "2026-01-01T00:00:00+00:00", "rig": "r"}
    check_metadata("timeseries", meta, {"t"}, TimeBase(1000.0, None, 0.0, "Fs"))
    with pytest.raises(IngestError, match="^MAT scalar `dt` = "):
        check_metadata("timeseries", meta, {"t"}, TimeBase(None, 1e-12, 0.0, "dt"))
