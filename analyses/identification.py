"""PLPA third-order model identified from closed-loop data (seed 000, section 2.3, Eqs. 10 and 14).

The plant is

    X(s) / U(s) = k wn^2 / (s (s^2 + 2 zeta wn s + wn^2))                      (Eq. 10)

stabilised during the test by a proportional controller ``u = kp (x_ref - x) + u_d`` that runs
at the logging rate (5 kHz, continuous for the plant). The persistent excitation ``u_d`` and the
reference ``x_ref`` are the external inputs; the closed loop from ``u_d`` to ``x`` is Eq. 14.

Identification here is *output error*: the continuous closed loop is discretised exactly with a
zero-order hold on the external inputs at the identification rate, simulated from the measured
``u_d`` and ``x_ref``, and ``wn``, ``zeta``, ``k`` and the initial state are fitted with
:func:`scipy.optimize.least_squares` (bounded, scaled) to the measured position.

Decimation to the identification rate (default 50 Hz):

* the output ``x`` goes through a zero-phase FIR anti-alias filter (:func:`scipy.signal.decimate`,
  in stages of at most 10) and is sampled on the identification grid;
* the inputs ``u_d`` and ``x_ref`` are averaged over each identification interval
  (integrate-and-dump, a boxcar anti-alias filter). That is exactly the input a zero-order hold
  model assumes; when the excitation is itself held on a grid (the bench's ``u_d`` is held for
  0.02 s) the identification grid is aligned with its switching instants, which makes the
  discretisation exact.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy  # its submodules load on first use: a rebuild that reuses every stage never pays for them

from analyses.quality import Gate, Sensor, describe_sensor, jacobian_se

__all__ = ["FIT_MIN_PCT", "plpa_plant_ss", "plpa_closed_loop_ss", "simulate_closed_loop", "decimate_for_identification",
           "fit_percent", "IdentificationResult", "identify_third_order", "plot_identification"]


def plpa_plant_ss(wn: float, zeta: float, k: float):
    """State space of the PLPA plant, Eq. 10, with state ``[x, x', x'']``.

    Parameters
    ----------
    wn : float
        Natural frequency. [rad/s]
    zeta : float
        Damping ratio. [-]
    k : float
        Velocity gain ``k_lin``. [m/(V s)]

    Returns
    -------
    A, B, C, D : ndarray
        Continuous-time matrices; input the valve command ``u`` [V], output the position ``x`` [m].
    """
    A = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, -wn * wn, -2.0 * zeta * wn]])
    B = np.array([[0.0], [0.0], [k * wn * wn]])
    C = np.array([[1.0, 0.0, 0.0]])
    D = np.zeros((1, 1))
    return A, B, C, D


def plpa_closed_loop_ss(wn: float, zeta: float, k: float, kp: float):
    """The plant under ``u = kp (x_ref - x) + u_d`` (Eq. 14), inputs ``[u_d, x_ref]``.

    Parameters
    ----------
    wn, zeta, k : float
        Plant parameters. [rad/s], [-], [m/(V s)]
    kp : float
        Proportional gain of the stabilising controller. [V/m]

    Returns
    -------
    A, B, C, D : ndarray
        Continuous closed loop; inputs ``u_d`` [V] and ``x_ref`` [m], output ``x`` [m].
    """
    A, B, C, _ = plpa_plant_ss(wn, zeta, k)
    Acl = A - kp * B @ C
    Bcl = np.hstack([B, kp * B])
    return Acl, Bcl, C, np.zeros((1, 2))


def _discrete_closed_loop(wn, zeta, k, kp, dt):
    """ZOH discretisation; returns (a, b_ud, b_xref, Ad, C) with transfer-function coefficients."""
    Acl, Bcl, C, D = plpa_closed_loop_ss(wn, zeta, k, kp)
    Ad, Bd, Cd, _, _ = scipy.signal.cont2discrete((Acl, Bcl, C, D), dt, method="zoh")
    # characteristic polynomial of Ad and numerators C adj(zI - Ad) Bd (no feed-through)
    a = np.real(np.poly(Ad))
    nums = []
    for j in range(Bd.shape[1]):
        b, _ = scipy.signal.ss2tf(Ad, Bd[:, [j]], Cd, np.zeros((1, 1)))
        nums.append(np.real(b[0]))
    return a, nums[0], nums[1], Ad, Cd


def simulate_closed_loop(wn: float, zeta: float, k: float, kp: float, u_d, x_ref, dt: float,
                         x0=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Position of the closed loop driven by held inputs (exact zero-order-hold discretisation).

    Parameters
    ----------
    wn, zeta, k : float
        Plant parameters. [rad/s], [-], [m/(V s)]
    kp : float
        Controller gain. [V/m]
    u_d : array_like
        Excitation, held over each interval ``[i dt, (i+1) dt)``. [V]
    x_ref : array_like
        Reference, held likewise. [m]
    dt : float
        Sample time. [s]
    x0 : sequence of 3 float
        Initial state ``[x, x', x'']``. [m], [m/s], [m/s2]

    Returns
    -------
    ndarray
        Position at ``i dt``, ``i = 0 .. len(u_d) - 1``. [m]
    """
    u_d = np.asarray(u_d, dtype=float)
    x_ref = np.broadcast_to(np.asarray(x_ref, dtype=float), u_d.shape)
    a, b1, b2, Ad, C = _discrete_closed_loop(wn, zeta, k, kp, dt)
    return _response(a, b1, b2, Ad, C, u_d, x_ref) + _free_basis(a, Ad, C, len(u_d)) @ np.asarray(x0, float)


def _response(a, b1, b2, Ad, C, u_d, x_ref):
    return scipy.signal.lfilter(b1, a, u_d) + scipy.signal.lfilter(b2, a, x_ref)


def _free_basis(a, Ad, C, n):
    """Columns: output of the unforced loop from each unit initial state (``C Ad^i e_j``)."""
    first = np.vstack([C @ np.linalg.matrix_power(Ad, i) for i in range(3)])  # (3, 3): y0..y2 per state
    impulse = np.zeros(n)
    impulse[0] = 1.0
    cols = []
    for j in range(3):
        y = first[:, j]
        num = np.convolve(a, y)[:3]  # y = num / a  =>  num = a * y (first three terms)
        cols.append(scipy.signal.lfilter(num, a, impulse))
    return np.column_stack(cols)


def fit_percent(y, y_model) -> float:
    """``fit_pct`` of warehouse.md: ``100 (1 - ||y - y_model|| / ||y - mean(y)||)``. [%]"""
    y = np.asarray(y, float)
    y_model = np.asarray(y_model, float)
    den = np.linalg.norm(y - y.mean())
    if den == 0:
        return float("nan")
    return float(100.0 * (1.0 - np.linalg.norm(y - y_model) / den))


def _hold_phase(u: np.ndarray, q: int) -> int:
    """Index offset (0..q-1) of the switching instants of a held signal, 0 if it is not held."""
    change = np.flatnonzero(np.abs(np.diff(u)) > 1e-12 * max(1.0, float(np.max(np.abs(u))))) + 1
    if len(change) < 3 or len(change) > 0.5 * len(u):
        return 0
    counts = np.bincount(change % q, minlength=q)
    best = int(np.argmax(counts))
    return best if counts[best] >= 0.6 * len(change) else 0


def decimate_for_identification(t, x, u_d, x_ref, rate_hz: float = 50.0):
    """Bring 5 kHz logs to the identification rate with anti-alias filtering.

    Parameters
    ----------
    t : array_like
        Time, uniformly sampled. [s]
    x : array_like
        Position (output). [m]
    u_d : array_like
        Excitation (input). [V]
    x_ref : array_like
        Reference (input). [m]
    rate_hz : float
        Identification rate. [Hz]

    Returns
    -------
    dict
        ``t_s``, ``x_m`` (zero-phase FIR anti-aliased, sampled at the start of each interval),
        ``u_d_v`` and ``x_ref_m`` (interval means, the zero-order-hold input), ``dt_s``
        (the identification sample time actually used: an integer decimation factor).
    """
    t = np.asarray(t, float)
    x = np.asarray(x, float)
    u_d = np.asarray(u_d, float)
    x_ref = np.asarray(x_ref, float)
    dt_log = float(np.median(np.diff(t)))
    q = max(1, int(round(1.0 / (rate_hz * dt_log))))
    q = min(q, max(1, len(t)))  # a factor past the record leaves no block; its FIR (20 q taps) stays that size
    off = _hold_phase(u_d, q) if q > 1 else 0
    n_blocks = (len(t) - off) // q
    end = off + n_blocks * q
    xs = x
    factors = _factors(q)
    for f in factors:
        if f > 1:
            xs = _fir_decimate(xs, f)
    # xs[i] is the filtered x at t[i*q]; keep the grid starting at ``off``
    x_dec = _interp_grid(xs, q, off, n_blocks, x)
    ud = u_d[off:end].reshape(n_blocks, q).mean(axis=1)
    xr = x_ref[off:end].reshape(n_blocks, q).mean(axis=1)
    return {"t_s": t[off:end:q][:n_blocks], "x_m": x_dec, "u_d_v": ud, "x_ref_m": xr, "dt_s": q * dt_log}


def _fir_decimate(x: np.ndarray, q: int) -> np.ndarray:
    """``signal.decimate(x, q, ftype="fir", zero_phase=True)`` with odd-reflection padding.

    The ends are extended by point reflection (value and slope continue), as ``filtfilt``
    does, instead of zeros: the position is far from zero and must not start with a transient.
    Output ``i`` is the filtered signal at input ``i q``.
    """
    b = scipy.signal.firwin(20 * q + 1, 1.0 / q, window="hamming")
    npad = int(np.ceil(len(b) / q)) * q
    npad = min(npad, (len(x) - 1) // q * q) if len(x) > q else 0
    if npad > 0:
        x = np.concatenate([2 * x[0] - x[npad:0:-1], x, 2 * x[-1] - x[-2:-npad - 2:-1]])
    y = scipy.signal.resample_poly(x, 1, q, window=b)
    n_out = -(-(len(x) - 2 * npad) // q)
    return y[npad // q: npad // q + n_out]


def _factors(q: int) -> list[int]:
    """Split a decimation factor into stages of at most 10 (scipy advises <= 13 per call)."""
    out, rest = [], q
    for f in (10, 8, 5, 4, 3, 2):
        while rest % f == 0 and rest > 1:
            out.append(f)
            rest //= f
    while rest > 1:  # a prime factor > 10: one stage with it
        out.append(rest)
        rest = 1
    return out or [1]


def _interp_grid(xs, q, off, n_blocks, x):
    """The filtered output at indices ``off + i q`` (xs holds it at ``i q``)."""
    if off == 0:
        return np.asarray(xs[:n_blocks], float)
    grid = np.arange(len(xs)) * q
    want = off + np.arange(n_blocks) * q
    return np.interp(want, grid, xs)


@dataclass
class IdentificationResult:
    """Outcome of :func:`identify_third_order`; NaNs and ``message`` when not identifiable."""

    wn_rad_s: float = float("nan")
    zeta: float = float("nan")
    k_lin_m_v_s: float = float("nan")
    fit_pct: float = float("nan")
    x0: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    dt_s: float = float("nan")
    t_s: np.ndarray = field(default_factory=lambda: np.empty(0))
    x_m: np.ndarray = field(default_factory=lambda: np.empty(0))
    x_model_m: np.ndarray = field(default_factory=lambda: np.empty(0))
    u_d_v: np.ndarray = field(default_factory=lambda: np.empty(0))
    message: str = ""
    note: str | None = None
    se: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))

    def __post_init__(self):
        if self.note is None and self.message and not self.ok:
            self.note = self.message   # why the parameters are NaN

    @property
    def ok(self) -> bool:
        return bool(np.isfinite(self.wn_rad_s))


WN_BOUNDS = (0.3, 1000.0)
ZETA_BOUNDS = (0.01, 10.0)
K_BOUNDS = (1e-4, 1e3)
#: The model's acceptance limit on ``fit_pct`` (output error on the identification-rate data):
#: a model that explains less than this share of the motion is not reported, unless its
#: residuals are at the position sensor's floor (then the motion itself is that small). [%]
FIT_MIN_PCT = 80.0
#: Names of the reported parameters (table columns).
PARAM_NAMES = ("wn_rad_s", "zeta", "k_lin_m_v_s")


def identify_third_order(t, x, u_d, x_ref, kp: float, rate_hz: float = 50.0,
                         min_samples: int = 100, x_sensor: Sensor | None = None,
                         ud_sensor: Sensor | None = None) -> IdentificationResult:
    """Identify ``wn``, ``zeta``, ``k`` of Eq. 10 from a closed-loop run by output error.

    Parameters
    ----------
    t : array_like
        Time at the logging rate. [s]
    x : array_like
        Measured position. [m]
    u_d : array_like
        Measured excitation added to the valve command. [V]
    x_ref : array_like
        Measured position reference. [m]
    kp : float
        Gain of the stabilising controller (run metadata ``kp_v_m``). [V/m]
    rate_hz : float
        Identification rate (``id_sample_rate_hz``). [Hz]
    min_samples : int
        Fewest identification-rate samples accepted.
    x_sensor, ud_sensor : Sensor, optional
        Resolution and noise of ``x`` and ``u_d`` (run metadata); estimated from the records
        when absent.

    Returns
    -------
    IdentificationResult
        Parameters, ``fit_pct`` (warehouse.md) on the identification-rate data, the decimated
        data and the simulated model output. When the run cannot be identified the parameters
        are NaN and ``message`` says why; when the fit does not pass the quality gates (a
        parameter at its bound, standard errors from the Jacobian over half the value, an
        ill-conditioned design, ``fit_pct`` under :data:`FIT_MIN_PCT` with residuals above
        three sigmas of the position sensor) they are NaN too and ``note`` (= ``message``)
        says why; ``fit_pct`` and the model output are kept as the evidence.
    """
    t = np.asarray(t, float)
    if len(t) < 2 or not np.all(np.isfinite(t)):
        return IdentificationResult(message="too short or invalid time")
    if not (kp is not None and np.isfinite(kp) and kp > 0):
        return IdentificationResult(message=f"controller gain kp_v_m = {kp!r} is not a positive number")
    data = [np.asarray(v, float) for v in (x, u_d, x_ref)]
    if any(not np.all(np.isfinite(v)) for v in data):
        return IdentificationResult(message="non-finite samples in x, u_d or x_ref")
    dt_log = float(np.median(np.diff(t)))
    if not dt_log > 0:
        return IdentificationResult(message=f"time does not advance (median step {dt_log:.3g} s)")
    q = max(1, round(1.0 / (rate_hz * dt_log)))  # as decimate_for_identification: said before its filter
    if len(t) // q < min_samples:                 # (20 q taps, sized by the step) is built
        return IdentificationResult(message=f"too short: {len(t) // q} samples at {1 / (q * dt_log):.3g} Hz "
                                    f"(need {min_samples})")
    dec = decimate_for_identification(t, *data, rate_hz=rate_hz)
    y, ud, xr, dt = dec["x_m"], dec["u_d_v"], dec["x_ref_m"], dec["dt_s"]
    base = dict(dt_s=dt, t_s=dec["t_s"], x_m=y, u_d_v=ud)
    if len(y) < min_samples:
        return IdentificationResult(message=f"too short: {len(y)} samples at {1 / dt:.0f} Hz "
                                    f"(need {min_samples})", **base)
    if x_sensor is None:
        x_sensor = describe_sensor(data[0])
    if ud_sensor is None:
        ud_sensor = describe_sensor(data[1])
    if not np.std(ud) > ud_sensor.floor() or not np.ptp(y) > 2 * x_sensor.floor():
        return IdentificationResult(message=f"no excitation: u_d (std {np.std(ud):.2g} V) or x (range "
                                    f"{np.ptp(y):.2g} m) does not exceed its sensor's floor "
                                    f"({ud_sensor.floor():.2g} V, {x_sensor.floor():.2g} m)", **base)

    n = len(y)
    y_scale = float(np.std(y)) or 1.0

    def forced_and_basis(p):
        a, b1, b2, Ad, C = _discrete_closed_loop(p[0], p[1], p[2], kp, dt)
        return _response(a, b1, b2, Ad, C, ud, xr), _free_basis(a, Ad, C, n)

    def projected_cost(p):
        """Residual norm with the initial state solved by linear least squares."""
        if kp * p[2] >= 2 * p[1] * p[0]:  # unstable closed loop (Routh): not a candidate
            return np.inf, None
        forced, basis = forced_and_basis(p)
        x0, *_ = np.linalg.lstsq(basis, y - forced, rcond=None)
        r = y - forced - basis @ x0
        return float(r @ r), x0

    # coarse grid for a seed (the initial state projected out), then a joint bounded fit
    best = (np.inf, None, None)
    for wn in np.geomspace(1.0, 200.0, 8):
        for zeta in (0.2, 0.45, 0.9, 2.0):
            for k in np.geomspace(0.02, 50.0, 7):
                cost, x0 = projected_cost((wn, zeta, k))
                if cost < best[0]:
                    best = (cost, np.array([wn, zeta, k]), x0)
    if best[1] is None:
        return IdentificationResult(message="no stable model fits the data", **base)
    p0 = np.concatenate([best[1], best[2]])
    x_sc = np.array([1.0, 1.0, 1.0]) * np.abs(best[1])
    x0_sc = np.maximum(np.abs(best[2]), [y_scale, y_scale * 10, y_scale * 100])
    lo = np.array([WN_BOUNDS[0], ZETA_BOUNDS[0], K_BOUNDS[0], -np.inf, -np.inf, -np.inf])
    hi = np.array([WN_BOUNDS[1], ZETA_BOUNDS[1], K_BOUNDS[1], np.inf, np.inf, np.inf])
    p0 = np.clip(p0, lo + 1e-12, hi - 1e-12)

    def residuals(p):
        forced, basis = forced_and_basis(p)
        r = (forced + basis @ p[3:] - y) / y_scale
        if not np.all(np.isfinite(r)):
            return np.full(n, 1e6)
        return r

    try:
        sol = scipy.optimize.least_squares(residuals, p0, bounds=(lo, hi), x_scale=np.concatenate([x_sc, x0_sc]),
                                     method="trf", xtol=1e-10, ftol=1e-10, max_nfev=400)
    except (ValueError, np.linalg.LinAlgError) as exc:
        return IdentificationResult(message=f"fit failed: {exc}", **base)
    p = sol.x
    forced, basis = forced_and_basis(p)
    y_model = forced + basis @ p[3:]
    fit = fit_percent(y, y_model)
    msg = "" if sol.success else f"least_squares: {sol.message}"
    # standard errors of (wn, zeta, k) from the Jacobian (the initial state is a nuisance)
    se, cond = jacobian_se(sol.jac, sol.fun)
    gate = Gate()
    for name, v in zip(PARAM_NAMES, p[:3]):
        gate.physical(name, float(v), lo=0.0)
    gate.within_bounds(p[:3], lo[:3], hi[:3], PARAM_NAMES)
    gate.identifiable(cond=cond, beta=p[:3], se=se[:3], names=PARAM_NAMES)
    rms = float(np.sqrt(np.mean((y - y_model) ** 2)))
    if not (np.isfinite(fit) and fit >= FIT_MIN_PCT) and not rms <= 3.0 * x_sensor.floor():
        gate.fail(f"model misses the data (fit {fit:.3g} % < {FIT_MIN_PCT:g} %, residual RMS {rms:.2g} m "
                  f"over 3 x the position sensor floor {x_sensor.floor():.2g} m)")
    if not gate.ok:
        return IdentificationResult(fit_pct=fit, x0=p[3:].copy(), x_model_m=y_model, message=gate.note,
                                    note=gate.note, se=se[:3], **base)
    return IdentificationResult(wn_rad_s=float(p[0]), zeta=float(p[1]), k_lin_m_v_s=float(p[2]), fit_pct=fit,
                                x0=p[3:].copy(), x_model_m=y_model, message=msg, se=se[:3], **base)


def plot_identification(result: IdentificationResult, title: str = ""):
    """Measured vs model position at the identification rate, and the excitation.

    Parameters
    ----------
    result : IdentificationResult
    title : str

    Returns
    -------
    matplotlib.figure.Figure
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=(9, 7))
    ax1, ax_r, ax2 = fig.subplots(3, 1, sharex=True, gridspec_kw={"height_ratios": [2.2, 1, 1]})
    t = result.t_s - (result.t_s[0] if len(result.t_s) else 0.0)
    ax1.plot(t, result.x_m * 1e3, color="0.2", lw=1.2, label="measured (anti-aliased, decimated)")
    if len(result.x_model_m):
        ax1.plot(t, result.x_model_m * 1e3, color="tab:red", lw=1.0, ls="--",
                 label=f"model: wn={result.wn_rad_s:.2f} rad/s, zeta={result.zeta:.3f}, "
                       f"k={result.k_lin_m_v_s:.3f} m/(V s); fit {result.fit_pct:.1f} %")
        ax_r.plot(t, (result.x_m - result.x_model_m) * 1e3, color="tab:red", lw=0.8)
    ax_r.axhline(0, color="0.3", lw=0.6)
    ax_r.set_ylabel("measured - model [mm]")
    ax_r.grid(alpha=0.3)
    ax1.set_ylabel("position x [mm]")
    ax1.legend(loc="upper right", fontsize=8)
    ax1.grid(alpha=0.3)
    ax2.step(t, result.u_d_v, where="post", color="tab:blue", lw=0.8)
    ax2.set_ylabel("u_d [V]")
    ax2.set_xlabel(f"time [s] (identification rate {1 / result.dt_s:.0f} Hz)" if np.isfinite(result.dt_s)
                   else "time [s]")
    ax2.grid(alpha=0.3)
    fig.suptitle(title or "PLPA identification: measured vs output-error model (Eq. 14)")
    fig.tight_layout()
    return fig
