"""Durability (hose service life) generators: back-and-forth strokes for hours, hose wear.

The carriage repeats single strokes (one-way moves of ``stroke_m``): dwell ``dwell_s`` at the
end, accelerate at ``accel_m_s2`` to ``speed_m_s``, cruise, decelerate to the other end. The
position is an analytic function of time, so a run of any length is generated in chunks
(:func:`iter_durability_chunks`) with bounded memory. Chamber pressures carry the drive force
``m a + F(v)`` around a mean pressure.

Hose wear (:class:`WearPath`): each hose's seal pressure falls linearly with distance at its own
rate, lognormal across hoses around the adjustment's mean (fast under distance-set rollers, as the
wall thins and the squeeze relaxes; slow under force-set ones, whose spring follows the wall), so
its leak at the pressure it sealed when new grows as a power 1.5 of distance; the wall bursts at a
Weibull distance of its own. A hose fails at the first of its leak crossing the lab's limit
(:data:`LEAK_LIMIT_L_MIN` at :data:`LEAK_PRESSURE_BAR`) and its rupture (docs/physics.md,
"Durability").
"""
from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import pandas as pd

from pipeline.simulator.base import HOSE_AREA_M2, MOVING_MASS_KG, SimRun, encoder, make_rng, pressure_sensor
from pipeline.simulator.plpa import LEAK_C, SPRING_FORCE_MAX_N, friction_force, seal_pressure_bar, viscous_parameters

#: The lab's functional failure by leakage (the demo plan's ``leak_limit_l_min`` at
#: ``leak_pressure_bar``): a hose has failed when its leak at the working pressure reaches the limit.
LEAK_LIMIT_L_MIN = 2.0
#: The working pressure at which the leak limit applies; new durability hoses seal it exactly. [bar gauge]
LEAK_PRESSURE_BAR = 6.0
#: Mean seal-pressure loss per km of travel across hoses, per roller adjustment. [bar/km]
SEAL_WEAR_BAR_KM = {"distance": 0.03, "force": 0.004}
#: Hose-to-hose coefficient of variation of the wear (a lognormal factor of mean 1). [-]
WEAR_CV = 0.35
#: Log-scale standard deviation of the seal deficit at one leakage check (how the hose seats
#: when it is clamped for the check): the leak's scatter around its path is 1.5 times it. [-]
SEATING_LOG_SD = 0.05
#: Rupture (wall burst) distance, a two-parameter Weibull per adjustment: (shape, scale [km]),
#: independent of the seal's wear.
RUPTURE_LIFE = {"force": (2.4, 90.0), "distance": (1.8, 80.0)}
#: New hose wall thickness [mm] and its mean wear per km (scaled by the hose's wear factor). [mm/km]
WALL_NEW_MM = 3.0
WALL_WEAR_MM_KM = {"distance": 0.012, "force": 0.006}


def sealing_setting(adjustment: str, p_bar: float = LEAK_PRESSURE_BAR) -> dict:
    """The roller setting at which a new hose seals ``p_bar`` (physics.md's seal pressure
    inverted): ``z_rollers_mm`` to 0.1 mm or ``spring_force_n`` to 1 N."""
    if adjustment == "distance":
        return {"z_rollers_mm": round(3.0 + (7.5 - p_bar) / 1.5, 1)}
    return {"spring_force_n": float(round((p_bar - 2.0) / 9.7 * SPRING_FORCE_MAX_N))}


@dataclass(frozen=True)
class WearPath:
    """One hose's degradation path and its rupture distance (the truth of its life).

    The seal pressure falls linearly with distance at the hose's own rate ``k``:
    ``p_seal(d) = p_seal_new - k d`` (the wall thins, the squeeze relaxes), and the leak at a
    pressure ``p`` is ``c (p - p_seal(d))^1.5`` above ``p_seal(d)`` (physics.md). At the pressure
    the hose seals when new (``p = p_seal_new``) the leak is ``(w d)^1.5`` with the **wear rate**
    ``w = c^(2/3) k`` [1/km]: a power law through the origin with a lognormal ``w`` across hoses,
    the family :mod:`analyses.leak_degradation` fits. At another pressure the path starts with an
    offset (a leak at ``d = 0`` above the seal pressure, none until ``k d = p_seal_new - p`` below it).

    Attributes
    ----------
    adjustment : str
        ``distance`` or ``force``.
    p_seal_new_bar : float
        Seal pressure of the new hose at its setting. [bar gauge]
    seal_wear_bar_km : float
        Its seal-pressure loss per km, ``k``. [bar/km]
    wear_factor : float
        ``k`` over the adjustment's mean (it also scales the wall's thinning). [-]
    c : float
        Leak coefficient of the checked chamber. [l/min/bar^1.5]
    rupture_km : float
        Distance at which the wall bursts. [km]
    """

    adjustment: str
    p_seal_new_bar: float
    seal_wear_bar_km: float
    wear_factor: float
    c: float
    rupture_km: float

    def seal_pressure_bar(self, distance_km: float, seating: float = 1.0) -> float:
        """Seal pressure after ``distance_km``, its deficit scaled by ``seating`` at a check. [bar gauge]"""
        return self.p_seal_new_bar - self.seal_wear_bar_km * distance_km * seating

    def leak_l_min(self, p_bar: float, distance_km: float) -> float:
        """The true leak at ``p_bar`` after ``distance_km`` (no seating scatter). [l/min ANR]"""
        return self.c * max(p_bar - self.seal_pressure_bar(distance_km), 0.0) ** 1.5

    @property
    def wear_rate_per_km(self) -> float:
        """``w = c^(2/3) k``: the leak at the new seal pressure is ``(w d)^1.5``. [1/km]"""
        return self.c ** (2.0 / 3.0) * self.seal_wear_bar_km

    def crossing_km(self, limit_l_min: float | None, p_bar: float | None) -> float:
        """Distance at which the leak at ``p_bar`` reaches ``limit_l_min`` (inf without a
        limit, 0 for a hose that leaks that much new). [km]"""
        if limit_l_min is None or p_bar is None:
            return math.inf
        need = (limit_l_min / self.c) ** (2.0 / 3.0) - (p_bar - self.p_seal_new_bar)  # deficit to wear [bar]
        return max(need, 0.0) / self.seal_wear_bar_km

    def failure(self, limit_l_min: float | None, p_bar: float | None) -> tuple[float, str]:
        """The hose's true failure distance [km] and mode (``leakage`` or ``rupture``): whichever comes first."""
        cross = self.crossing_km(limit_l_min, p_bar)
        return (cross, "leakage") if cross <= self.rupture_km else (self.rupture_km, "rupture")

    def truth(self, limit_l_min: float | None, p_bar: float | None) -> dict:
        """Its truth.json record: wear rate, crossing, rupture and failure distances [km]."""
        life, mode = self.failure(limit_l_min, p_bar)
        cross = self.crossing_km(limit_l_min, p_bar)
        return {"seal_wear_bar_km": self.seal_wear_bar_km, "wear_factor": self.wear_factor,
                "wear_rate_per_km": self.wear_rate_per_km, "p_seal_new_bar": self.p_seal_new_bar, "leak_c": self.c,
                "leak_crossing_km": cross if math.isfinite(cross) else None, "rupture_km": self.rupture_km,
                "failure_km": life, "failure_mode_true": mode}


def draw_wear_path(adjustment: str, setting: dict, rng: np.random.Generator, *, seal_wear_bar_km: float | None = None,
                   wear_cv: float = WEAR_CV, rupture: tuple | None = None, chamber: str = "A") -> WearPath:
    """One hose's :class:`WearPath`: a lognormal wear factor (mean 1, ``wear_cv``) times the mean
    seal wear of its adjustment, and a Weibull rupture distance (``rupture``: shape, scale [km])."""
    s_log = math.sqrt(math.log1p(wear_cv ** 2))
    factor = float(math.exp(s_log * rng.standard_normal() - s_log ** 2 / 2.0))
    shape, scale = rupture or RUPTURE_LIFE[adjustment]
    k = (SEAL_WEAR_BAR_KM[adjustment] if seal_wear_bar_km is None else seal_wear_bar_km) * factor
    p0 = seal_pressure_bar(adjustment, setting.get("z_rollers_mm"), setting.get("spring_force_n"))
    return WearPath(adjustment, p0, k, factor, LEAK_C[chamber], float(scale * rng.weibull(shape)))


def life_b10_km(adjustment: str, limit_l_min: float | None = LEAK_LIMIT_L_MIN, p_bar: float | None = LEAK_PRESSURE_BAR,
                setting: dict | None = None, q: float = 0.10) -> float:
    """The true ``q`` quantile (B10) of the life of the adjustment's hoses: the first of the
    lognormal leak crossing and the Weibull rupture (their survivals multiply), at ``setting``
    (default: :func:`sealing_setting` of ``p_bar``). [km]"""
    from scipy import optimize, stats

    setting = setting or sealing_setting(adjustment, p_bar or LEAK_PRESSURE_BAR)
    s_log = math.sqrt(math.log1p(WEAR_CV ** 2))
    mean = WearPath(adjustment, seal_pressure_bar(adjustment, setting.get("z_rollers_mm"),
                                                  setting.get("spring_force_n")),
                    SEAL_WEAR_BAR_KM[adjustment], 1.0, LEAK_C["A"], math.inf).crossing_km(limit_l_min, p_bar)
    shape, scale = RUPTURE_LIFE[adjustment]

    def survival(t):
        s_leak = 1.0 if not math.isfinite(mean) else stats.norm.sf((math.log(t) - math.log(mean) - s_log ** 2 / 2) / s_log)
        return s_leak * math.exp(-(t / scale) ** shape)

    return float(optimize.brentq(lambda t: survival(t) - (1.0 - q), 1e-6, 10 * scale))


def wall_thickness_mm(adjustment: str, distance_km: float, wear_factor: float = 1.0) -> float:
    """True wall thickness after ``distance_km`` of travel, thinning at ``wear_factor`` times the mean. [mm]"""
    return WALL_NEW_MM - WALL_WEAR_MM_KM[adjustment] * wear_factor * distance_km


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
