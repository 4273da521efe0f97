"""Ambient / supply logger (kind timeseries): non-canonical channels exported as recorded."""
import numpy as np
import pytest

from pipeline.simulator import simulate_timeseries
from pipeline.simulator.writers import default_columns


def test_logger_truth_describes_its_samples():
    run = simulate_timeseries(4, duration_s=600.0, fs_hz=2.0)
    d = run.data
    assert list(d.columns) == ["t_s", "p_supply_pa", "temperature_degc", "rel_humidity_pct"]
    assert len(d) == run.truth["n_samples"] == 1200
    for col, stats in run.truth["channels"].items():
        assert stats["mean"] == pytest.approx(d[col].mean()) and stats["max"] == d[col].max()
    assert d.temperature_degc.mean() == pytest.approx(21.5 + 0.8 * 300 / 3600, abs=0.01)   # linear drift
    assert 6.0e5 - 2e3 < d.p_supply_pa.min() and d.p_supply_pa.max() < 6.6e5 + 2e3
    recharges = np.flatnonzero(np.diff(d.p_supply_pa.to_numpy()) > 0.4e5)   # every 240 s in 600 s
    assert len(recharges) in (2, 3) and np.diff(d.t_s.to_numpy()[recharges]) == pytest.approx(240.0)
    assert run.metadata["kind"] == "timeseries"
    assert list(simulate_timeseries(4, duration_s=10.0, supply=False).data.columns) == \
        ["t_s", "temperature_degc", "rel_humidity_pct"]


def test_non_canonical_columns_need_a_unit_and_keep_their_name():
    cols = default_columns(["p_supply_pa", "temperature"], {"p_supply": "bar", "temperature": "degC"},
                           {"temperature": "Temperature"})
    assert [(c.name, c.unit) for c in cols] == [("p_supply", "bar"), ("Temperature", "degC")]
    with pytest.raises(ValueError, match="temperature"):
        default_columns(["temperature"])
