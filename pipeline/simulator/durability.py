"""Durability (hose service life) generators: back-and-forth strokes for hours, hose wear.

The carriage repeats single strokes (one-way moves of ``stroke_m``): dwell ``dwell_s`` at the
end, accelerate at ``accel_m_s2`` to ``speed_m_s``, cruise, decelerate to the other end. The
position is an analytic function of time, so a run of any length is generated in chunks
(:func:`iter_durability_chunks`) with bounded memory. Chamber pressures carry the drive force
``m a + F(v)`` around a mean pressure.

Hose wear: under distance-set rollers the seal pressure falls as the wall thins, so leakage grows
with distance; under force-set rollers it stays nearly flat (:func:`worn_seal_pressure_bar`).
"""
from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import pandas as pd

from pipeline.simulator.base import HOSE_AREA_M2, MOVING_MASS_KG, SimRun, encoder, make_rng, pressure_sensor
from pipeline.simulator.plpa import friction_force, seal_pressure_bar, viscous_parameters

#: Hose life distance, two-parameter Weibull per roller adjustment: (shape, scale [km]).
WEIBULL_LIFE = {"force": (2.4, 90.0), "distance": (1.8, 40.0)}
#: Seal-pressure loss per km of travel. [bar/km]
SEAL_WEAR_BAR_KM = {"distance": 0.06, "force": 0.004}
#: New hose wall thickness [mm] and its wear per km. [mm/km]
WALL_NEW_MM = 3.0
WALL_WEAR_MM_KM = {"distance": 0.012, "force": 0.006}


def worn_seal_pressure_bar(adjustment: str, distance_km: float, z_rollers_mm: float | None = None,
                           spring_force_n: float | None = None) -> float:
    """Seal pressure of a hose after ``distance_km`` of travel. [bar gauge]"""
    p0 = seal_pressure_bar(adjustment, z_rollers_mm, spring_force_n)
    return p0 - SEAL_WEAR_BAR_KM[adjustment] * distance_km


def wall_thickness_mm(adjustment: str, distance_km: float) -> float:
    """True wall thickness after ``distance_km`` of travel. [mm]"""
    return WALL_NEW_MM - WALL_WEAR_MM_KM[adjustment] * distance_km


def weibull_life_km(adjustment: str, rng: np.random.Generator) -> float:
    """One hose life drawn from the Weibull of its adjustment. [km]"""
    shape, scale = WEIBULL_LIFE[adjustment]
    return float(scale * rng.weibull(shape))


@dataclass(frozen=True)
class StrokePlan:
    """The stroke pattern of a durability run and its exact totals."""

    stroke_m: float
    speed_m_s: float
    accel_m_s2: float
    dwell_s: float
    strokes: int
    fs_hz: float
    x0_m: float = 0.1

    @property
    def accel_time_s(self) -> float:
        # triangular profile when the stroke is too short to reach speed
        return min(self.speed_m_s / self.accel_m_s2, math.sqrt(self.stroke_m / self.accel_m_s2))

    @property
    def peak_speed_m_s(self) -> float:
        return self.accel_m_s2 * self.accel_time_s

    @property
    def move_time_s(self) -> float:
        ta, v = self.accel_time_s, self.peak_speed_m_s
        cruise = (self.stroke_m - v * ta) / v
        return 2 * ta + cruise

    @property
    def period_s(self) -> float:
        return self.dwell_s + self.move_time_s

    @property
    def duration_s(self) -> float:
        return self.strokes * self.period_s + self.dwell_s

    @property
    def n_samples(self) -> int:
        return int(math.floor(self.duration_s * self.fs_hz)) + 1

    @property
    def distance_m(self) -> float:
        return self.strokes * self.stroke_m

    def state(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position [m], velocity [m/s], acceleration [m/s2] at times ``t``."""
        t = np.asarray(t, dtype=float)
        k = np.minimum(np.floor(t / self.period_s), self.strokes).astype(np.int64)
        tau = t - k * self.period_s - self.dwell_s  # time into the move (negative: dwelling)
        ta, vp, a, L = self.accel_time_s, self.peak_speed_m_s, self.accel_m_s2, self.stroke_m
        tm = self.move_time_s
        moving = (tau >= 0) & (k < self.strokes)
        tau = np.clip(tau, 0.0, tm)
        s = np.where(tau < ta, 0.5 * a * tau * tau,
                     np.where(tau < tm - ta, 0.5 * a * ta * ta + vp * (tau - ta),
                              L - 0.5 * a * (tm - tau) ** 2))
        sv = np.where(tau < ta, a * tau, np.where(tau < tm - ta, vp, a * (tm - tau)))
        sa = np.where(tau < ta, a, np.where(tau < tm - ta, 0.0, -a))
        s = np.where(moving, s, 0.0)
        sv = np.where(moving, sv, 0.0)
        sa = np.where(moving, sa, 0.0)
        forward = (k % 2) == 0
        start = np.where(forward, self.x0_m, self.x0_m + L)
        direction = np.where(forward, 1.0, -1.0)
        return start + direction * s, direction * sv, direction * sa


def stroke_plan(distance_m: float | None = None, duration_s: float | None = None, *, stroke_m: float = 0.5,
                speed_m_s: float = 0.5, accel_m_s2: float = 2.0, dwell_s: float = 0.2,
                fs_hz: float = 1000.0) -> StrokePlan:
    """The plan covering ``distance_m`` (rounded up to whole strokes) or fitting in ``duration_s``."""
    plan = StrokePlan(stroke_m, speed_m_s, accel_m_s2, dwell_s, 0, fs_hz)
    if distance_m is not None:
        strokes = int(math.ceil(distance_m / stroke_m - 1e-9))
    elif duration_s is not None:
        strokes = int(math.floor((duration_s - dwell_s) / plan.period_s))
    else:
        raise ValueError("give distance_m or duration_s")
    return StrokePlan(stroke_m, speed_m_s, accel_m_s2, dwell_s, max(strokes, 0), fs_hz)


def iter_durability_chunks(plan: StrokePlan, rng=None, *, p_mean_bar: float = 2.0, chunk_rows: int = 1_000_000,
                           fc_n: float | None = None, ka_n_s_m: float | None = None) -> Iterator[pd.DataFrame]:
    """Samples of a durability run, ``chunk_rows`` at a time (columns t_s, x_m, p_a_pa, p_b_pa)."""
    rng = make_rng(rng)
    fc0, ka0, vs = viscous_parameters(p_mean_bar)
    fc = fc0 if fc_n is None else fc_n
    ka = ka0 if ka_n_s_m is None else ka_n_s_m
    n = plan.n_samples
    for i0 in range(0, n, chunk_rows):
        m = min(chunk_rows, n - i0)
        t = (np.arange(i0, i0 + m, dtype=float)) * (1.0 / plan.fs_hz)
        x, v, a = plan.state(t)
        force = MOVING_MASS_KG * a + friction_force(v, fc, ka, vs)
        base = p_mean_bar * 1e5
        p_a = base + 0.5 * force / HOSE_AREA_M2
        p_b = base - 0.5 * force / HOSE_AREA_M2
        yield pd.DataFrame({"t_s": t, "x_m": encoder(x), "p_a_pa": pressure_sensor(p_a, rng),
                            "p_b_pa": pressure_sensor(p_b, rng)})


def durability_truth(plan: StrokePlan, hose_id: str, adjustment: str, p_mean_bar: float) -> dict:
    return {"kind": "durability", "hose_id": hose_id, "adjustment": adjustment, "distance_m": plan.distance_m,
            "distance_km": plan.distance_m / 1e3, "strokes": plan.strokes, "duration_s": plan.duration_s,
            "stroke_m": plan.stroke_m, "speed_m_s": plan.speed_m_s, "peak_speed_m_s": plan.peak_speed_m_s,
            "accel_m_s2": plan.accel_m_s2, "dwell_s": plan.dwell_s, "fs_hz": plan.fs_hz,
            "n_samples": plan.n_samples, "p_mean_bar": p_mean_bar, "x0_m": plan.x0_m,
            "stroke_definition": "one one-way move of stroke_m between the two ends"}


def simulate_durability(hose_id: str = "H-001", adjustment: str = "distance", distance_m: float | None = None,
                        duration_s: float | None = None, fs_hz: float = 1000.0, rng=None, *, stroke_m: float = 0.5,
                        speed_m_s: float = 0.5, accel_m_s2: float = 2.0, dwell_s: float = 0.2,
                        p_mean_bar: float = 2.0, **metadata) -> SimRun:
    """Durability run in memory (for long runs use :func:`stroke_plan` + :func:`iter_durability_chunks`).

    Give ``distance_m`` (whole strokes, rounded up) or ``duration_s``; default 60 s.
    """
    if distance_m is None and duration_s is None:
        duration_s = 60.0
    plan = stroke_plan(distance_m, duration_s, stroke_m=stroke_m, speed_m_s=speed_m_s, accel_m_s2=accel_m_s2,
                       dwell_s=dwell_s, fs_hz=fs_hz)
    data = pd.concat(list(iter_durability_chunks(plan, rng, p_mean_bar=p_mean_bar)), ignore_index=True)
    meta = {"kind": "durability", "rig": "plpa-1", "hose_id": hose_id, "adjustment": adjustment,
            "hose_area_m2": HOSE_AREA_M2, **metadata}
    return SimRun(data, meta, durability_truth(plan, hose_id, adjustment, p_mean_bar))
