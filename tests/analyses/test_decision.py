"""The looks of the decision: hand-checked hose distances at each failure (runs, a run under way, odometer),
event order and ties, the estimate's NULL notes, recovery of a known life ratio, and the sticky verdict."""
import math
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from analyses.decision import (FROM_ODOMETER, FROM_RUNS, decide, failure_events, look_estimates, look_hoses,
                               usable_hoses)
from analyses.hose_life import hose_distance_at
from analyses.life_effect import common_shape_fit


def T(s):
    ts = pd.Timestamp(s)
    return ts if ts.tzinfo else ts.tz_localize("UTC")


def hose(hid, adj, km, status, source, installed, ended=None):
    return {"hose_id": hid, "adjustment": adj, "distance_km": km, "status": status, "distance_source": source,
            "installed_at": T(installed), "ended_at": T(ended) if ended else pd.NaT}


def frame(rows):
    df = pd.DataFrame(rows)
    for c in ("installed_at", "ended_at"):
        df[c] = pd.to_datetime(df[c], utc=True)
    return df


def runs_of(rows):
    df = pd.DataFrame(rows, columns=["hose_id", "started_at", "duration_h", "distance_km"])
    df["started_at"] = pd.to_datetime(df["started_at"], utc=True)
    return df


@pytest.fixture
def four():
    """D1 (runs, fails 01-03 10:00 at 20 km), F2 (a run under way at D1's failure, fails 01-05 at 10 km),
    D2 (odometer only, 40 km from 01-02 to its failure 01-06), F1 (runs, running at 30 km),
    F3 (installed 01-04, no runs yet), X (failed, no distance: left out)."""
    life = frame([hose("D1", "distance", 20.0, "failed", "runs", "2026-01-01", "2026-01-03T10:00"),
                  hose("F1", "force", 30.0, "running", "runs", "2026-01-01"),
                  hose("D2", "distance", 40.0, "failed", "odometer", "2026-01-02", "2026-01-06"),
                  hose("F2", "force", 10.0, "failed", "runs", "2026-01-03", "2026-01-05"),
                  hose("F3", "force", 0.0, "running", "none", "2026-01-04"),
                  hose("X", "force", math.nan, "failed", "none", "2026-01-01", "2026-01-02")])
    runs = runs_of([("D1", "2026-01-01T00:00", 10.0, 10.0), ("D1", "2026-01-03T00:00", 10.0, 10.0),
                    ("F1", "2026-01-01T00:00", 20.0, 20.0), ("F1", "2026-01-04T00:00", 10.0, 10.0),
                    ("F2", "2026-01-03T05:00", 10.0, 10.0)])
    return life, runs


def test_hand_checked_looks_runs_odometer_and_a_run_under_way(four):
    life, runs = four
    hoses = usable_hoses(life)
    assert list(hoses["hose_id"]) == ["D1", "D2", "F1", "F2", "F3"]          # X: life unknown
    ev = failure_events(hoses)
    assert list(ev["hose_id"]) == ["D1", "F2", "D2"] and list(ev["look"]) == [1, 2, 3]
    got = look_hoses(hoses, runs, ev)
    d = {(r.look, r.hose_id): (r.distance_km, r.failed, r.distance_from) for r in got.itertuples()}
    # look 1, 2026-01-03 10:00: F3 not installed yet
    assert sorted(h for (k, h) in d if k == 1) == ["D1", "D2", "F1", "F2"]
    assert d[1, "D1"] == (20.0, True, FROM_RUNS)
    assert d[1, "F1"] == (20.0, False, FROM_RUNS)                          # second run starts 01-04
    assert d[1, "F2"][0] == pytest.approx(5.0)                             # half of a 10 h run
    assert d[1, "D2"][0] == pytest.approx(40.0 * (1 + 10 / 24) / 4) and d[1, "D2"][2] == FROM_ODOMETER
    # look 2, 2026-01-05: F2 fails at its life, F3 in at 0 km
    assert d[2, "F2"] == (10.0, True, FROM_RUNS) and d[2, "F3"] == (0.0, False, FROM_RUNS)
    assert d[2, "F1"][0] == pytest.approx(30.0) and d[2, "D2"][0] == pytest.approx(30.0)
    assert d[3, "D2"] == (40.0, True, FROM_ODOMETER) and d[3, "D1"] == (20.0, True, FROM_RUNS)
    est = look_estimates(got, ev)
    assert list(est["failures"]) == [1, 2, 3] and list(est["n_hoses"]) == [4, 5, 5]
    assert est["total_km"].iloc[0] == pytest.approx(20 + 20 + 5 + 40 * (1 + 10 / 24) / 4)
    # the data cannot tell: a NULL estimate and the fit's note, never a number
    assert est["log_ratio"].isna().all() and est["se_log_ratio"].isna().all()
    assert est["note"].iloc[0].startswith("too few failures to tell a Weibull")
    assert "odometer" in est["note"].iloc[0] and "odometer" not in est["note"].iloc[2]   # D2 failed by look 3


def test_ties_broken_by_hose_id_and_failed_in_look_order():
    life = frame([hose("B", "force", 5.0, "failed", "odometer", "2026-01-01", "2026-01-02"),
                  hose("A", "distance", 4.0, "failed", "odometer", "2026-01-01", "2026-01-02")])
    ev = failure_events(usable_hoses(life))
    assert list(ev["hose_id"]) == ["A", "B"]
    got = look_hoses(usable_hoses(life), runs_of([]), ev)
    first = got[got["look"] == 1].set_index("hose_id")
    assert first.loc["A", "failed"] and not first.loc["B", "failed"]


def test_runs_distance_is_hose_distance_at_when_no_run_is_under_way():
    """Looks between runs: the runs' distance is hose_distance_at's (a run without a duration counts whole)."""
    runs = runs_of([("H", "2026-01-01T00:00", 2.0, 3.0), ("H", "2026-01-02T00:00", 2.0, 4.0),
                    ("H", "2026-01-03T00:00", math.nan, 5.0)])
    times = ["2026-01-01T12:00", "2026-01-02T12:00", "2026-01-04"]
    life = frame([hose("H", "force", 12.0, "running", "runs", "2026-01-01")]
                 + [hose(f"E{i}", "distance", 1.0, "failed", "odometer", "2025-12-31", w) for i, w in enumerate(times)])
    hoses = usable_hoses(life)
    ev = failure_events(hoses)
    got = look_hoses(hoses, runs, ev)
    h = got[got["hose_id"] == "H"]["distance_km"].to_numpy()
    assert h == pytest.approx([hose_distance_at(runs, T(w)) for w in times])


def test_a_known_ratio_recovered_and_the_last_look_is_the_censored_fit():
    """60 hoses per adjustment start together and run at 1 km/h (one run each, its life long): at each failure
    every hose is at min(life, hours elapsed), and the last look's estimate is the fit of those lives."""
    rng = np.random.default_rng(23)
    n, ratio, shape = 60, 1.5, 2.0
    lives = np.r_[40.0 * rng.weibull(shape, n), 40.0 * ratio * rng.weibull(shape, n)]
    adj = np.r_[["distance"] * n, ["force"] * n]
    end_h = 60.0                                  # test stopped: hoses still alive are running
    start = T("2026-01-01")
    rows, runs = [], []
    for i, (x, a) in enumerate(zip(lives, adj)):
        failed = x < end_h
        km = x if failed else end_h
        rows.append(hose(f"H{i:03d}", a, km, "failed" if failed else "running", "runs", "2026-01-01",
                         start + pd.Timedelta(hours=x) if failed else None))
        runs.append((f"H{i:03d}", start, km, km))
    hoses = usable_hoses(frame(rows))
    ev = failure_events(hoses)
    got = look_hoses(hoses, runs_of(runs), ev)
    k = len(ev) // 2
    at = (ev["event_at"].iloc[k - 1] - start) / pd.Timedelta(hours=1)
    look = got[got["look"] == k].set_index("hose_id")
    expect = {f"H{i:03d}": min(x, at) for i, x in enumerate(lives)}
    assert all(look.loc[h, "distance_km"] == pytest.approx(expect[h]) for h in look.index)
    est = look_estimates(got, ev)
    last = got[got["look"] == len(ev)]
    fit = common_shape_fit(last["distance_km"], last["failed"], (last["adjustment"] == "force").astype(int))
    assert est["log_ratio"].iloc[-1] == pytest.approx(fit.log_ratio)
    assert abs(est["log_ratio"].iloc[-1] - math.log(ratio)) < 3 * est["se_log_ratio"].iloc[-1]
    assert est["se_log_ratio"].iloc[-1] < est["se_log_ratio"].iloc[5]     # information grows with failures


def test_the_verdict_sticks_and_later_looks_are_still_shown():
    est = pd.DataFrame({"failures": [2, 3, 4, 5], "log_ratio": [np.nan, 1.0, 0.0, 0.0],
                        "se_log_ratio": [np.nan, 0.1, 0.5, 0.5]})
    sv = decide(est, 4, margin=1.25, alpha=0.05, spending="pocock")
    assert sv.verdict == "force longer" and sv.decided_at == 1
    assert sv.crossed == ("", "force longer", "", "")
    assert list(sv.information_fraction) == [0.5, 0.75, 1.0, 1.0]   # the fourth look: no new information
    assert decide(est.iloc[0:0], 4, 1.25, 0.05, "pocock") is None
    # frozen at the third look: the first two are read without an estimate (their alpha spent unused)
    late = decide(est.assign(look=[1, 2, 3, 4]), 4, 1.25, 0.05, "pocock", first_look=3)
    assert late.verdict == "undecided" and late.crossed == ("", "", "", "")
    assert late.boundary_z[2] == sv.boundary_z[2] and "2 look(s) without an estimate" in late.note
    # no max_failures yet: every look shown without a boundary, none decides
    none = decide(est, None, 1.25, 0.05, "pocock")
    assert none.verdict == "undecided" and none.decided_at is None and np.isnan(none.boundary_z).all()
    assert np.isnan(none.information_fraction).all() and none.crossed == ("",) * 4


def test_likelihood_check_compares_the_looks_profile_deviance_with_the_boundary():
    """confirm(i, ...) is ratio_deviance of look i's hoses (at 1 for a longer life, at both
    margins for no practical difference) against boundary_z squared: hand-set boundaries just
    below and above the deviance flip it."""
    from analyses.decision import likelihood_check
    from analyses.life_effect import ratio_deviance
    rng = np.random.default_rng(5)
    n = 12
    life = np.concatenate([rng.weibull(2.0, n) * 300.0, rng.weibull(2.0, n) * 100.0])
    failed = np.ones(2 * n, bool)
    failed[[0, n]] = False
    adj = np.array(["force"] * n + ["distance"] * n)
    in_looks = pd.DataFrame({"look": 7, "hose_id": [f"H{i}" for i in range(2 * n)], "adjustment": adj,
                             "distance_km": life, "failed": failed, "distance_from": "runs"})
    est = pd.DataFrame({"look": [7]})
    confirm = likelihood_check(in_looks, est, 1.5, [0.5])
    g = (adj == "force").astype(int)
    dev1 = ratio_deviance(life, failed, g, 1.0)
    assert dev1 > 4.0
    assert confirm(0, "force longer", math.sqrt(dev1) * 0.99)
    assert not confirm(0, "force longer", math.sqrt(dev1) * 1.01)
    devs = [ratio_deviance(life, failed, g, r) for r in (1.5, 1 / 1.5)]
    assert confirm(0, "no practical difference", math.sqrt(min(devs)) * 0.99)
    assert not confirm(0, "no practical difference", math.sqrt(min(devs)) * 1.01)


def test_likelihood_check_stops_at_the_verdict():
    """Once a look with new information is confirmed (the verdict, which sticks), later looks are passed
    unchecked; a confirmed look without new information does not stop the checks, nor does an earlier look
    asked after it."""
    from analyses.decision import likelihood_check
    rng = np.random.default_rng(5)
    n = 12
    life = np.concatenate([rng.weibull(2.0, n) * 300.0, rng.weibull(2.0, n) * 100.0])
    adj = np.array(["force"] * n + ["distance"] * n)
    in_looks = pd.concat([pd.DataFrame({"look": k, "hose_id": [f"H{i}" for i in range(2 * n)], "adjustment": adj,
                                        "distance_km": life, "failed": True, "distance_from": "runs"})
                          for k in (1, 2, 3, 4)], ignore_index=True)
    est = pd.DataFrame({"look": [1, 2, 3, 4]})
    confirm = likelihood_check(in_looks, est, 1.5, [0.5, 0.5, 0.75, 1.0])   # look 2: no new information
    assert not confirm(0, "force longer", 1e3)         # a boundary no deviance reaches: not confirmed
    assert confirm(1, "force longer", 1.0)              # confirmed, but no new information: no verdict yet
    assert not confirm(2, "force longer", 1e3)          # still checked
    assert confirm(2, "force longer", 1.0)              # the verdict (new information)
    assert confirm(3, "force longer", 1e3)              # after it: not checked
    assert not confirm(1, "force longer", 1e3)          # an earlier look is still checked


def _staggered(n_distance=8, n_force=6, seed=2):
    """All hoses installed on day 0, odometer-only; the distance-set ones fail on days 1..n_distance, then the
    force-set ones on the following days; two force-set hoses still running."""
    rng = np.random.default_rng(seed)
    t0 = pd.Timestamp("2026-01-01", tz="UTC")
    rows = [{"hose_id": f"D{i}", "adjustment": "distance", "status": "failed", "ended_at": t0 + pd.Timedelta(days=i + 1)}
            for i in range(n_distance)]
    rows += [{"hose_id": f"F{i}", "adjustment": "force", "status": "failed",
              "ended_at": t0 + pd.Timedelta(days=n_distance + i + 1)} for i in range(n_force)]
    rows += [{"hose_id": f"R{i}", "adjustment": "force", "status": "running", "ended_at": pd.NaT,
              "odometer_at": t0 + pd.Timedelta(days=40)} for i in range(2)]
    life = pd.DataFrame(rows)
    life["distance_km"] = 10.0 * rng.weibull(2.0, len(life)) + 1.0
    life["distance_source"], life["installed_at"] = "odometer", t0
    return usable_hoses(life)


def test_freeze_look_is_the_first_with_half_few_failures_of_each_adjustment_and_later_failures_do_not_move_it():
    from analyses.decision import freeze_look
    from analyses.service_life import reduced_bias_shape
    from analyses.sequential import FEW_FAILURES

    assert FEW_FAILURES / 2 == 5
    runs = pd.DataFrame(columns=["hose_id", "started_at", "duration_h", "distance_km"])
    hoses = _staggered()
    events = failure_events(hoses)
    look, fit, failures = freeze_look(hoses, runs, events)
    assert look == 13 and failures == [8, 5]                  # D0..D7 (looks 1-8), F0..F4 (looks 9-13): hand-checked
    in_looks = look_hoses(hoses, runs, events)
    m = (in_looks["look"] == 13).to_numpy()
    ref = common_shape_fit(in_looks["distance_km"][m].to_numpy(float), in_looks["failed"][m].to_numpy(bool),
                           (in_looks["adjustment"][m] == "force").to_numpy(int))
    # the shape the design reads is the MLE with the reduced-bias adjustment from its 13 failures
    assert fit.shape == pytest.approx(reduced_bias_shape(ref.shape, 13), rel=1e-10) and fit.shape < ref.shape
    assert fit.log_ratio == pytest.approx(ref.log_ratio, rel=1e-9)
    # the night before F5 failed (running then, its odometer read at that time) gives the same look and fit
    early = hoses.copy()
    f5 = (early["hose_id"] == "F5").to_numpy()
    early.loc[f5, "odometer_at"], early.loc[f5, "status"] = early.loc[f5, "ended_at"], "running"
    early.loc[f5, "ended_at"] = pd.NaT
    assert len(failure_events(early)) == len(events) - 1
    again = freeze_look(early, runs, failure_events(early))
    assert again[0] == 13 and again[1].shape == fit.shape and again[2] == [8, 5]
    # four force-set failures: no look qualifies yet
    few = _staggered(n_force=4)
    assert freeze_look(few, runs, failure_events(few)) == (None, None, [8, 4])
    assert freeze_look(few, runs, failure_events(few.iloc[0:0])) == (None, None, [0, 0])


def test_decide_with_the_looks_gives_the_repeated_intervals_of_the_profile_likelihood():
    from analyses.life_effect import ratio_deviance
    from analyses.look_fits import bartlett_factor
    runs = pd.DataFrame(columns=["hose_id", "started_at", "duration_h", "distance_km"])
    hoses = _staggered(n_distance=10, n_force=10)
    events = failure_events(hoses)
    in_looks = look_hoses(hoses, runs, events)
    est = look_estimates(in_looks, events)
    wald = decide(est, 30, 1.25, 0.05, "obrien-fleming", first_look=13)
    sv = decide(est, 30, 1.25, 0.05, "obrien-fleming", in_looks, first_look=13)
    has = np.isfinite(wald.rci_lower)
    assert has.sum() >= 3 and not has[:12].any()
    assert np.array_equal(np.isfinite(sv.rci_lower), has) and np.array_equal(np.isfinite(sv.rci_upper), has)
    for i in np.flatnonzero(has):
        m = (in_looks["look"] == est["look"].iloc[i]).to_numpy()
        x, f = in_looks["distance_km"][m].to_numpy(float), in_looks["failed"][m].to_numpy(bool)
        g = (in_looks["adjustment"][m] == "force").to_numpy(int)
        b = float(bartlett_factor(f.sum()))
        for bound in (sv.rci_lower[i], sv.rci_upper[i]):      # where the deviance reaches b_k c_k^2
            assert ratio_deviance(x, f, g, math.exp(bound)) == pytest.approx(b * sv.boundary_z[i] ** 2, abs=1e-6)
        assert sv.rci_lower[i] < est["log_ratio"].iloc[i] < sv.rci_upper[i]
    assert not np.allclose(sv.rci_lower[has], wald.rci_lower[has])      # not the Wald interval
    for name in ("boundary_z", "efficacy_lower", "efficacy_upper", "futility_lower", "information_fraction"):
        assert np.array_equal(getattr(sv, name), getattr(wald, name), equal_nan=True)   # only the intervals change
    assert "does not close" not in sv.note


def test_an_interval_the_profile_likelihood_does_not_close_is_null_with_a_note():
    """Two failures an adjustment, at a boundary of 6: the deviance stays below 36 up to the search edge."""
    from analyses.decision import profile_intervals
    from analyses.sequential import sequential_verdict
    x = [1.0, 2.0, 3.0, 5.0, 1.5, 2.5, 9.0, 9.0]
    in_looks = pd.DataFrame({"look": 1, "distance_km": x, "failed": [1, 1, 0, 0, 1, 1, 0, 0],
                             "adjustment": ["distance"] * 4 + ["force"] * 4}).astype({"failed": bool})
    fit = common_shape_fit(in_looks["distance_km"], in_looks["failed"], (in_looks["adjustment"] == "force").astype(int))
    est = pd.DataFrame({"look": [1], "log_ratio": [fit.log_ratio], "se_log_ratio": [fit.se_log_ratio]})
    sv = sequential_verdict([fit.log_ratio], [fit.se_log_ratio], [1.0], 1.25, 0.05)
    assert np.isfinite(sv.rci_lower).all()
    wide = profile_intervals(replace(sv, boundary_z=np.array([6.0])), in_looks, est)
    assert np.isnan(wide.rci_lower).all() and np.isnan(wide.rci_upper).all()
    assert "1 look(s) whose repeated interval the profile likelihood does not close" in wide.note
    narrow = profile_intervals(replace(sv, boundary_z=np.array([1.0])), in_looks, est)
    assert narrow.rci_lower[0] < fit.log_ratio < narrow.rci_upper[0] and "repeated interval" not in narrow.note


def test_the_looks_fits_solved_once_are_those_each_reader_solves_bit_for_bit():
    """look_fits_of's fits, passed to freeze_look, look_estimates and decide (the profile intervals), give
    exactly what each solves on its own: each look's fit is its own, whatever the other looks."""
    from analyses.decision import freeze_look, look_fits_of

    runs = pd.DataFrame(columns=["hose_id", "started_at", "duration_h", "distance_km"])
    hoses = _staggered(n_distance=10, n_force=10)
    events = failure_events(hoses)
    in_looks = look_hoses(hoses, runs, events)
    fits = look_fits_of(in_looks, events)
    assert len(fits) == len(events) and fits[0].note and fits[-1].note is None   # the first looks: too few
    alone = freeze_look(hoses, runs, events, in_looks)
    shared = freeze_look(hoses, runs, events, in_looks, fits)
    assert alone[0] == shared[0] == 15 and alone[2] == shared[2] == [10, 5]
    assert alone[1].shape == shared[1].shape and alone[1].log_ratio == shared[1].log_ratio
    est = look_estimates(in_looks, events)
    pd.testing.assert_frame_equal(look_estimates(in_looks, events, fits), est, check_exact=True)
    a = decide(est, 30, 1.25, 0.05, "obrien-fleming", in_looks, first_look=13)
    b = decide(est, 30, 1.25, 0.05, "obrien-fleming", in_looks, first_look=13, fits=fits)
    assert np.isfinite(a.rci_lower).sum() >= 3
    for name in ("rci_lower", "rci_upper", "boundary_z"):
        assert np.array_equal(getattr(a, name), getattr(b, name), equal_nan=True)
    assert a.note == b.note and a.verdict == b.verdict


def test_look_estimates_without_looks_and_of_a_look_without_event_keep_their_types():
    """The frame built from columns types them as the rows did: no look -> no rows, every column untyped;
    a look given without its event (the remaining-life stage's) -> event_at and hose_id untyped."""
    from analyses.decision import LOOK_COLUMNS

    runs = pd.DataFrame(columns=["hose_id", "started_at", "duration_h", "distance_km"])
    hoses = _staggered()
    in_looks = look_hoses(hoses, runs, failure_events(hoses))
    none = look_estimates(in_looks.iloc[0:0], failure_events(hoses).iloc[0:0])
    assert list(none.columns) == LOOK_COLUMNS and none.empty and set(none.dtypes) == {np.dtype(object)}
    one = look_estimates(in_looks, pd.DataFrame({"look": [13], "event_at": [None], "hose_id": [None]}))
    assert one["event_at"].dtype == object and one["hose_id"].dtype == object and one["look"].dtype == np.int64
    assert one["failures"].tolist() == [13] and math.isfinite(one["log_ratio"].iloc[0])
