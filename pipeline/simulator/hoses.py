"""The durability campaigns' hoses: each hose's life on the rig as logbook events and run plans.

Older hoses carry odometer readings only (logbook ``durability-2025``, dates from 2023). Logged
hoses get durability runs, inspections (wall thickness) and leakage checks of their worn seal;
the first one spans both campaigns (``durability-2025`` and ``durability-2026``). Each hose has a
degradation path (:class:`pipeline.simulator.durability.WearPath`: its own wear rate, its seal
pressure falling with distance, a rupture distance), drawn with the campaign's own generator, so
the hoses do not depend on the other runs; it fails at the first of its leak at the profile's
``leak_pressure_bar`` reaching ``leak_limit_l_min`` and its rupture, and the logbook names the
mode. Every hose is set to seal ``leak_pressure_bar`` when new (:func:`~pipeline.simulator.durability.sealing_setting`),
so its leak there starts at zero and grows as a power of distance. Leakage checks read the worn
seal with a small seating scatter (:data:`~pipeline.simulator.durability.SEATING_LOG_SD`).
Truth per hose: its wear rate, true leak-crossing, rupture and failure distances, also for the
hoses still running.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime, timedelta

import numpy as np

from pipeline.simulator import durability as dur
from pipeline.simulator.plan import Planner, RunSpec, iso
from pipeline.simulator.profiles import Profile

HOSE_TYPE = "FLEXIGOM AIR"
#: The columns of a campaign's ``hoses.csv`` (the logbook events' fields).
HOSES_COLUMNS = ["hose_id", "event", "at", "hose_type", "adjustment", "z_rollers_mm", "spring_force_n",
                 "failure_mode", "wall_thickness_mm", "distance_km", "notes"]


@dataclass(frozen=True)
class LoggedHose:
    """A logged hose's fate, drawn before its runs are planned.

    ``index``: its number among the logged hoses; ``spans``: continued into ``durability-2026``;
    ``life_km``: its true failure distance [km] (``path``'s first of leak crossing and rupture);
    ``end_km``: the distance it runs [km] (its life if it fails, else the profile's stop);
    ``outcome``: ``failed``, ``removed`` or ``running``; ``path``: its degradation path;
    ``mode``: how it fails (or would).
    """

    hose_id: str
    adjustment: str
    index: int
    campaign: str
    spans: bool
    life_km: float
    end_km: float
    outcome: str
    path: dur.WearPath | None = None
    mode: str | None = None


def plan_hoses(pl: Planner) -> None:
    """Plan every hose of the durability campaigns into ``pl``: the odometer hoses' logbook, then
    each logged hose's runs, checks and events."""
    p = pl.p
    rng = np.random.default_rng([int(pl.seed), 987654321])
    when = pl.clock["odometer"]
    for j in range(p.odometer_hoses):
        when = _odometer_hose(pl, j, when, rng)
    for j in range(p.logged_hoses):
        _HoseRuns(pl, _logged_hose(p, pl.seed, j), rng).plan()


def _odometer_hose(pl: Planner, j: int, when: datetime, rng: np.random.Generator) -> datetime:
    """An older hose (logbook of durability-2025 with odometer readings only) installed at
    ``when``; returns when the next one is installed."""
    p = pl.p
    adj = ("distance", "force")[j % 2]
    hose_id = f"H{j + 1:03d}"
    setting = _setting(adj, p)
    path = dur.draw_wear_path(adj, setting, _path_rng(pl.seed, hose_id))
    life, mode = path.failure(p.leak_limit_l_min, p.leak_pressure_bar)
    stop = p.odometer_stop_km
    failed = life <= stop
    dist = life if failed else stop
    days = max(1, int(dist / 20.0))  # about 20 km a working day on the old rig
    ev = [_event(hose_id, "installed", when, adjustment=adj, hose_type=HOSE_TYPE, **setting,
                 notes="tested before runs were logged")]
    if dist > 10:
        ev.append(_event(hose_id, "inspected", when + timedelta(days=days // 2, hours=6),
                         wall_thickness_mm=round(dur.wall_thickness_mm(adj, dist / 2, path.wear_factor)
                                                 + rng.normal(0, 0.01), 2),
                         notes=f"odometer {dist / 2:.1f} km"))
    end = when + timedelta(days=days, hours=8)
    if failed:
        ev.append(_event(hose_id, "failed", end, failure_mode=mode, distance_km=round(dist, 1)))
    else:
        ev.append(_event(hose_id, "removed", end, distance_km=round(dist, 1), notes="test stopped"))
    pl.logbooks["durability-2025"] += ev
    pl.hoses[hose_id] = {"hose_id": hose_id, "hose_type": HOSE_TYPE, "adjustment": adj, **setting,
                         "life_km_drawn": life, "status": "failed" if failed else "removed",
                         "failure_mode": mode if failed else None, "distance_km": round(dist, 1),
                         "source": "odometer", "n_runs": 0, "strokes": None,
                         "campaigns": ["durability-2025"], **path.truth(p.leak_limit_l_min, p.leak_pressure_bar)}
    return end + timedelta(days=1)


def _path_rng(seed: int, hose_id: str) -> np.random.Generator:
    """The generator of a hose's degradation path: its own, from the seed and its number, so a
    hose's path depends on nothing planned before it."""
    return np.random.default_rng([int(seed), 24, int(hose_id[1:])])


def _logged_hose(p: Profile, seed: int, j: int) -> LoggedHose:
    """Logged hose ``j``: its campaign, its degradation path, its life and how its test ends."""
    adj = ("distance", "force")[j % 2]
    camp = "durability-2025" if j < max(1, p.logged_hoses // 2) else "durability-2026"
    hose_id = f"H{100 + j + 1:03d}"
    path = dur.draw_wear_path(adj, _setting(adj, p), _path_rng(seed, hose_id))
    life, mode = path.failure(p.leak_limit_l_min, p.leak_pressure_bar)
    stop = p.stop_km[adj]
    if j == p.logged_hoses - 1:
        outcome = "running"
    elif life <= stop:
        outcome = "failed"
    else:
        outcome = "removed" if j % 3 != 1 else "running"
    end_km = life if outcome == "failed" else stop
    return LoggedHose(hose_id, adj, j, camp, j == 0, life, end_km, outcome, path, mode)


class _HoseRuns:
    """One logged hose's life on the rig: installation, runs, inspections, leakage checks, its end.

    Walks the hose's own clock (``when``) and distance (``km``) while it plans into the planner.
    """

    def __init__(self, pl: Planner, hose: LoggedHose, rng: np.random.Generator):
        self.pl, self.hose, self.rng = pl, hose, rng
        self.setting = _setting(hose.adjustment, pl.p)
        n_runs = max(1, math.ceil(hose.end_km / pl.p.dur_run_km - 1e-9))
        split = (n_runs + 1) // 2 if hose.spans else n_runs  # runs logged in the first campaign
        if hose.spans and n_runs < 2:
            n_runs, split = 2, 1
        self.n_runs, self.split = n_runs, split
        self.per_run = hose.end_km / n_runs
        self.when = pl.clock[hose.campaign]
        self.km = 0.0
        self.strokes = 0
        self.checks: list[dict] = []

    def plan(self) -> None:
        """Plan the hose: installed, checked, its runs, its end; then record it in ``pl.hoses``."""
        h, pl = self.hose, self.pl
        pl.logbooks[h.campaign].append(_event(h.hose_id, "installed", self.when - timedelta(hours=1),
                                              adjustment=h.adjustment, hose_type=HOSE_TYPE, **self.setting))
        self.check(0)
        for r in range(self.n_runs):
            self.run(r)
        mode = self.end()
        pl.clock["durability-2026" if h.spans else h.campaign] = self.when + timedelta(days=1)
        pl.hoses[h.hose_id] = {"hose_id": h.hose_id, "hose_type": HOSE_TYPE, "adjustment": h.adjustment,
                               **self.setting, "life_km_drawn": h.life_km, "status": h.outcome,
                               "failure_mode": mode, "distance_km": self.km, "strokes": self.strokes,
                               "source": "runs", "n_runs": self.n_runs,
                               "campaigns": [h.campaign] + (["durability-2026"] if h.spans else []),
                               "leakage_checks": self.checks,
                               **h.path.truth(self.pl.p.leak_limit_l_min, self.pl.p.leak_pressure_bar)}

    def campaign_at(self, run_number: int) -> str:
        """The campaign the hose is in after ``run_number`` runs."""
        return "durability-2026" if self.hose.spans and run_number > self.split else self.hose.campaign

    def check(self, after_run: int) -> None:
        """A leakage check of the worn seal after ``after_run`` runs (30 min): the seal pressure
        of the hose's path, its deficit scattered by how the hose seats for the check."""
        h, p = self.hose, self.pl.p
        p_seal = h.path.seal_pressure_bar(self.km, math.exp(dur.SEATING_LOG_SD * self.rng.standard_normal()))
        plan = self.pl.add(RunSpec(self.campaign_at(after_run), "leakage_check", "leakage",
                                   f"check-{h.hose_id}-{after_run:02d}",
                                   dict(chamber="A", adjustment=h.adjustment,
                                        z_rollers_mm=self.setting.get("z_rollers_mm"),
                                        spring_force_n=self.setting.get("spring_force_n"), p_seal_bar=p_seal,
                                        fs_hz=p.check_fs_hz, plateau_s=p.check_plateau_s, hose_id=h.hose_id),
                                   meta={"hose_id": h.hose_id, "distance_km_so_far": round(self.km, 6)}),
                           when=self.when)
        self.checks.append({"run_id": plan.run_id, "distance_km": self.km, "p_seal_bar": p_seal,
                            "p_seal_path_bar": h.path.seal_pressure_bar(self.km),
                            "leak_path_l_min": h.path.leak_l_min(p.leak_pressure_bar, self.km)})
        self.when += timedelta(minutes=30)

    def run(self, r: int) -> None:
        """Durability run ``r`` (2 h break after it), then a check or an inspection when due."""
        h, p, pl = self.hose, self.pl.p, self.pl
        if h.spans and r == self.split:
            pl.clock[h.campaign] = self.when
            self.when = max(pl.clock["durability-2026"], self.when)
        sp = dur.stroke_plan(distance_m=self.per_run * 1e3, stroke_m=p.dur_stroke_m, speed_m_s=p.dur_speed_m_s,
                             accel_m_s2=p.dur_accel_m_s2, dwell_s=p.dur_dwell_s, fs_hz=p.dur_fs_hz)
        pl.add(RunSpec(self.campaign_at(r + 1), "durability", "durability", f"dur-{h.hose_id}-{r + 1:02d}",
                       dict(distance_m=self.per_run * 1e3, stroke_m=p.dur_stroke_m, speed_m_s=p.dur_speed_m_s,
                            accel_m_s2=p.dur_accel_m_s2, dwell_s=p.dur_dwell_s, fs_hz=p.dur_fs_hz),
                       meta={"hose_id": h.hose_id, "adjustment": h.adjustment, **self.setting}), when=self.when)
        self.km += sp.distance_m / 1e3
        self.strokes += sp.strokes
        self.when = self.when + timedelta(seconds=math.ceil(sp.duration_s)) + timedelta(hours=2)
        last = r == self.n_runs - 1
        if (r + 1) % p.check_every == 0 or last:
            if not (last and h.outcome == "failed"):
                self.check(r + 1)
        if (r + 1) % 2 == 0 and not last:
            thickness = round(dur.wall_thickness_mm(h.adjustment, self.km, h.path.wear_factor)
                              + self.rng.normal(0, 0.01), 2)
            pl.logbooks[self.campaign_at(r + 1)].append(_event(h.hose_id, "inspected", self.when,
                                                               wall_thickness_mm=thickness))
            self.when += timedelta(minutes=20)

    def end(self) -> str | None:
        """How the hose's test ends (failed, removed, still running); returns its failure mode."""
        h = self.hose
        book = self.pl.logbooks[self.campaign_at(self.n_runs)]
        mode = h.mode if h.outcome == "failed" else None
        if h.outcome == "failed":
            extra = ({"distance_km": round(self.km * 1.005, 2), "notes": "odometer read at failure"}
                     if h.index % 4 == 2 else {})
            book.append(_event(h.hose_id, "failed", self.when, failure_mode=mode, **extra))
            if mode == "leakage":
                self.check(self.n_runs)
        elif h.outcome == "removed":
            book.append(_event(h.hose_id, "removed", self.when, notes="campaign budget reached"))
        return mode


def _setting(adj: str, p: Profile) -> dict:
    """A hose's roller distance [mm] or spring force [N]: the setting that seals the profile's
    ``leak_pressure_bar`` when new (its leak there starts at zero)."""
    return dur.sealing_setting(adj, p.leak_pressure_bar or dur.LEAK_PRESSURE_BAR)


def _event(hose_id: str, event: str, at: datetime, **kw) -> dict:
    """A logbook row: the hose, the event, when, and the event's fields."""
    return {"hose_id": hose_id, "event": event, "at": iso(at), **kw}
