"""Friction from any motion record: inverse-dynamics least squares (IDIM-LS).

The pass method (:mod:`analyses.viscous_friction`) needs stretches of constant velocity. A
record of any motion (passes, ramps, a trapezoid at one speed, a sine) also carries the
friction, through the carriage's equation of motion (Gautier; Janot et al., IDIM-LS)::

    F_drive = M a + Fv v + Fc tanh(v / vs) + offset

with ``F_drive`` the drive force toward +x (``(p_a - p_b) A``, or the load-cell channel ``f``
when the rig states its force balance so), ``M`` the moving mass [kg], ``Fv`` the viscous
coefficient [N s/m], ``Fc`` the Coulomb level [N] and ``offset`` a constant force [N] (a
load-cell zero, a pressure-sensor offset, gravity on an inclined rig).

Method (:func:`friction_dynamic`)
---------------------------------
1. *Cut-off from the data.* The position's power spectrum is compared with its sensor's noise
   floor (white noise ``s^2 + res^2 / 12`` spread over ``fs / 2``); the cut-off is the highest
   frequency at which the motion stands :data:`SNR_MIN` above that floor (at most ``fs / 5``).
   Above it a derivative would be noise.
2. *Zero-phase low-pass, in parallel.* Position and drive force go through the same
   Butterworth filter forwards and backwards (``sosfiltfilt``, no delay); velocity and
   acceleration are central differences of the filtered position. Because the force is filtered
   exactly like the position, the linear terms hold on the filtered signals (parallel
   filtering); the nonlinear Coulomb column is computed from the filtered velocity and then
   filtered again, like the force. Its sign is read from a velocity filtered at
   :data:`SIGN_CUTOFF_FACTOR` times the cut-off (at most ``fs / 4``): at the cut-off itself the
   motion's top frequencies are attenuated, which moves the zero crossings of the
   velocity -- and the Coulomb steps with them -- against the force's (on a multi-sine record this
   showed as a 0.7 ms lag of a force that had none, and Coulomb 13 % low).
3. *Parallel decimation.* Filtered columns and force are kept every ``r``-th sample, ``r`` such
   that the decimated Nyquist frequency is twice the cut-off: neighbouring rows are then
   nearly independent, as least-squares standard errors assume.
4. *Rows.* Samples slower than the filtered velocity's noise (:data:`V_MIN_N_SIGMA` sigmas, and
   at least :data:`V_MIN_REL` of the fastest speed; at rest friction is static and the model
   does not apply) are left out, with a guard of :data:`GUARD_PERIODS` filter periods around
   them (the filtered force there still carries the force at rest), and so are the filter's
   edges.
5. *Least squares* on ``[a, v, sign(v), 1]`` (rows slower than the velocity noise are out, so
   the tanh transition, well under a millimetre per second on the PLPA, is a sign). Standard
   errors ``sigma^2 (X'X)^-1`` and the scaled condition number come from
   :func:`analyses.quality.linear_lstsq`.
6. *Cut-off lowered for the mass.* From the noise-floor cut-off down, the first cut-off at which
   the filtered acceleration's noise is under :data:`EIV_MAX` of its variance is used (noise in
   a regressor biases its coefficient toward zero by that fraction); if none is, the mass is
   not reported.
7. *Lag of the force* (``lag_s``, positive when the force lags the motion, negative when it leads;
   ``lag_se_s``). A force logged ``tau`` late is ``F(t - tau) ~ F - tau dF/dt``: the time derivative
   of the fitted model, added as a column, estimates the lag with its standard error; the filtered
   force is then shifted by the estimate (cubic spline through the band-limited filtered force, a
   fractional delay) and the step repeated until it is under 1 % of its standard error (Gauss-Newton
   on the lag). A lag within :data:`LAG_MAX_SAMPLES` sample period -- channels scanned one after
   another, a position read a little late -- is within the sampling: when significant (over
   :data:`LAG_N_SE` standard errors) every parameter is taken from the compensated fit, provided,
   for a force that lags, that the form of the lag cannot move the mass beyond its standard error
   (a delay and any other lag of the same delay agree to first order in ``w tau`` and differ at
   the next: at most ``|dM| w_c tau / 2``, ``dM`` the mass change of the compensation, ``w_c``
   the cut-off). A force that leads is timing, not the force's dynamics (nothing causal advances
   it). A longer lag, or one whose form matters, is a dynamics (a valve, an amplifier, a filter in
   the DAQ) that a delay does not model: the uncompensated values are reported, and the mass only
   if compensating the lag as a delay would move it by no more than its standard error.

Quality gates (per parameter, unlike :class:`analyses.quality.Gate` which voids a whole row)
---------------------------------------------------------------------------------------------
The whole row is NULL (with a ``note``) when there are too few rows, the design is
ill-conditioned, or the model misses the filtered force (NRMSE over :data:`NRMSE_LIMIT_PCT`
and residuals above 3 times the filtered force noise). Otherwise each parameter is judged on
its own: a parameter whose standard error exceeds :data:`MAX_REL_SE` of its value (``offset``:
of half the RMS drive force), or whose value is physically impossible (``M <= 0``, ``Fc < 0``, ``Fv < 0``),
is NULL and the note names it and says why -- e.g. ``mass_kg`` with no acceleration content,
``coulomb_n`` and ``viscous_n_s_m`` when the record moves at one speed level (:data:`ONE_LEVEL_REL`,
:data:`ONE_LEVEL_SHARE`), ``mass_kg`` when the force lags or leads the motion by more than
:data:`LAG_MAX_SAMPLES` sample and compensating it would move the mass beyond its standard error
(step 7). The others stand:
collinear columns inflate each other's errors but do not bias the remaining estimates.
"""
from __future__ import annotations

import numpy as np

# scipy.signal's filters and Welch PSD and scipy.interpolate's CubicSpline, without importing either
# (about 1.3 CPU-s of a rebuild after one changed viscous run; issue 26)
from analyses.numerics_iir import butter_lowpass_sos, sosfiltfilt, welch_psd
from analyses.numerics_spline import NotAKnotSpline
from analyses.quality import COND_MAX, Sensor, describe_sensor, linear_lstsq, nrmse_pct, time_base_gap

#: The motion must stand this far above the position noise floor (power ratio) to be used. [-]
SNR_MIN = 100.0
#: Order of the Butterworth low-pass (run forwards and backwards: twice this in effect).
FILTER_ORDER = 4
#: Samples slower than this many sigmas of the filtered velocity noise are left out. [-]
V_MIN_N_SIGMA = 5.0
#: Samples slower than this fraction of the fastest are at rest too, whatever the sensor: the
#: filtered velocity of a record at rest still rings at about that level near a stop. [-]
V_MIN_REL = 1e-3
#: A model that misses the filtered force by more than this NRMSE (and more than 3 times the
#: filtered force noise) is not reported: the seed papers' own bar for a model that fits
#: (seed 001, Table 3). A record in the tanh transition (passes under a few ``vs``) misses it. [%]
NRMSE_LIMIT_PCT = 2.5
#: A drive force that lags or leads the motion by at most this many sample periods is compensated
#: (a fractional delay, step 7 of the module docstring): the sampling does not resolve a timing
#: under a sample, and a multiplexed DAQ scans its channels within one sample period. A longer lag
#: is dynamics a delay does not model: it voids the mass when compensating it as a delay would
#: move the mass beyond its standard error. [-]
LAG_MAX_SAMPLES = 1.0
#: A lag is significant beyond this many of its standard errors. [-]
LAG_N_SE = 3.0
#: Most Gauss-Newton steps of the lag estimate. [-]
LAG_MAX_ITER = 8
#: The Coulomb column's sign comes from a velocity filtered at this multiple of the cut-off (at
#: most ``fs / 4``): an order-4 Butterworth run forwards and backwards passes the band of the
#: filtered columns (up to 1/3 of its own cut-off) within 2e-4 in amplitude, so the zero crossings
#: stay where the motion has them. [-]
SIGN_CUTOFF_FACTOR = 3.0
#: Largest share of the filtered acceleration's variance that may be sensor noise (the bias of
#: the mass toward zero, errors in variables). [-]
EIV_MAX = 0.01
#: Samples within this many filter periods of a slow one are left out (filter transients). [-]
GUARD_PERIODS = 2.0
#: Least rows of the regression. [-]
MIN_ROWS = 20
#: Largest standard error of a reported parameter, as a fraction of its value: a value is
#: reported to about +-40 % at two standard errors, or not at all. [-]
MAX_REL_SE = 0.2
#: Speeds within this fraction of the median speed count as one speed level; a record with
#: fewer than :data:`ONE_LEVEL_SHARE` of its rows off that level moves at one speed, and its
#: Coulomb and viscous parts are not reported (what separates them would be the short ramps,
#: where filter transients dominate). [-]
ONE_LEVEL_REL = 0.05
ONE_LEVEL_SHARE = 0.1

PARAMS = ("mass_kg", "viscous_n_s_m", "coulomb_n", "offset_n")
SE_NAMES = {"mass_kg": "mass_se_kg", "viscous_n_s_m": "viscous_se_n_s_m", "coulomb_n": "coulomb_se_n",
            "offset_n": "offset_se_n"}
COLUMNS = ("mass_kg", "coulomb_n", "viscous_n_s_m", "offset_n", "mass_se_kg", "coulomb_se_n", "viscous_se_n_s_m",
           "offset_se_n", "nrmse_pct", "n_samples", "cond", "cutoff_hz", "lag_s", "lag_se_s", "note")


def _sigma_eff(sensor: Sensor) -> float:
    """White-noise equivalent of a sensor: ``sqrt(noise^2 + res^2 / 12)``. [unit of the channel]"""
    return float(np.hypot(sensor.noise, sensor.resolution / np.sqrt(12.0)))


def motion_cutoff_hz(x_m, fs_hz: float, sensor: Sensor | None = None, snr_min: float = SNR_MIN) -> float | None:
    """Highest frequency at which the position stands ``snr_min`` above its sensor's noise floor.

    Parameters
    ----------
    x_m : array_like
        Uniformly sampled position [m].
    fs_hz : float
        Sample rate [Hz].
    sensor : analyses.quality.Sensor, optional
        Position sensor [m]; estimated from ``x_m`` when not given.
    snr_min : float
        Power ratio of motion to noise floor [-].

    Returns
    -------
    float or None
        The cut-off [Hz], at most ``fs / 5``; None when the record never rises above its noise.
    """
    x = np.asarray(x_m, dtype=float)
    sensor = sensor if sensor is not None else describe_sensor(x)
    n = x.size
    if n < 16:
        return None
    nper = int(min(n, 2 ** int(np.ceil(np.log2(max(16, min(n, 16 * fs_hz)))))))
    # scipy.signal.welch(x, fs=fs_hz, nperseg=nper, detrend="linear") without importing scipy.signal
    f, pxx = welch_psd(x, fs_hz, nper)
    floor = 2.0 * _sigma_eff(sensor) ** 2 / fs_hz  # one-sided PSD of white noise [m^2/Hz]
    top = fs_hz / 5.0
    above = np.flatnonzero((pxx > snr_min * floor) & (f > 0))
    if above.size == 0:
        return None
    return float(min(f[above[-1]], top)) if floor > 0 else top


def _filt(sos, y):
    return sosfiltfilt(sos, y)  # scipy.signal.sosfiltfilt's bits (analyses.numerics_iir)


def _estimate_lag(ff, X, X_all, idx, dt: float, max_shift: float):
    """Lag of the filtered force behind the model (module docstring, step 7).

    Returns ``(tau, tau_se, fit, y)``: the lag [s] (positive: the force lags), its standard error,
    the fit on the force shifted by it and that shifted force at the rows ``idx``; ``tau_se`` NaN
    (and ``fit``, ``y`` None) when the record cannot tell a lag from the other columns, ``fit``
    and ``y`` None when the estimate runs past ``max_shift`` [s] (the rows' margin to the edges).
    """
    spline = NotAKnotSpline(np.arange(ff.size), ff)  # scipy.interpolate.CubicSpline's values, to the bit
    tau, step, tau_se = 0.0, np.inf, float("nan")
    for _ in range(LAG_MAX_ITER):
        y = spline(idx + tau / dt)  # F_meas(t + tau): the force as it was when the motion was
        fit = linear_lstsq(X, y)
        deriv = np.gradient(X_all @ fit.beta, dt)[idx]
        aug = linear_lstsq(np.column_stack([X, deriv]), y)
        if aug.rank < X.shape[1] + 1 or not np.isfinite(aug.se[-1]):
            return tau, float("nan"), None, None
        step, tau_se = -float(aug.beta[-1]), float(aug.se[-1])
        tau += step
        if not abs(tau) < max_shift:
            return tau, tau_se, None, None
        if abs(step) <= 0.01 * tau_se:
            break
    y = spline(idx + tau / dt)
    return tau, tau_se, linear_lstsq(X, y), y


def friction_dynamic(t_s, x_m, force_n, sensor: Sensor | None = None, force_sensor: Sensor | None = None, *,
                     cutoff_hz: float | None = None) -> dict:
    """Mass, Coulomb and viscous friction and force offset of one run by IDIM-LS (module docstring).

    Parameters
    ----------
    t_s : array_like
        Time [s].
    x_m : array_like
        Position [m].
    force_n : array_like
        Drive force toward +x [N].
    sensor : analyses.quality.Sensor, optional
        Position sensor [m]; estimated from ``x_m`` when not given.
    force_sensor : analyses.quality.Sensor, optional
        Drive-force noise [N]; estimated from ``force_n`` when not given.
    cutoff_hz : float, optional
        Low-pass cut-off [Hz]; chosen from the data (:func:`motion_cutoff_hz`) when not given.

    Returns
    -------
    dict
        ``mass_kg``, ``coulomb_n``, ``viscous_n_s_m``, ``offset_n`` and their standard errors
        ``mass_se_kg``, ``coulomb_se_n``, ``viscous_se_n_s_m``, ``offset_se_n``; ``nrmse_pct``
        (filtered force vs model over the rows used), ``n_samples`` (rows used), ``cond``
        (scaled condition number of the design), ``cutoff_hz``, ``note`` (None when every value stands).
    """
    out = dict.fromkeys(COLUMNS)
    t = np.asarray(t_s, dtype=float)
    x = np.asarray(x_m, dtype=float)
    f = np.asarray(force_n, dtype=float)
    ok = np.isfinite(t) & np.isfinite(x) & np.isfinite(f)
    t, x, f = t[ok], x[ok], f[ok]
    out["n_samples"] = 0
    if t.size < 4 * MIN_ROWS:
        out["note"] = f"too few samples: {t.size} < {4 * MIN_ROWS}"
        return out
    order = np.argsort(t, kind="stable")
    t, x, f = t[order], x[order], f[order]
    dt = float(np.median(np.diff(t)))
    if not (np.isfinite(dt) and dt > 0):
        out["note"] = "time does not advance"
        return out
    sensor = sensor if sensor is not None else describe_sensor(x)
    force_sensor = force_sensor if force_sensor is not None else describe_sensor(f)
    if np.max(np.abs(np.diff(t) - dt)) > 0.01 * dt:  # not uniformly sampled: onto a uniform grid
        gap = time_base_gap(t, dt)  # a grid sized by the span, not by the samples: refused
        if gap:
            out["note"] = gap
            return out
        tu = t[0] + dt * np.arange(int(np.floor((t[-1] - t[0]) / dt)) + 1)
        x, f, t = np.interp(tu, t, x), np.interp(tu, t, f), tu
    fs = 1.0 / dt
    fc = cutoff_hz if cutoff_hz is not None else motion_cutoff_hz(x, fs, sensor)
    if fc is None or not (0 < fc < fs / 2):
        out["note"] = "the position never rises above its sensor's noise: no motion to identify from"
        return out
    sig_x = _sigma_eff(sensor)
    a_resolved = True
    if cutoff_hz is None:
        # lower the cut-off until the filtered acceleration's noise (white position noise through
        # an ideal low-pass, differentiated twice) is under 1 % of its variance: noise in a
        # regressor biases its coefficient toward zero by that fraction (errors in variables)
        for cand in np.geomspace(fc, fc / 30.0, 16):
            sos = butter_lowpass_sos(FILTER_ORDER, cand, fs)
            a_c = np.gradient(np.gradient(_filt(sos, x), dt), dt)
            noise_a = (2 * np.pi) ** 4 * sig_x ** 2 * (2 / fs) * cand ** 5 / 5
            if noise_a <= EIV_MAX * float(np.var(a_c)):
                fc = float(cand)
                break
        else:
            a_resolved = False
    out["cutoff_hz"] = float(fc)
    sos = butter_lowpass_sos(FILTER_ORDER, fc, fs)
    xf, ff = _filt(sos, x), _filt(sos, f)
    v = np.gradient(xf, dt)
    a = np.gradient(v, dt)
    # noise of the filtered velocity (ideal low-pass of white position noise, differentiated)
    sig_v = 2 * np.pi * sig_x * np.sqrt(2 * fc ** 3 / (3 * fs))
    v_min = max(V_MIN_N_SIGMA * sig_v, V_MIN_REL * float(np.max(np.abs(v))), 1e-12)
    slow = np.abs(v) < v_min
    slow_raw = slow.copy()
    guard = max(1, int(np.ceil(GUARD_PERIODS / fc / dt)))
    if slow.any():  # dilate the slow samples by the guard
        k = np.ones(2 * guard + 1)
        slow = np.convolve(slow.astype(float), k, mode="same") > 0
    r = max(1, int(np.floor(fs / (4 * fc))))
    use = ~slow
    edge = max(guard, int(np.ceil(2.0 / fc / dt)))
    use[:edge] = False
    use[-edge:] = False
    idx = np.flatnonzero(use)
    idx = idx[(idx - edge) % r == 0]
    if idx.size < MIN_ROWS:
        out["n_samples"] = int(idx.size)
        out["note"] = f"too few moving samples: {idx.size} < {MIN_ROWS}"
        return out
    # sign(v), 0 where the carriage is at rest, filtered like the force (parallel filtering); the
    # sign from a velocity that keeps the motion's zero crossings (SIGN_CUTOFF_FACTOR)
    fc_sign = min(SIGN_CUTOFF_FACTOR * fc, fs / 4.0)
    if fc_sign > fc:
        v_s = np.gradient(_filt(butter_lowpass_sos(FILTER_ORDER, fc_sign, fs), x), dt)
        sig_vs = 2 * np.pi * sig_x * np.sqrt(2 * fc_sign ** 3 / (3 * fs))
        vs_min = max(V_MIN_N_SIGMA * sig_vs, V_MIN_REL * float(np.max(np.abs(v_s))), 1e-12)
        col = _filt(sos, np.where(np.abs(v_s) < vs_min, 0.0, np.sign(v_s)))
    else:
        col = _filt(sos, np.where(slow_raw, 0.0, np.sign(v)))
    X_all = np.column_stack([a, v, col, np.ones(v.size)])
    X = X_all[idx]
    fit = linear_lstsq(X, ff[idx])
    y = ff[idx]
    out.update({"n_samples": int(idx.size), "cond": float(fit.cond)})
    if not (fit.cond < COND_MAX) or fit.rank < len(PARAMS):
        out["note"] = (f"design is ill-conditioned (condition number {fit.cond:.2g}): "
                       "the record cannot separate mass, friction and offset")
        return out
    tau, tau_se, lag_fit, lag_y = _estimate_lag(ff, X, X_all, idx, dt, edge * dt)
    lag_known = bool(np.isfinite(tau_se)) and lag_fit is not None
    fit_delay = None  # the compensated fit of a lag that is not compensated, to weigh the mass against
    if lag_known and abs(tau) > LAG_N_SE * tau_se:
        # a lead is timing (nothing causal advances the force); a lag may be a dynamics: how far the
        # delay moves the mass, and how far a lag of another form could move it beyond that (the
        # forms agree to first order in w tau and differ at the next, ~ w_c tau / 2 of it)
        shift_m = abs(float(lag_fit.beta[0] - fit.beta[0]))
        shape_m = shift_m * 2 * np.pi * fc * tau / 2 if tau > 0 else 0.0
        if abs(tau) <= LAG_MAX_SAMPLES * dt and shape_m <= fit.se[0]:
            fit, y = lag_fit, lag_y  # within the sampling: compensated
        else:
            fit_delay = lag_fit
    if lag_known:
        out["lag_s"], out["lag_se_s"] = float(tau), float(tau_se)
    nrmse = nrmse_pct(y, fit.fitted)
    out["nrmse_pct"] = float(nrmse) if np.isfinite(nrmse) else None
    values = dict(zip(PARAMS, (float(b) for b in fit.beta)))
    ses = dict(zip(PARAMS, (float(s) for s in fit.se)))
    sig_f = _sigma_eff(force_sensor) * np.sqrt(2 * fc / fs)
    rms = float(np.sqrt(np.mean((y - fit.fitted) ** 2)))
    if not np.isfinite(nrmse) or (nrmse > NRMSE_LIMIT_PCT and rms > 3 * sig_f):
        out["note"] = (f"model misses the data (NRMSE {nrmse:.2g} % > {NRMSE_LIMIT_PCT:g} %)"
                       if np.isfinite(nrmse) else "fit quality undefined (the force has no range)")
        return out
    # per-parameter gates
    f_rms = float(np.sqrt(np.mean(y ** 2)))
    failed: dict[str, str] = {}
    for name in PARAMS:
        b, s = values[name], ses[name]
        scale = max(abs(b), 0.5 * f_rms) if name == "offset_n" else abs(b)
        if not np.isfinite(s) or s > MAX_REL_SE * scale:
            failed[name] = f"not identifiable (estimate {b:.3g} +- {s:.2g})"
        elif name != "offset_n" and (b < 0 or (name == "mass_kg" and b == 0)):
            failed[name] = f"physically impossible ({b:.3g} < 0)" if b < 0 else "zero"
    speeds = np.abs(v[idx])
    one_level = bool(np.mean(np.abs(speeds - np.median(speeds)) <= ONE_LEVEL_REL * np.median(speeds))
                     >= 1 - ONE_LEVEL_SHARE)
    reasons = []
    fric = [n for n in ("coulomb_n", "viscous_n_s_m") if n in failed]
    if one_level:
        for n in ("coulomb_n", "viscous_n_s_m"):
            failed.setdefault(n, "one speed level")
        reasons.append(f"coulomb_n and viscous_n_s_m NULL: the record moves at one speed level "
                       f"(|v| about {np.median(speeds):.3g} m/s), which cannot separate Coulomb from viscous friction")
    elif fric:
        reasons.append("; ".join(f"{n} NULL: {failed[n]}" for n in fric))
    if not a_resolved and "mass_kg" not in failed:
        failed["mass_kg"] = "acceleration not resolved"
        reasons.append("mass_kg NULL: the acceleration does not rise above the position sensor's noise "
                       "at any usable cut-off")
    elif "mass_kg" in failed:
        acc_rms = float(np.sqrt(np.mean(a[idx] ** 2)))
        reasons.append(f"mass_kg NULL: {failed['mass_kg']}; acceleration content {acc_rms:.2g} m/s2 RMS")
    if "offset_n" in failed:
        reasons.append(f"offset_n NULL: {failed['offset_n']}")
    # a force that lags (or leads) the motion by more than a sample -- a valve or amplifier lag, a
    # filter in the DAQ -- is dynamics, not a delay: the mass stands only if compensating the lag
    # as a delay would not move it beyond its standard error; the friction, read at steadier
    # speeds, stands
    way = "lags" if tau > 0 else "leads"
    if "mass_kg" not in failed and fit_delay is not None:
        m_delay = float(fit_delay.beta[0])
        if abs(m_delay - values["mass_kg"]) > ses["mass_kg"]:
            failed["mass_kg"] = "lag"
            why = ("more than a sample" if abs(tau) > LAG_MAX_SAMPLES * dt else
                   f"{2 * np.pi * fc * abs(tau):.2g} rad at the cut-off, where a delay no longer stands for any lag")
            reasons.append(f"mass_kg NULL: the drive force {way} the motion by about {1e3 * abs(tau):.2g} ms "
                           f"({abs(tau) / dt:.2g} samples, {why}), which the model has no term for: compensated as "
                           f"a delay it would move the mass from {values['mass_kg']:.3g} to {m_delay:.3g} kg, beyond "
                           f"its standard error {ses['mass_kg']:.2g} kg")
    elif "mass_kg" not in failed and np.isfinite(tau_se) and lag_fit is None:
        failed["mass_kg"] = "lag"
        reasons.append(f"mass_kg NULL: the drive force {way} the motion by more than {1e3 * edge * dt:.2g} ms, "
                       "which the model has no term for")
    if out["lag_s"] is None:
        reasons.append(f"lag_s NULL: the estimate runs past the {1e3 * edge * dt:.2g} ms the record's edges leave"
                       if np.isfinite(tau_se) else
                       "lag_s NULL: the record cannot tell a lag of the force from its mass and friction")
    for name in PARAMS:
        if name in failed:
            out[name] = out[SE_NAMES[name]] = None
        else:
            out[name], out[SE_NAMES[name]] = values[name], ses[name]
    out["note"] = "; ".join(reasons) or None
    return out


__all__ = ["COLUMNS", "friction_dynamic", "motion_cutoff_hz", "NRMSE_LIMIT_PCT", "SNR_MIN"]
