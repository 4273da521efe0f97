"""The ``rul`` profile: hundreds of running hoses with frequent leak checks and known futures, for
calibrating the remaining-life predictions of issue 24 ("Remaining life") end to end.

Each hose type has, per roller adjustment, a median leak-crossing distance (log-uniform over
``crossing_km`` for distance-set rollers, ``force_slower`` times longer for force-set ones), a
hose-to-hose coefficient of variation of the wear (``wear_cv``) and a Weibull rupture distance
(shape ``rupture_shape``, scale ``rupture_scale`` median crossings). Every hose is a
:class:`~pipeline.simulator.durability.WearPath` set to seal the plan's ``leak_pressure_bar``
when new, so its leak there is ``(w d)^1.5`` with a lognormal wear rate ``w`` (the family of
:mod:`analyses.leak_degradation`), read by a leakage check (three plateaus up to that pressure, a
low-range flow meter stated in ``rig.toml``) after every durability run of ``check_every``
median crossings, with the seating scatter of physics.md. A hose fails at the first of its leak
crossing ``leak_limit_l_min`` (the rig's leak monitor stops the run there; a last check reads the
leak) and its rupture; the logbook names the mode. The campaign ends for each hose at a distance
drawn uniformly over ``ends`` median crossings (staggered installations): the hoses alive then
are ``running``, their distance so far given by their runs.

Distances are short (a few km: a hose type worn fast on purpose) so that the durability runs
between checks stay a few thousand samples at the demo's 5 Hz logging; the analyses are
invariant to the scale. Truth (``truth.json``): per hose type and adjustment the wear-rate
distribution (mean and standard deviation of ``w`` [1/km]), per hose its wear rate, true
leak-crossing, rupture and failure distances [km], also for the running hoses. Seeded: hose type
``j`` draws from its own generator ``(seed, 24, j)``. References: Lu & Meeker 1993 (degradation
paths with random effects), Meeker & Escobar 1998 ch. 13 and 15.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime, timedelta

import numpy as np

from pipeline.simulator import durability as dur
from pipeline.simulator.plan import Planner, RunSpec, iso
from pipeline.simulator.profiles import Profile
from pipeline.simulator.variants import VARIANTS

#: The campaign folder the profile writes.
RUL_CAMPAIGN = "rul-2026"
START = datetime(2026, 2, 2, 7, 0)
ADJUSTMENTS = ("distance", "force")
#: The campaign's rig.toml: the endurance rig, its encoder, and the low-range flow meter of its checks.
RIG_TOML = ('[metadata]\nrig = "plpa-2"\nhose_area_m2 = 4.9e-4\n\n[sensors.x]\nresolution = "5 um"\n\n'
            '[sensors.q_leak]\nresolution = "0.001 l/min"\nnoise = "0.002 l/min"\n')
#: Durability runs and leakage checks, both CSV with their metadata embedded.
DURABILITY_VARIANT = VARIANTS["durability"][1]
CHECK_VARIANT = VARIANTS["leakage_check"][0]


@dataclass(frozen=True)
class RulProfile:
    """A ``rul`` campaign's settings.

    ``hose_types`` types of ``hoses`` hoses per adjustment; ``crossing_km`` the range
    (log-uniform) of a type's median leak-crossing distance under distance-set rollers [km];
    ``force_slower`` the range of how many times longer force-set hoses take; ``wear_cv`` the range
    of a type's hose-to-hose coefficient of variation of the wear rate [-]; ``rupture_shape`` [-]
    and ``rupture_scale`` (in median crossings) the rupture Weibull; ``check_every`` the distance
    between leak checks and ``ends`` the range of the hoses' distances at the campaign's end, both
    in median crossings; ``leak_limit_l_min`` [l/min] at ``leak_pressure_bar`` [bar] the failure
    by leakage (the plan's); ``flow_noise_l_min`` the checks' flow-meter noise [l/min].
    """

    hose_types: int = 10
    hoses: int = 25
    crossing_km: tuple = (1.5, 3.0)
    force_slower: tuple = (1.5, 2.5)
    wear_cv: tuple = (0.25, 0.45)
    rupture_shape: float = 2.0
    rupture_scale: float = 3.0
    check_every: float = 0.2
    ends: tuple = (0.6, 1.05)
    leak_limit_l_min: float = dur.LEAK_LIMIT_L_MIN
    leak_pressure_bar: float = dur.LEAK_PRESSURE_BAR
    confidence: float = 0.9
    flow_noise_l_min: float = 0.002
    check_fs_hz: float = 20.0
    check_plateau_s: float = 3.0


def plan_toml(p: RulProfile) -> str:
    """The profile's ``plan.toml``: the leakage failure and the confidence as the lab's ``[defaults]``."""
    return ("# the rul profile's test plan (pipeline.simulator.rul)\n[defaults]\n"
            f"confidence = {p.confidence!r}\nleak_limit_l_min = {p.leak_limit_l_min!r}\n"
            f"leak_pressure_bar = {p.leak_pressure_bar!r}\n")


def group_truth(hose_type: str, adj: str, median_km: float, cv: float, p: RulProfile) -> dict:
    """The truth of one (hose type, adjustment): its wear-rate distribution, median crossing,
    rupture Weibull, check spacing."""
    reach = (p.leak_limit_l_min / dur.LEAK_C["A"]) ** (2.0 / 3.0)   # the seal deficit at the limit [bar]
    seal_wear = reach * math.sqrt(1.0 + cv * cv) / median_km        # mean k: median crossing = reach / median k
    w_mean = dur.LEAK_C["A"] ** (2.0 / 3.0) * seal_wear
    return {"hose_type": hose_type, "adjustment": adj, "median_crossing_km": median_km, "wear_cv": cv,
            "seal_wear_bar_km": seal_wear, "wear_rate_mean_per_km": w_mean, "wear_rate_sd_per_km": w_mean * cv,
            "rupture_shape": p.rupture_shape, "rupture_scale_km": p.rupture_scale * median_km,
            "check_every_km": p.check_every * median_km, "setting": dur.sealing_setting(adj, p.leak_pressure_bar)}


class _Bench:
    """One hose on its bench: its runs, checks and logbook rows, planned into ``pl``."""

    def __init__(self, pl: Planner, p: RulProfile, group: dict, hose_id: str, rng: np.random.Generator, when):
        self.pl, self.p, self.g, self.hose_id, self.rng, self.when = pl, p, group, hose_id, rng, when
        self.path = dur.draw_wear_path(group["adjustment"], group["setting"], rng,
                                       seal_wear_bar_km=group["seal_wear_bar_km"], wear_cv=group["wear_cv"],
                                       rupture=(group["rupture_shape"], group["rupture_scale_km"]))
        self.km, self.n = 0.0, 0

    def plan(self, end_km: float, rows: list[dict]) -> dict:
        """Run the hose to its failure or to ``end_km``; its logbook rows and its truth."""
        g, p = self.g, self.p
        life, mode = self.path.failure(p.leak_limit_l_min, p.leak_pressure_bar)
        stop = min(life, end_km)
        rows.append({"hose_id": self.hose_id, "event": "installed", "at": iso(self.when - timedelta(minutes=30)),
                     "hose_type": g["hose_type"], "adjustment": g["adjustment"], **g["setting"]})
        while stop - self.km > 1e-3:
            self.run(min(g["check_every_km"], stop - self.km))
            if stop - self.km > 1e-3 or (life <= end_km and mode == "leakage"):
                self.check()
        failed = life <= end_km
        if failed:
            rows.append({"hose_id": self.hose_id, "event": "failed", "at": iso(self.when), "failure_mode": mode})
        return {"hose_id": self.hose_id, "hose_type": g["hose_type"], "adjustment": g["adjustment"],
                "status": "failed" if failed else "running", "distance_km": self.km, "end_km": end_km,
                "n_runs": self.n, **self.path.truth(p.leak_limit_l_min, p.leak_pressure_bar)}

    def run(self, km: float) -> None:
        """A durability run of ``km`` (whole 1 m strokes at the demo's 5 Hz logging)."""
        d = Profile("rul")
        kw = dict(distance_m=km * 1e3, stroke_m=d.dur_stroke_m, speed_m_s=d.dur_speed_m_s,
                  accel_m_s2=d.dur_accel_m_s2, dwell_s=d.dur_dwell_s, fs_hz=d.dur_fs_hz)
        sp = dur.stroke_plan(**kw)
        self.n += 1
        self.pl.add(RunSpec(RUL_CAMPAIGN, "durability", "durability", f"dur-{self.hose_id}-{self.n:02d}", kw,
                            meta={"hose_id": self.hose_id, "adjustment": self.g["adjustment"], **self.g["setting"]}),
                    variant=DURABILITY_VARIANT, when=self.when)
        self.km += sp.distance_m / 1e3
        self.when += timedelta(seconds=math.ceil(sp.duration_s) + 600)

    def check(self) -> None:
        """A leakage check of the worn seal at the hose's distance now (seating scatter included)."""
        p, g = self.p, self.g
        seating = math.exp(dur.SEATING_LOG_SD * self.rng.standard_normal())
        kw = dict(chamber="A", adjustment=g["adjustment"], z_rollers_mm=g["setting"].get("z_rollers_mm"),
                  spring_force_n=g["setting"].get("spring_force_n"),
                  p_seal_bar=self.path.seal_pressure_bar(self.km, seating), fs_hz=p.check_fs_hz,
                  plateau_s=p.check_plateau_s, hose_id=self.hose_id, flow_noise_l_min=p.flow_noise_l_min,
                  pressures_bar=[0.0, p.leak_pressure_bar / 2.0, p.leak_pressure_bar])
        self.pl.add(RunSpec(RUL_CAMPAIGN, "leakage_check", "leakage", f"check-{self.hose_id}-{self.n:02d}", kw,
                            meta={"hose_id": self.hose_id, "distance_km_so_far": round(self.km, 6)}),
                    variant=CHECK_VARIANT, when=self.when)
        self.when += timedelta(minutes=15)


def plan_rul(seed: int, p: RulProfile) -> tuple[Planner, list[dict], dict]:
    """Every run of a ``rul`` campaign (a :class:`~pipeline.simulator.plan.Planner` holding the
    plans), its logbook rows and its truth (settings, per group, per hose)."""
    pl = Planner(Profile("rul"), seed)
    rows, groups, hoses = [], {}, {}
    for j in range(p.hose_types):
        rng = np.random.default_rng([int(seed), 24, j])
        hose_type = f"RUL-{j + 1:02d}"
        median = float(math.exp(rng.uniform(math.log(p.crossing_km[0]), math.log(p.crossing_km[1]))))
        medians = {"distance": median, "force": median * float(rng.uniform(*p.force_slower))}
        cv = float(rng.uniform(*p.wear_cv))
        for a, adj in enumerate(ADJUSTMENTS):
            g = group_truth(hose_type, adj, medians[adj], cv, p)
            for n in range(p.hoses):
                when = START + timedelta(days=j, hours=a * 12 + n * 0.25)
                bench = _Bench(pl, p, g, f"{hose_type}-{adj[0].upper()}{n + 1:03d}", rng, when)
                h = bench.plan(float(rng.uniform(*p.ends)) * medians[adj], rows)
                hoses[h["hose_id"]] = h
            g.update({f"n_{s}": sum(h["status"] == s for h in hoses.values() if h["hose_type"] == hose_type
                                    and h["adjustment"] == adj) for s in ("failed", "running")})
            groups[f"{hose_type}/{adj}"] = g
    settings = {k: getattr(p, k) for k in p.__dataclass_fields__}
    truth = {"generator": "pneubench simulator", "seed": seed, "profile": "rul", "settings": settings,
             "plan": "plan.toml", "logbook": f"{RUL_CAMPAIGN}/hoses.csv", "groups": groups, "hoses": hoses}
    return pl, rows, truth
