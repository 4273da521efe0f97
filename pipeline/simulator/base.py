"""Shared pieces of the bench simulator: the :class:`SimRun` container, sensor models, constants.

Every generator returns a :class:`SimRun` whose ``data`` uses the warehouse column names in SI
(pressures gauge [Pa], flows [kg/s]), i.e. exactly what ingest must produce from the files the
writers make of it. Sensor values are quantised to a resolution in SI (pressure 1 Pa, encoder
5 um, force 1 mN, ...), so the exported text stays short and the round trip is exact to float
precision.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from schemas.units import L_MIN_M3_S, P_ATM_DEFAULT_PA, RHO_ANR_KG_M3

#: PLPA hose cross-section (25 mm bore). [m2]
HOSE_AREA_M2 = 4.9e-4
#: PLPA moving mass. [kg]
MOVING_MASS_KG = 2.0
#: Encoder resolution (paper). [m]
ENCODER_M = 5e-6
#: Pressure sensor noise, one sigma. [Pa]
PRESSURE_NOISE_PA = 300.0
#: Resolution pressures are logged with. [Pa]
PRESSURE_RES_PA = 1.0
#: Ambient pressure. [Pa]
P_ATM_PA = P_ATM_DEFAULT_PA
#: Fixed origin of simulated ``started_at`` dates (no clock time: output is deterministic).
EPOCH = "2025-03-03T08:00:00"


@dataclass
class SimRun:
    """One simulated run.

    Attributes
    ----------
    data : pandas.DataFrame
        Samples, columns named as in the warehouse (``t_s``, ``p_a_pa``, ``x_m`` ...), SI,
        gauge pressures, mass flows. Exactly what ingest should produce.
    metadata : dict
        Run metadata keyed as bench-exports.md names them (``kind``, ``chamber`` ...).
    truth : dict
        Every true value used to make the run (JSON-serialisable).
    """

    data: pd.DataFrame
    metadata: dict
    truth: dict = field(default_factory=dict)

    @property
    def kind(self) -> str:
        return self.metadata["kind"]


def make_rng(rng=None) -> np.random.Generator:
    """A numpy Generator from a Generator, a seed, or None (seed 0: deterministic default)."""
    if isinstance(rng, np.random.Generator):
        return rng
    return np.random.default_rng(0 if rng is None else rng)


def quantise(values, step: float) -> np.ndarray:
    """Round to a multiple of ``step``, returned as ``k / (1/step)`` so decimal text is short.

    Dividing an integer by a power of ten is correctly rounded, so e.g. ``35 / 1e6`` prints as
    ``3.5e-05``; ``35 * 5e-6`` would not always.
    """
    values = np.asarray(values, dtype=float)
    inv = 1.0 / step
    if abs(inv - round(inv)) < 1e-9 * inv:
        counts = np.round(values * round(inv))
        return counts / round(inv) + 0.0
    counts = np.round(values / step)
    return counts * step + 0.0


def encoder(x_m, rng=None) -> np.ndarray:
    """Encoder reading: position quantised to 5 um. [m]"""
    counts = np.round(np.asarray(x_m, dtype=float) / ENCODER_M)
    return counts * 5.0 / 1e6 + 0.0


def pressure_sensor(p_pa, rng: np.random.Generator, sigma_pa: float = PRESSURE_NOISE_PA) -> np.ndarray:
    """Pressure transducer: Gaussian noise, logged with 1 Pa resolution. [Pa gauge]"""
    p = np.asarray(p_pa, dtype=float)
    return quantise(p + rng.normal(0.0, sigma_pa, p.shape), PRESSURE_RES_PA)


def first_order_steps(t, times, levels, initial: float, tau_s: float) -> np.ndarray:
    """Response of a first-order lag to set-point steps ``levels[i]`` at ``times[i]``.

    Exact for piecewise-constant set-points: within each segment the output relaxes
    exponentially from its value at the segment start toward the new level.
    """
    t = np.asarray(t, dtype=float)
    out = np.empty_like(t)
    value = float(initial)
    bounds = list(times) + [np.inf]
    if t.size and t[0] < bounds[0]:
        mask = t < bounds[0]
        out[mask] = value
    for i, level in enumerate(levels):
        t0, t1 = bounds[i], bounds[i + 1]
        mask = (t >= t0) & (t < t1)
        out[mask] = level + (value - level) * np.exp(-(t[mask] - t0) / tau_s)
        if np.isfinite(t1):
            value = level + (value - level) * np.exp(-(t1 - t0) / tau_s)
    return out


def time_vector(n: int, fs_hz: float, t0: float = 0.0) -> np.ndarray:
    """Sample times ``t0 + k / fs`` (as a DAQ with waveform timing gives them). [s]"""
    return t0 + np.arange(n, dtype=float) * (1.0 / fs_hz)


def l_min_anr_to_kg_s(q_l_min):
    """Standard litres per minute (ANR, ISO 8778) to mass flow. [kg/s]"""
    return np.asarray(q_l_min, dtype=float) * (L_MIN_M3_S * RHO_ANR_KG_M3)


def jsonable(value):
    """Numpy scalars/arrays to plain Python, recursively (for truth.json)."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value
