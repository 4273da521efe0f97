"""The decision's looks: one look at each failure, every hose at its distance then, the verdict over them.

A hose type's test is read at every failure, in logbook time order (Jennison & Turnbull 2000,
ch. 1 and 7: a look at each event). Pure functions from the ``hose_life`` rows of one hose type
and its matched durability runs to the looks, so that the same raw/ gives the same looks
whatever night they were computed on:

* :func:`failure_events`: the looks, the failed hoses with a known positive life ordered by
  ``ended_at`` (ties by ``hose_id``);
* :func:`look_hoses`: every hose installed by a look's event at its distance then: from its
  durability runs (a run under way at the event counts the fraction of its duration elapsed,
  linear in time; a run without a duration counts whole once started, as
  :func:`analyses.hose_life.hose_distance_at` counts it); for a hose known only by its odometer,
  linear in time between its installation and its end event ("odometer, linear in time").
  A hose that failed at or before the look (in look order) is at its exact life, the others are
  censored at their distance then;
* :func:`look_estimates`: per look the common-shape Weibull regression of life on the
  adjustment (:func:`analyses.life_effect.common_shape_fit`, Meeker & Escobar 1998, ch. 17):
  ``log_ratio`` and its standard error, NaN with a note where the data cannot tell;
* :func:`decide`: the sequential verdict over all looks
  (:func:`analyses.sequential.sequential_verdict`: Lan & DeMets 1983 alpha spending, repeated
  confidence intervals, a verdict that sticks) at ``information_fraction = failures /
  max_failures``.

Decisions
---------
* Hoses whose life is unknown (a failed or removed hose without runs or odometer reading) are
  left out: their failure is no look (the ``life_effect`` fit leaves them out too, so the last
  look's failures are that fit's).
* A hose known only by its odometer without an end event (a running hose whose reading came from
  an earlier installation) has no time span to interpolate over: it is left out of the looks
  (its count is returned for the note).
* The times of a reinstalled hose's gap are not known to :mod:`analyses.hose_life`'s table: an
  odometer hose is interpolated over first installation .. last end.

References
----------
Meeker, W. Q. & Escobar, L. A. (1998). Statistical Methods for Reliability Data. Wiley.
Jennison, C. & Turnbull, B. W. (2000). Group Sequential Methods with Applications to Clinical
Trials. Chapman & Hall/CRC.
Lan, K. K. G. & DeMets, D. L. (1983). Discrete sequential boundaries for clinical trials.
Biometrika 70, 659-663.
"""
from __future__ import annotations

import math

import numpy as np
import pandas as pd

from analyses.life_effect import common_shape_fit
from analyses.sequential import SequentialVerdict, sequential_verdict

#: ``distance_from`` of a hose whose distance comes from its durability runs.
FROM_RUNS = "runs"
#: ``distance_from`` of a hose known only by its odometer.
FROM_ODOMETER = "odometer, linear in time"

#: Adjustment -> group of :func:`analyses.life_effect.life_effect` (0 distance, 1 force).
GROUP = {"distance": 0, "force": 1}

LOOK_HOSE_COLUMNS = ["look", "hose_id", "adjustment", "distance_km", "failed", "distance_from"]
LOOK_COLUMNS = ["look", "event_at", "hose_id", "failures", "n_hoses", "total_km", "log_ratio", "se_log_ratio",
                "note"]


def _ns(values) -> np.ndarray:
    """UTC times as int64 nanoseconds (NaT -> the minimum int64)."""
    return pd.to_datetime(pd.Series(values), utc=True, format="ISO8601").to_numpy("datetime64[ns]").astype(np.int64)


_NAT = np.iinfo(np.int64).min


def usable_hoses(life: pd.DataFrame) -> pd.DataFrame:
    """The hoses of ``life`` that can be placed in the looks.

    Parameters
    ----------
    life : DataFrame
        ``hose_life`` rows: ``hose_id``, ``adjustment``, ``distance_km`` [km], ``status``,
        ``distance_source``, ``installed_at``, ``ended_at`` (UTC).

    Returns
    -------
    DataFrame
        The rows with a known distance (>= 0), an adjustment ``force`` or ``distance``, an
        installation time, and (odometer-only hoses) an end event; sorted by ``hose_id``.
    """
    d = pd.to_numeric(life["distance_km"], errors="coerce")
    ok = d.notna() & (d >= 0) & life["adjustment"].isin(list(GROUP)) & life["installed_at"].notna()
    ok &= ~((life["distance_source"] == "odometer") & life["ended_at"].isna())
    return life[ok].sort_values("hose_id", kind="stable").reset_index(drop=True)


def failure_events(hoses: pd.DataFrame) -> pd.DataFrame:
    """The looks: failed hoses with a positive life, by ``ended_at`` then ``hose_id``.

    Parameters
    ----------
    hoses : DataFrame
        :func:`usable_hoses` rows.

    Returns
    -------
    DataFrame
        ``look`` (1..), ``hose_id``, ``event_at`` (UTC).
    """
    failed = hoses[(hoses["status"] == "failed") & (pd.to_numeric(hoses["distance_km"]) > 0)
                   & hoses["ended_at"].notna()]
    ev = failed[["hose_id", "ended_at"]].rename(columns={"ended_at": "event_at"})
    ev = ev.sort_values(["event_at", "hose_id"], kind="stable").reset_index(drop=True)
    ev.insert(0, "look", np.arange(1, len(ev) + 1, dtype=np.int64))
    return ev


def runs_distance_at(starts, durations_h, distances_km, times) -> np.ndarray:
    """Distance [km] a hose's runs had covered at each time.

    A run ended by then counts whole; a run under way counts the fraction of its duration
    elapsed (linear in time); a run without a positive duration counts whole once started (as
    :func:`analyses.hose_life.hose_distance_at`); a run without a distance counts 0.

    Parameters
    ----------
    starts : array_like of datetime64 or Timestamp
        Start of each run (UTC).
    durations_h : array_like
        Duration of each run [h].
    distances_km : array_like
        Distance of each run [km].
    times : array_like of datetime64 or Timestamp
        When (UTC).

    Returns
    -------
    numpy.ndarray
        One distance [km] per time.
    """
    t = _ns(times).astype(np.float64)
    if len(starts) == 0:
        return np.zeros(t.size)
    s = _ns(starts).astype(np.float64)
    dur = np.asarray(pd.to_numeric(pd.Series(durations_h), errors="coerce"), float) * 3.6e12
    km = np.nan_to_num(np.asarray(pd.to_numeric(pd.Series(distances_km), errors="coerce"), float))
    elapsed = t[None, :] - s[:, None]
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = np.where((np.isfinite(dur) & (dur > 0))[:, None], np.clip(elapsed / dur[:, None], 0.0, 1.0),
                        (elapsed > 0).astype(float))
    return km @ frac


def _odometer_at(hose: dict, t: np.ndarray) -> np.ndarray:
    """Distance [km] of an odometer-only hose at times ``t`` [ns], linear between installation and end."""
    start, end = _ns([hose["installed_at"]])[0], _ns([hose["ended_at"]])[0]
    km = float(hose["distance_km"])
    if end <= start:
        return np.where(t >= end, km, 0.0)
    return km * np.clip((t - start) / float(end - start), 0.0, 1.0)


def look_hoses(hoses: pd.DataFrame, runs: pd.DataFrame, events: pd.DataFrame) -> pd.DataFrame:
    """Every hose in every look, at its distance at the look's event.

    Parameters
    ----------
    hoses : DataFrame
        :func:`usable_hoses` rows of one hose type.
    runs : DataFrame
        Their matched durability runs: ``hose_id`` (the hose the run belongs to,
        :func:`analyses.hose_life.match_runs`), ``started_at`` (UTC), ``duration_h`` [h],
        ``distance_km`` [km].
    events : DataFrame
        :func:`failure_events` of those hoses.

    Returns
    -------
    DataFrame
        ``look``, ``hose_id``, ``adjustment``, ``distance_km`` [km], ``failed`` (at or before the
        look, in look order), ``distance_from`` (:data:`FROM_RUNS` or :data:`FROM_ODOMETER`);
        a hose is in a look when installed by its event; ordered by look then hose.
    """
    t = _ns(events["event_at"]) if len(events) else np.empty(0, np.int64)
    rank = dict(zip(events["hose_id"], events["look"]))
    by_hose = {h: g for h, g in runs.groupby("hose_id", sort=False)} if len(runs) else {}
    frames = []
    for h in hoses.to_dict("records"):
        installed = _ns([h["installed_at"]])[0]
        odometer = h.get("distance_source") == "odometer"
        if odometer:
            dist = _odometer_at(h, t.astype(np.float64))
        else:
            mine = by_hose.get(h["hose_id"])
            dist = (runs_distance_at(mine["started_at"], mine["duration_h"], mine["distance_km"], events["event_at"])
                    if mine is not None else np.zeros(t.size))
        failed = np.arange(1, t.size + 1) >= rank.get(h["hose_id"], t.size + 1)
        dist = np.where(failed, float(h["distance_km"]), dist)
        keep = t >= installed
        frames.append(pd.DataFrame({"look": events["look"].to_numpy()[keep], "hose_id": h["hose_id"],
                                    "adjustment": h["adjustment"], "distance_km": dist[keep], "failed": failed[keep],
                                    "distance_from": FROM_ODOMETER if odometer else FROM_RUNS}))
    if not frames:
        return pd.DataFrame(columns=LOOK_HOSE_COLUMNS)
    out = pd.concat(frames, ignore_index=True)
    return out.sort_values(["look", "hose_id"], kind="stable", ignore_index=True)[LOOK_HOSE_COLUMNS]


def look_estimates(in_looks: pd.DataFrame, events: pd.DataFrame) -> pd.DataFrame:
    """The estimate at each look: the common-shape life ratio and its standard error.

    Parameters
    ----------
    in_looks : DataFrame
        :func:`look_hoses`.
    events : DataFrame
        :func:`failure_events`.

    Returns
    -------
    DataFrame
        Per look: ``look``, ``event_at``, ``hose_id`` (the hose that failed), ``failures``,
        ``n_hoses`` (in the look), ``total_km`` [km] (their distances summed), ``log_ratio`` [-]
        (ln force / distance life), ``se_log_ratio`` [-], ``note`` (why the estimate is NaN, and
        the hoses placed by odometer).
    """
    rows = []
    groups = dict(iter(in_looks.groupby("look", sort=True))) if len(in_looks) else {}
    for ev in events.to_dict("records"):
        g = groups.get(ev["look"], in_looks.iloc[0:0])
        fit = common_shape_fit(g["distance_km"].to_numpy(float), g["failed"].to_numpy(bool),
                               g["adjustment"].map(GROUP).to_numpy(int))
        ok = fit.note is None and math.isfinite(fit.se_log_ratio) and fit.se_log_ratio > 0
        notes = [fit.note] if fit.note else ([] if ok else ["the fit's information is not positive definite"])
        by_odo = int(((g["distance_from"] == FROM_ODOMETER) & ~g["failed"]).sum())
        if by_odo:
            notes.append(f"{by_odo} censored hose(s) known only by their odometer: distance linear in time "
                         "between installation and end event")
        rows.append({"look": ev["look"], "event_at": ev["event_at"], "hose_id": ev["hose_id"],
                     "failures": int(g["failed"].sum()), "n_hoses": len(g), "total_km": float(g["distance_km"].sum()),
                     "log_ratio": fit.log_ratio if ok else math.nan, "se_log_ratio": fit.se_log_ratio if ok else math.nan,
                     "note": "; ".join(notes) or None})
    return pd.DataFrame(rows, columns=LOOK_COLUMNS)


def decide(estimates: pd.DataFrame, max_failures: int, margin: float, alpha: float,
           spending: str) -> SequentialVerdict | None:
    """The sequential verdict over every look (None without looks).

    Parameters
    ----------
    estimates : DataFrame
        :func:`look_estimates`.
    max_failures : int
        Failures (both adjustments) at which the test ends [-].
    margin : float
        Smallest life ratio worth acting on [-].
    alpha : float
        Two-sided error rate of the verdict [-].
    spending : {"obrien-fleming", "pocock"}
        Lan-DeMets spending family.

    Returns
    -------
    SequentialVerdict or None
        Per look the information fraction ``failures / max_failures`` (capped at 1), the
        boundaries on the log scale, what each look crossed, and the sticky verdict.
    """
    if estimates.empty:
        return None
    t = estimates["failures"].to_numpy(float) / float(max_failures)
    return sequential_verdict(estimates["log_ratio"].to_numpy(float), estimates["se_log_ratio"].to_numpy(float), t,
                              margin, alpha, spending)
