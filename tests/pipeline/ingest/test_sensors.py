"""Sensor resolution and noise (pipeline.ingest.sensors): rig.toml [sensors] and metadata, in SI."""
import pytest

from pipeline.ingest.result import IngestError
from pipeline.ingest.sensors import sensor_value_si

from tests.conftest import STEP_META
from tests.pipeline.ingest.helpers import T, ingest, quarantine


# -- sensor characteristics -------------------------------------------------------------------
def test_sensor_metadata_from_rig_toml_and_metadata_in_si(raw, warehouse):
    raw.write("c/rig.toml", '[sensors.x]\nresolution = "5 um"\nnoise = 2e-6\n'
                            '[sensors.p_a]\nnoise = "300 Pa"\nresolution = "0.01 bar"\n'
                            '[sensors.q_leak]\nnoise = "1 g/s"\n')   # channel not in this run: not stored
    raw.csv("c/a.csv", {**STEP_META, "sensor_X_noise": "0.003 mm", "sensor_p_a_resolution": "1 kPa",
                        "sensor_p_b_noise": "0.003 bara"},
            {"t[s]": T, "x[mm]": T, "x_ref[mm]": T, "p_a[bar(a)]": T, "p_b[bar]": T})
    p = ingest(raw, "c/a.csv", warehouse).run["params"]
    assert p["sensor_x_resolution"] == 5e-06
    assert p["sensor_x_noise"] == pytest.approx(3e-6)             # metadata overrides rig.toml
    assert p["sensor_p_a_noise"] == 300.0
    assert p["sensor_p_a_resolution"] == 1000.0                    # a difference: no gauge offset
    assert p["sensor_p_b_noise"] == pytest.approx(300.0)           # bara: still a difference
    assert "sensor_X_noise" not in p and "sensor_q_leak_noise" not in p


@pytest.mark.parametrize("toml, reason", [
    ('[sensors.x]\nresolution = "5 bar"\n', "unit `bar` is not a length unit"),
    ('[sensors.x]\nresolution = "-5 um"\n', "must be zero or positive"),
    ('[sensors.x]\nnoise = "inf"\n', "not a number with a unit"),
    ('[sensors.x]\nnoise = nan\n', "must be zero or positive and finite"),
    ('[sensors.x]\nnoise = "a lot"\n', "not a number with a unit"),
    ('[sensors.x]\nresolutoin = "5 um"\n', "unknown key(s) resolutoin"),
    ('[sensors]\nx = "5 um"\n', "must be a table"),
])
def test_q_bad_sensor_values(raw, warehouse, toml, reason):
    raw.write("c/rig.toml", toml)
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[mm]": T, "x_ref[mm]": T})
    err = quarantine(raw, warehouse)
    assert "[sensors" in err and reason in err


def test_zero_resolution_states_an_analog_sensor(raw, warehouse):
    raw.write("c/rig.toml", '[sensors.x]\nresolution = 0\nnoise = "20 um"\n')
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[mm]": T, "x_ref[mm]": T})
    res = ingest(raw, "c/a.csv", warehouse)
    assert res.error is None
    assert (res.run["params"]["sensor_x_resolution"], res.run["params"]["sensor_x_noise"]) == (0.0, 2e-05)


def test_q_bad_sensor_metadata(raw, warehouse):
    raw.csv("c/a.csv", {**STEP_META, "sensor_x_resolution": "5 N"}, {"t[s]": T, "x[mm]": T, "x_ref[mm]": T})
    assert "metadata `sensor_x_resolution`: unit `N` is not a length unit" in quarantine(raw, warehouse)


@pytest.mark.parametrize("where,stated,reason", [
    ("meta", {"sensor_x_resolution": "5"}, "metadata `sensor_x_resolution`: resolution 5 m is outside its plausible "
                                           "range 0 to 0.1 m ("),          # um meant, a bare number is metres
    ("rig", '[sensors.p_a]\nnoise = "300 bar"\n', "rig.toml [sensors.p_a]: noise 3e+07 Pa is outside its plausible "
                                                  "range 0 to 100000 Pa ("),
])
def test_q_sensor_values_outside_their_plausible_range(raw, warehouse, where, stated, reason):
    meta = dict(STEP_META)
    if where == "rig":
        raw.write("c/rig.toml", stated)
    else:
        meta.update(stated)
    raw.csv("c/a.csv", meta, {"t[s]": T, "x[mm]": T, "x_ref[mm]": T, "p_a[bar]": T})
    assert quarantine(raw, warehouse).startswith(reason)


def test_sensor_value_si_is_exact_for_sub_units_and_refuses_another_dimension():
    assert sensor_value_si("5 um", "x", "resolution", "here") == 5e-6
    assert sensor_value_si(0, "x", "noise", "here") == 0.0
    with pytest.raises(IngestError, match="^here: unit `bar` is not a length unit"):
        sensor_value_si("1 bar", "x", "noise", "here")
