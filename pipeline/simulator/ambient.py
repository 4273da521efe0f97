"""Ambient / supply logger: a ``timeseries`` export (catalogued and queryable, no analysis).

A small logger beside the benches records the room temperature [degC] and relative humidity
[%] and, on one of its inputs, the supply line pressure behind the service unit. Temperature
and humidity are not canonical channels: ingest keeps them under their names with their units
recorded, values unconverted (bench-exports.md, "Channels and units").
"""
from __future__ import annotations

import numpy as np
import pandas as pd

from pipeline.simulator.base import SimRun, make_rng, quantise, time_vector

#: Supply line: the compressor recharges the receiver from ``SUPPLY_LOW_BAR`` to
#: ``SUPPLY_HIGH_BAR`` (gauge) and the line then falls linearly until the next cycle.
SUPPLY_HIGH_BAR = 6.6
SUPPLY_LOW_BAR = 6.0
SUPPLY_PERIOD_S = 240.0
SUPPLY_NOISE_PA = 300.0
#: Logger resolutions: 0.01 degC, 0.1 % RH, 100 Pa.
TEMPERATURE_RES_C = 0.01
HUMIDITY_RES_PCT = 0.1
PRESSURE_RES_PA = 100.0


def simulate_timeseries(rng=None, *, duration_s: float = 600.0, fs_hz: float = 1.0, supply: bool = True,
                        temperature_c: float = 21.5, drift_c_h: float = 0.8, humidity_pct: float = 45.0,
                        **metadata) -> SimRun:
    """An ambient logger run: ``temperature`` [degC], ``rel_humidity`` [%], optionally ``p_supply``.

    The non-canonical channels are named as ingest stores them (docs/inputs.md: the column ends
    in its unit): ``temperature_degc``, ``rel_humidity_pct``; exported as ``temperature[degC]``
    and ``rel_humidity[%]``.

    Parameters
    ----------
    rng : numpy.random.Generator or int, optional
    duration_s : float
        Length of the log. [s]
    fs_hz : float
        Logging rate. [Hz]
    supply : bool
        Whether the supply line pressure (canonical ``p_supply``) is logged.
    temperature_c : float
        Room temperature at the start. [degC]
    drift_c_h : float
        Linear warming of the room. [degC/h]
    humidity_pct : float
        Mean relative humidity. [%]

    Returns
    -------
    SimRun
        ``data`` columns ``t_s``, (``p_supply_pa``,) ``temperature_degc``, ``rel_humidity_pct`` (the
        non-canonical columns as ingest names them, in their raw units); truth holds the
        parameters and the mean / min / max of every logged channel.
    """
    rng = make_rng(rng)
    n = int(round(duration_s * fs_hz))
    t = time_vector(n, fs_hz)
    temp = quantise(temperature_c + drift_c_h * t / 3600.0 + rng.normal(0.0, 0.03, n), TEMPERATURE_RES_C)
    hum = quantise(humidity_pct - 2.0 * np.sin(2 * np.pi * t / max(duration_s, 1.0)) + rng.normal(0.0, 0.3, n),
                   HUMIDITY_RES_PCT)
    data = {"t_s": t}
    truth = {"kind": "timeseries", "fs_hz": fs_hz, "duration_s": duration_s, "n_samples": n,
             "temperature_c": temperature_c, "drift_c_h": drift_c_h, "humidity_pct": humidity_pct,
             "units": {"temperature_degc": "degC", "rel_humidity_pct": "%"}}
    if supply:
        phase = rng.uniform(0.0, SUPPLY_PERIOD_S)
        frac = ((t + phase) % SUPPLY_PERIOD_S) / SUPPLY_PERIOD_S
        p_bar = SUPPLY_HIGH_BAR - (SUPPLY_HIGH_BAR - SUPPLY_LOW_BAR) * frac
        data["p_supply_pa"] = quantise(p_bar * 1e5 + rng.normal(0.0, SUPPLY_NOISE_PA, n), PRESSURE_RES_PA)
        truth.update(supply_high_bar=SUPPLY_HIGH_BAR, supply_low_bar=SUPPLY_LOW_BAR,
                     supply_period_s=SUPPLY_PERIOD_S, supply_phase_s=phase, supply_noise_pa=SUPPLY_NOISE_PA)
    data["temperature_degc"] = temp
    data["rel_humidity_pct"] = hum
    frame = pd.DataFrame(data)
    truth["channels"] = {c: {"mean": float(frame[c].mean()), "min": float(frame[c].min()),
                             "max": float(frame[c].max())} for c in frame.columns if c != "t_s"}
    meta = {"kind": "timeseries", "rig": "lab-logger", "logger": "ambient", **metadata}
    return SimRun(frame, meta, truth)
