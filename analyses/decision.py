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
  ``log_ratio`` and its standard error, NaN with a note where the data cannot tell; all looks
  are solved at once (:func:`analyses.look_fits.look_fits`: each look's own score equation,
  vectorised over padded (look, hose) matrices, the same unique root to 1e-13): one solve a hose
  type, not one a failure;
* :func:`decide`: the sequential verdict over all looks
  (:func:`analyses.sequential.sequential_verdict`: Lan & DeMets 1983 alpha spending, repeated
  confidence intervals, a verdict that sticks) at ``information_fraction = failures /
  max_failures``; the likelihood check (:func:`likelihood_check`) confirms the Wald crossings up
  to the verdict, not after it (a later look cannot change a verdict that sticks); the repeated
  confidence intervals shown are the profile likelihood's, ``{log ratio : deviance <= b_k c_k^2}``
  (:func:`profile_intervals`, J&T ch. 9 with the likelihood ratio for the Wald statistic);
* :func:`freeze_look`: when the plan leaves ``max_failures`` unset, the look at which it is
  frozen (the first with ``FEW_FAILURES / 2`` failures of each adjustment and a common shape),
  whose own fit designs it, its shape with Abernethy's reduced-bias adjustment (Abernethy 2006,
  sec. 5.5); :func:`decide` reads the looks before it as looks without an estimate
  (their alpha spent unused: Jennison & Turnbull 2000, sec. 7.2 and ch. 14, the internal pilot;
  Mehta & Tsiatis 2001), and without a frozen maximum no look decides.

Decisions
---------
* Hoses whose life is unknown (a failed or removed hose without runs or odometer reading) are
  left out: their failure is no look (the ``life_effect`` fit leaves them out too, so the last
  look's failures are that fit's).
* A hose known only by its odometer without an end event (a running hose whose reading came from
  an earlier installation, e.g. read in a pause of its test) is interpolated over installation ..
  the reading's time (``hose_life.odometer_at``) and held at the reading after it: the last
  distance known, a suspension there (the ``life_effect`` fit counts it at that distance too, so
  the last look is that fit's). Without a reading time it has no span: it is left out of the
  looks (its count is returned for the note).
* The times of a reinstalled hose's gap are not known to :mod:`analyses.hose_life`'s table: an
  odometer hose is interpolated over first installation .. last end.

References
----------
Meeker, W. Q. & Escobar, L. A. (1998). Statistical Methods for Reliability Data. Wiley.
Jennison, C. & Turnbull, B. W. (2000). Group Sequential Methods with Applications to Clinical
Trials. Chapman & Hall/CRC.
Lan, K. K. G. & DeMets, D. L. (1983). Discrete sequential boundaries for clinical trials.
Biometrika 70, 659-663.
Abernethy, R. B. (2006). The New Weibull Handbook, 5th ed. Abernethy, North Palm Beach.
Mehta, C. R. & Tsiatis, A. A. (2001). Flexible sample size considerations using information-based
interim monitoring. Drug Information Journal 35, 1095-1112.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pandas as pd

from analyses.life_effect import ratio_deviance
from analyses.look_fits import bartlett_factor, look_fits, profile_rci
from analyses.sequential import FEW_FAILURES, SequentialVerdict, sequential_verdict
from analyses.service_life import reduced_bias_shape

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
    """UTC times as int64 nanoseconds (NaT -> the minimum int64); times already typed are not parsed again."""
    s = values if isinstance(values, pd.Series) else pd.Series(values)
    if not (isinstance(s.dtype, pd.DatetimeTZDtype) or s.dtype.kind == "M"):
        s = pd.to_datetime(s, utc=True, format="ISO8601")
    return s.to_numpy("datetime64[ns]").astype(np.int64)


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
    d = pd.to_numeric(life["distance_km"], errors="coerce").to_numpy(float)
    adjustment = life["adjustment"].to_numpy(object)
    ok = ~np.isnan(d) & (d >= 0) & np.isin(adjustment, list(GROUP))
    # an odometer hose's interpolation ends at its end event, or while it runs at its reading's time (odometer_at;
    # held at that reading after it, the last distance known: a suspension there): without either, no span
    read_at = life["ended_at"].isna().to_numpy()
    if "odometer_at" in life:
        read_at = read_at & life["odometer_at"].isna().to_numpy()
    ok &= life["installed_at"].notna().to_numpy() & ~((life["distance_source"].to_numpy(object) == "odometer")
                                                      & read_at)
    kept = np.flatnonzero(ok)
    ids = life["hose_id"].to_numpy(object)[kept]
    order = sorted(range(kept.size), key=lambda i: (not isinstance(ids[i], str), str(ids[i])))   # as sort_values
    return life.iloc[kept[order]].reset_index(drop=True)


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
    ok = ((hoses["status"].to_numpy(object) == "failed") & (pd.to_numeric(hoses["distance_km"]).to_numpy(float) > 0)
          & hoses["ended_at"].notna().to_numpy())
    rows = np.flatnonzero(ok)
    t, ids = _ns(hoses["ended_at"].iloc[rows]).tolist(), hoses["hose_id"].to_numpy(object)[rows].tolist()
    order = rows[sorted(range(len(ids)), key=lambda i: (t[i], ids[i]))]
    return pd.DataFrame({"look": np.arange(1, len(ids) + 1, dtype=np.int64),
                         "hose_id": hoses["hose_id"].iloc[order].reset_index(drop=True),
                         "event_at": hoses["ended_at"].iloc[order].reset_index(drop=True)})


def _run_fractions(starts, durations_h, t: np.ndarray) -> np.ndarray:
    """Per run (rows) and time ``t`` [ns] (columns), the fraction of the run done by then."""
    s = _ns(starts).astype(np.float64)
    dur = pd.to_numeric(pd.Series(durations_h), errors="coerce").to_numpy(float) * 3.6e12
    elapsed = t.astype(np.float64)[None, :] - s[:, None]
    timed = np.isfinite(dur) & (dur > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(timed[:, None], np.clip(elapsed / np.where(timed, dur, 1.0)[:, None], 0.0, 1.0),
                        (elapsed > 0).astype(float))


def _odometer_at(installed: np.ndarray, ended: np.ndarray, km: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Distance [km] of odometer-only hoses (rows) at times ``t`` [ns] (columns), linear between
    installation and end event (a step at the end when they coincide)."""
    span = (ended - installed).astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = np.clip((t[None, :] - installed[:, None].astype(np.float64)) / span[:, None], 0.0, 1.0)
    frac = np.where((span > 0)[:, None], frac, (t[None, :] >= ended[:, None]).astype(float))
    return km[:, None] * frac


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
    if hoses.empty or events.empty:
        return pd.DataFrame(columns=LOOK_HOSE_COLUMNS)
    t = _ns(events["event_at"])
    ids = hoses["hose_id"].to_numpy(object)
    km = pd.to_numeric(hoses["distance_km"]).to_numpy(float)
    installed, ended = _ns(hoses["installed_at"]), _ns(hoses["ended_at"])
    if "odometer_at" in hoses:                  # a running hose's reading time (usable_hoses); NaT is int64's least
        ended = np.where(ended != np.iinfo(np.int64).min, ended, _ns(hoses["odometer_at"]))
    odometer = (hoses["distance_source"] == "odometer").to_numpy()
    dist = np.zeros((len(ids), t.size))
    index = {h: i for i, h in enumerate(ids)}
    run_of = [index.get(h, -1) for h in runs["hose_id"].tolist()] if len(runs) else []
    mine = np.flatnonzero(np.asarray(run_of, dtype=np.int64) >= 0)     # the runs of these hoses
    if mine.size:
        frac = _run_fractions(runs["started_at"].iloc[mine], runs["duration_h"].iloc[mine], t)
        kms = np.nan_to_num(pd.to_numeric(runs["distance_km"].iloc[mine], errors="coerce").to_numpy(float))
        np.add.at(dist, np.asarray(run_of, dtype=np.int64)[mine], kms[:, None] * frac)
    if odometer.any():
        dist[odometer] = _odometer_at(installed[odometer], ended[odometer], km[odometer], t.astype(np.float64))
    look_of = dict(zip(events["hose_id"].tolist(), events["look"].tolist()))
    rank = np.array([look_of.get(h, t.size + 1) for h in ids], dtype=int)
    failed = np.arange(1, t.size + 1)[None, :] >= rank[:, None]
    dist = np.where(failed, km[:, None], dist)
    keep = t[None, :] >= installed[:, None]
    look_ix, hose_ix = np.nonzero(keep.T)                       # by look, then by hose (hoses sorted by id)
    text = {"hose_id": ids[hose_ix], "adjustment": hoses["adjustment"].to_numpy(object)[hose_ix],
            "distance_from": np.where(odometer[hose_ix], FROM_ODOMETER, FROM_RUNS).astype(object)}
    text = {c: pd.Series(v, dtype=object) for c, v in text.items()}      # object: no string inference per look
    return pd.DataFrame({"look": events["look"].to_numpy()[look_ix], "hose_id": text["hose_id"],
                         "adjustment": text["adjustment"], "distance_km": dist[hose_ix, look_ix],
                         "failed": failed[hose_ix, look_ix], "distance_from": text["distance_from"]})


def look_estimates(in_looks: pd.DataFrame, events: pd.DataFrame, fits: list | None = None) -> pd.DataFrame:
    """The estimate at each look: the common-shape life ratio and its standard error.

    Parameters
    ----------
    in_looks : DataFrame
        :func:`look_hoses`.
    events : DataFrame
        :func:`failure_events`.
    fits : list of CommonShapeFit, optional
        :func:`analyses.look_fits.look_fits` of ``in_looks`` at every look of ``events`` (in that order) when
        the caller has them already (:func:`look_fits_of`): not solved again.

    Returns
    -------
    DataFrame
        Per look: ``look``, ``event_at``, ``hose_id`` (the hose that failed), ``failures``,
        ``n_hoses`` (in the look), ``total_km`` [km] (their distances summed), ``log_ratio`` [-]
        (ln force / distance life), ``se_log_ratio`` [-], ``note`` (why the estimate is NaN, and
        the hoses placed by odometer).
    """
    look = in_looks["look"].to_numpy(np.int64)
    x = in_looks["distance_km"].to_numpy(float)
    f = in_looks["failed"].to_numpy(bool)
    g = (in_looks["adjustment"] == "force").to_numpy(int)
    odo = (in_looks["distance_from"] == FROM_ODOMETER).to_numpy() & ~f
    numbers = events["look"].to_numpy(np.int64)
    if fits is None:
        fits = look_fits(x, f, g, look, numbers)       # every look's fit in one solve
    order = np.argsort(look, kind="stable")             # in_looks is by look already: then the identity
    sorted_look = look[order]
    starts, ends = np.searchsorted(sorted_look, numbers, "left"), np.searchsorted(sorted_look, numbers, "right")
    cols = {c: [] for c in ("failures", "n_hoses", "total_km", "log_ratio", "se_log_ratio", "note")}
    for fit, a, b in zip(fits, starts.tolist(), ends.tolist()):
        m = order[a:b]
        ok = fit.note is None and math.isfinite(fit.se_log_ratio) and fit.se_log_ratio > 0
        notes = [fit.note] if fit.note else ([] if ok else ["the fit's information is not positive definite"])
        by_odo = int(odo[m].sum())
        if by_odo:
            notes.append(f"{by_odo} censored hose(s) known only by their odometer: distance linear in time "
                         "between installation and end event")
        for c, v in (("failures", int(f[m].sum())), ("n_hoses", int(b - a)), ("total_km", float(x[m].sum())),
                     ("log_ratio", fit.log_ratio if ok else math.nan),
                     ("se_log_ratio", fit.se_log_ratio if ok else math.nan), ("note", "; ".join(notes) or None)):
            cols[c].append(v)
    # the frame built from its columns, each typed as a frame of rows would type it (a row at a time: 2x the time)
    if not numbers.size:
        return pd.DataFrame([], columns=LOOK_COLUMNS)
    out = pd.DataFrame({"look": numbers.tolist(), "event_at": list(events["event_at"]),
                        "hose_id": events["hose_id"].tolist(), **cols}, columns=LOOK_COLUMNS)
    return out


def look_fits_of(in_looks: pd.DataFrame, events: pd.DataFrame) -> list:
    """:func:`analyses.look_fits.look_fits` of every look of ``events`` (in that order) on :func:`look_hoses`
    ``in_looks``: each look is solved alone (its own score equation, whatever the other looks), so these are
    the fits :func:`look_estimates`, :func:`freeze_look` and :func:`profile_intervals` would solve again,
    bit for bit; a caller needing more than one of them solves them once and passes them on.

    Parameters
    ----------
    in_looks : DataFrame
        :func:`look_hoses`.
    events : DataFrame
        :func:`failure_events`.

    Returns
    -------
    list of CommonShapeFit
        One per look of ``events``.
    """
    return look_fits(in_looks["distance_km"].to_numpy(float), in_looks["failed"].to_numpy(bool),
                     (in_looks["adjustment"] == "force").to_numpy(int), in_looks["look"].to_numpy(np.int64),
                     events["look"].to_numpy(np.int64))


def likelihood_check(in_looks: pd.DataFrame, estimates: pd.DataFrame, margin: float, information_fraction,
                     deviance=ratio_deviance):
    """``confirm`` of :func:`analyses.sequential.sequential_verdict`: a look that crossed on the
    Wald scale crosses only if the common-shape profile likelihood agrees, i.e. its deviance
    (:func:`analyses.life_effect.ratio_deviance`) at ratio 1 (a longer life) or at both margins
    (no practical difference) exceeds ``boundary_z ** 2``: the profile likelihood confirming the
    Wald approximation (Meeker & Escobar 1998, sec. 8.3: likelihood intervals hold better in small
    samples; with the shape refitted the Wald interval is too narrow). Uncorrected by the Bartlett
    factor the shown intervals carry (:func:`profile_intervals`): with it the verdict's power at the
    margin fell to 0.733 (docs/decision.md, "Repeated confidence intervals, calibrated").

    Only the looks up to the verdict are checked: once a look with new information is confirmed
    (it declares the verdict, which sticks), a later look's crossing cannot change it and is
    passed unchecked (its ``crossed`` is the Wald crossing; the stage's note says so).

    Parameters
    ----------
    in_looks : DataFrame
        :func:`look_hoses`.
    estimates : DataFrame
        :func:`look_estimates` (its ``look`` numbers index ``in_looks``).
    margin : float
        Smallest life ratio worth acting on [-].
    information_fraction : array_like
        Per look ``failures / max_failures`` [-] as the verdict reads it: a look decides only when
        its fraction is above every earlier one (:func:`analyses.sequential.sequential_verdict`).
    deviance : callable, optional
        ``deviance(life, failed, group, ratio)``: the profile deviance of the life model the
        estimates come from (the common-shape Weibull's by default;
        :func:`analyses.life_effect_lognormal.lognormal_ratio_deviance` for a lognormal one).

    Returns
    -------
    callable
        ``confirm(index, crossed, boundary_z) -> bool``.
    """
    look = in_looks["look"].to_numpy(int)
    x = in_looks["distance_km"].to_numpy(float)
    f = in_looks["failed"].to_numpy(bool)
    g = (in_looks["adjustment"] == "force").to_numpy(int)
    numbers = estimates["look"].to_numpy(int)
    m_ratio = max(margin, 1.0 / margin)
    t = np.minimum(np.asarray(information_fraction, float), 1.0)
    new = t > np.concatenate([[0.0], np.maximum.accumulate(t)[:-1]])
    decided = math.inf                        # the earliest look known to declare the verdict

    def confirm(i: int, crossed: str, boundary_z: float) -> bool:
        nonlocal decided
        if i > decided:
            return True                       # after the verdict: not checked
        m = look == numbers[i]
        holds = crossing_holds(lambda r: deviance(x[m], f[m], g[m], r), crossed, boundary_z, m_ratio)
        if holds and new[i]:
            decided = min(decided, i)
        return holds

    return confirm


def crossing_holds(deviance, crossed: str, boundary_z: float, margin: float) -> bool:
    """The likelihood check's rule for one look: the profile deviance ``deviance(ratio)`` [-]
    above ``boundary_z ** 2`` at ratio 1 for a longer life, at both ``margin`` and
    ``1 / margin`` for ``no practical difference``."""
    margin = max(margin, 1.0 / margin)
    trials = (margin, 1.0 / margin) if crossed == "no practical difference" else (1.0,)
    return all(deviance(r) > boundary_z ** 2 for r in trials)


def freeze_look(hoses: pd.DataFrame, runs: pd.DataFrame, events: pd.DataFrame, in_looks: pd.DataFrame | None = None,
                fits: list | None = None):
    """The look at which a ``max_failures`` the plan leaves unset is frozen, and that look's fit.

    The first look at which each adjustment has at least ``FEW_FAILURES / 2`` failures
    (:data:`analyses.sequential.FEW_FAILURES`: the shape then rests on 10 or more) and whose
    common-shape fit (:func:`look_fits`) has a shape: a function of the data up to that look
    only, so the same raw/ gives the same look and fit whatever later failures came (the maximum
    is re-estimated once, on the nuisance shape, never on the effect: Mehta & Tsiatis 2001;
    Jennison & Turnbull 2000, ch. 14).

    Parameters
    ----------
    hoses, runs, events : DataFrame
        :func:`usable_hoses`, their matched runs and :func:`failure_events` (as :func:`look_hoses`).
    in_looks : DataFrame, optional
        :func:`look_hoses` of all of ``events`` when the caller has it: its rows up to a look are
        those of the looks up to it computed alone (each look's column is computed by itself), so
        they are read instead of computed again.
    fits : list of CommonShapeFit, optional
        :func:`look_fits_of` ``in_looks`` and ``events`` when the caller has them: each look's fit is its
        own (the same as fitted on the looks up to it), read instead of solved again.

    Returns
    -------
    look : int or None
        The look's number (None: no look qualifies yet).
    fit : CommonShapeFit or None
        Its common-shape fit, the shape bias-adjusted for the design
        (:func:`analyses.service_life.reduced_bias_shape` from that look's failures: the MLE from
        10-odd failures is biased steep, and a steep shape designs a short test); the other fields
        are the MLE's.
    failures : list of int
        Failures of the distance-set and force-set hoses by that look (by the last look when None).
    """
    if events.empty:
        return None, None, [0, 0]
    adjustment = dict(zip(hoses["hose_id"].tolist(), hoses["adjustment"].tolist()))
    g = np.array([adjustment.get(h) for h in events["hose_id"].tolist()], dtype=object)
    counts = np.stack([np.cumsum(g == a) for a in GROUP])        # (distance, force) x looks
    ready = np.flatnonzero(counts.min(axis=0) >= FEW_FAILURES / 2)
    for upto in (ready[:1], ready):     # the first ready look alone; all of them when its fit cannot tell
        if not upto.size:
            break
        last = int(events["look"].iloc[int(upto[-1])])
        if fits is not None:
            upto_fits = [fits[i] for i in upto.tolist()]
        elif in_looks is None:
            upto_looks = look_hoses(hoses, runs, events.iloc[:int(upto[-1]) + 1])
        else:
            upto_looks = in_looks[in_looks["look"].to_numpy(np.int64) <= last]
        if fits is None:
            upto_fits = look_fits(upto_looks["distance_km"].to_numpy(float), upto_looks["failed"].to_numpy(bool),
                                  (upto_looks["adjustment"] == "force").to_numpy(int),
                                  upto_looks["look"].to_numpy(np.int64), events["look"].to_numpy(np.int64)[upto])
        for i, fit in zip(upto.tolist(), upto_fits):
            if fit.note is None and math.isfinite(fit.shape):
                failures = [int(c) for c in counts[:, i]]
                return int(events["look"].iloc[i]), replace(fit, shape=reduced_bias_shape(fit.shape, sum(failures))), \
                    failures
    return None, None, [int(c) for c in counts[:, -1]]


def _no_maximum(n: int) -> SequentialVerdict:
    """The verdict of ``n`` looks read without a ``max_failures``: no boundary, none decides."""
    nan = np.full(n, math.nan)
    return SequentialVerdict(verdict="undecided", decided_at=None, information_fraction=nan, alpha_spent=nan,
                             boundary_z=nan, efficacy_lower=nan, efficacy_upper=nan, futility_lower=nan,
                             futility_upper=nan, rci_lower=nan, rci_upper=nan, crossed=("",) * n,
                             note="no max_failures yet: no look decides")


def decide(estimates: pd.DataFrame, max_failures: int | None, margin: float, alpha: float,
           spending: str, in_looks: pd.DataFrame | None = None, first_look: int = 1,
           deviance=ratio_deviance, fits: list | None = None) -> SequentialVerdict | None:
    """The sequential verdict over every look (None without looks).

    Parameters
    ----------
    estimates : DataFrame
        :func:`look_estimates`.
    max_failures : int or None
        Failures (both adjustments) at which the test ends [-]; None (not frozen yet,
        :func:`freeze_look`): every look is shown without boundaries and none decides.
    margin : float
        Smallest life ratio worth acting on [-].
    alpha : float
        Two-sided error rate of the verdict [-].
    spending : {"obrien-fleming", "pocock"}
        Lan-DeMets spending family.
    in_looks : DataFrame, optional
        :func:`look_hoses`: given, a look up to the verdict crosses only when the profile
        likelihood agrees with the Wald statistic (:func:`likelihood_check`); a later look's
        ``crossed`` is its Wald crossing, unchecked; and the repeated confidence intervals are the
        profile likelihood's (:func:`profile_intervals`) when ``deviance`` is the common-shape
        Weibull's. Without it, or for another model's deviance (the lognormal's, read at one look by
        the remaining-life stage, which shows no interval: its profile searched look by look costs
        seconds), they are the Wald intervals of :func:`analyses.sequential.sequential_verdict`.
    first_look : int, optional
        The first look that may decide (the look ``max_failures`` was frozen at): the looks before
        it are read as looks without an estimate, their alpha spent unused (conservative).
    deviance : callable, optional
        The likelihood check's profile deviance (:func:`likelihood_check`): the model of ``estimates``.
    fits : list of CommonShapeFit, optional
        :func:`look_fits_of` ``in_looks`` at every look of ``estimates`` when the caller has them: the
        profile intervals read them instead of solving the looks again (:func:`profile_intervals`).

    Returns
    -------
    SequentialVerdict or None
        Per look the information fraction ``failures / max_failures`` (capped at 1), the
        boundaries on the log scale, what each look crossed, and the sticky verdict.
    """
    if estimates.empty:
        return None
    if max_failures is None:
        return _no_maximum(len(estimates))
    t = estimates["failures"].to_numpy(float) / float(max_failures)
    confirm = likelihood_check(in_looks, estimates, margin, t, deviance) if in_looks is not None else None
    est, se = (estimates[c].to_numpy(float) for c in ("log_ratio", "se_log_ratio"))
    if first_look > 1:
        early = estimates["look"].to_numpy(np.int64) < first_look
        est, se = np.where(early, math.nan, est), np.where(early, math.nan, se)
    verdict = sequential_verdict(est, se, t, margin, alpha, spending, confirm=confirm)
    return verdict if in_looks is None or deviance is not ratio_deviance else profile_intervals(verdict, in_looks,
                                                                                              estimates, fits)


def profile_intervals(verdict: SequentialVerdict, in_looks: pd.DataFrame, estimates: pd.DataFrame,
                      fits: list | None = None) -> SequentialVerdict:
    """``verdict`` with its repeated confidence intervals taken from the profile likelihood.

    At each look that has a Wald interval ``log_ratio -/+ c_k se`` (an estimate and a boundary), the
    interval ``{log ratio : profile deviance <= b_k c_k^2}`` (:func:`analyses.look_fits.profile_rci`;
    Jennison & Turnbull 2000, ch. 9), ``b_k`` the Bartlett factor of the look's failures
    (:func:`analyses.look_fits.bartlett_factor`: the deviance's mean at the true ratio): the Wald one
    is too narrow with few failures and the shape refitted, and the uncorrected deviance's excess over
    chi-square(1), compounded over a look at every failure, made the intervals miss the true ratio
    more often than ``alpha`` (docs/decision.md, "Repeated confidence intervals, calibrated"). The
    verdict's crossings (:func:`likelihood_check`) keep ``c_k^2``, calibrated by their own error rates;
    where the deciding look's interval does not exclude what it decided, the note says so.
    An end the deviance does not reach within the search edge is NaN, and the verdict's note says
    how many looks have one.

    Parameters
    ----------
    verdict : SequentialVerdict
        :func:`analyses.sequential.sequential_verdict` over ``estimates``.
    in_looks, estimates : DataFrame
        :func:`look_hoses` and :func:`look_estimates` (``estimates`` one row a look of ``verdict``; the
        common-shape Weibull's estimates).
    fits : list of CommonShapeFit, optional
        :func:`look_fits_of` at every look of ``estimates`` (read, not solved again).

    Returns
    -------
    SequentialVerdict
        ``rci_lower`` / ``rci_upper`` [-] (log scale) replaced, everything else as given.
    """
    lo, hi = np.full(len(estimates), math.nan), np.full(len(estimates), math.nan)
    need = np.flatnonzero(np.isfinite(verdict.rci_lower) & np.isfinite(verdict.rci_upper))
    if need.size:
        look, failed = in_looks["look"].to_numpy(np.int64), in_looks["failed"].to_numpy(bool)
        numbers = estimates["look"].to_numpy(np.int64)[need]
        failures = np.array([failed[look == n].sum() for n in numbers.tolist()])
        lo[need], hi[need] = profile_rci(in_looks["distance_km"].to_numpy(float), failed,
                                         (in_looks["adjustment"] == "force").to_numpy(int), look, numbers,
                                         verdict.boundary_z[need] * np.sqrt(bartlett_factor(failures)),
                                         fits=None if fits is None else [fits[i] for i in need.tolist()])
    open_ = int((~(np.isfinite(lo[need]) & np.isfinite(hi[need]))).sum())
    note = verdict.note
    if verdict.decided_at is not None and not _interval_says(verdict.verdict, lo[verdict.decided_at],
                                                              hi[verdict.decided_at]):
        note = "; ".join(n for n in (note, "the deciding look's repeated interval (Bartlett-corrected) does not "
                                           f"show '{verdict.verdict}' on its own") if n)
    if open_:
        note = "; ".join(n for n in (note, f"{open_} look(s) whose repeated interval the profile likelihood does "
                                           "not close within the search edge (NULL on that side)") if n)
    return replace(verdict, rci_lower=lo, rci_upper=hi, note=note)


def _interval_says(verdict: str, lower: float, upper: float) -> bool:
    """Whether a repeated interval ``lower .. upper`` [-] (log scale) shows a longer life by itself: above 0
    for ``force longer``, below for ``distance longer`` (``no practical difference``: not judged here)."""
    if verdict == "force longer":
        return bool(lower > 0)
    if verdict == "distance longer":
        return bool(upper < 0)
    return True
