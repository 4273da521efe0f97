"""PLA as a pneumatic spring: a chamber's parameters fitted over all its runs (seed 001).

The model and the per-run preparation are :mod:`analyses.pla_spring`'s.

Parameters ``n``, ``Ae``, ``eps``, ``delta`` are fitted per chamber over all that chamber's runs by
nonlinear least squares, seeded as section 3.2 of the paper describes: ``Ae`` from force over
gauge pressure at rest position, ``n`` from the elastic part alone, ``delta`` from the loop area
``U = pi delta D^2`` of the lowest-pressure tests, ``eps`` last from what structural damping does
not explain in the small-amplitude tests. The objective weights each run by its force range and
length, so it minimises the sum of squared per-test NRMSE (Table 3's measure).

The joint fit reads no samples: each run gives its sufficient statistics once
(:func:`spring_run_stats`; the model is linear in ``Ae``, ``eps``, ``delta``, and ``n`` enters only
through ``exp(n L)``, so every sum the fit needs is a polynomial in ``n`` whose coefficients are
per-run sums, truncated where the next term is under 1e-17 of the sum), and a chamber's fit adds
its runs' polynomials and solves the separable problem (variable projection: Golub & Pereyra 1973,
SIAM J. Numer. Anal. 10, 413-432) for ``n``, the linear parameters by their normal equations at each
``n``. Same optimum as a nonlinear least-squares fit of the samples (tested to 1e-8 relative); one
changed run costs its own sums and a fit in milliseconds; the same sums in the same ``run_id``
order give the same bits, however they were computed or stored.

Quality gates (:class:`analyses.quality.Gate`): a chamber's parameters are reported only when
none sits at an optimiser bound, the Jacobian separates them (standard error under half the
value), and the model follows the data: the root mean square of the per-test NRMSE within the
paper's stated limit ``NRMSE_LIMIT_PCT`` (2.5 %, Table 3), or force residuals within three
sigmas of the load cell's noise. Otherwise NaN parameters and a ``note``. Each test keeps its
NRMSE (the evidence) and gets a note when it is above the limit and above the noise level.

"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from analyses.numerics import brentq
from analyses.pla_spring import (FORCE_SIGN, NRMSE_LIMIT_PCT, P_ATM_PA, PARAM_BOUNDS, PRESSURE_SIGN, SpringRun,
                                 cycle_span, spring_force)
from analyses.quality import Gate, gram_se, nrmse_pct

__all__ = ["SpringFit", "fit_spring_chamber", "SpringStats", "spring_run_stats", "fit_spring_stats", "spring_nrmse",
           "spring_model_force", "model_loop_energy"]


@dataclass
class SpringFit:
    """Fitted parameters of one chamber, the seeds, and per-run NRMSE."""

    chamber: str
    n_polytropic: float = float("nan")
    ae_m2: float = float("nan")
    epsilon_m2: float = float("nan")
    delta_n_m: float = float("nan")
    n_tests: int = 0
    seeds: dict = field(default_factory=dict)
    nrmse_pct: dict = field(default_factory=dict)
    message: str = ""
    note: str | None = None
    test_notes: dict = field(default_factory=dict)
    se: dict = field(default_factory=dict)
    model_loop_energy_j: dict = field(default_factory=dict)

    @property
    def params(self) -> tuple[float, float, float, float]:
        return self.n_polytropic, self.ae_m2, self.epsilon_m2, self.delta_n_m

    @property
    def ok(self) -> bool:
        return bool(np.isfinite(self.n_polytropic))


#: The moments are polynomials in ``t = n - N_CENTRE`` (the middle of n's bounds, so ``|t| <= 1``). [-]
N_CENTRE = 0.5 * (PARAM_BOUNDS[0][0] + PARAM_BOUNDS[1][0])
#: A run whose log volume ratio ``|ln((C/2) / (C/2 + s d))|`` exceeds this reaches the stroke's end
#: (the chamber at 1/20 or 20x its mid-stroke volume): outside the model. [-]
MAX_LOG_RATIO = 3.0
#: Truncation of the series in ``t``: the first neglected term under this share of the sum. [-]
_SERIES_TOL = 1e-17
#: Grid over n's bounds on which the profiled objective's minima are bracketed.
_N_GRID = 41
_FIT_SUMS = ("pp1", "pps", "pps2", "pq", "psq", "py", "psy", "qq", "qy", "yy")


@dataclass
class SpringStats:
    """What the joint fit needs of one run: its scalars and its sufficient statistics.

    The model is linear in ``Ae``, ``eps``, ``delta`` and depends on ``n`` only through
    ``E = exp(n L)``, ``L`` the log volume ratio of each sample. Every sum the fit needs
    (normal equations, Jacobian, residuals, model loop work) is a sum over samples of ``E``,
    ``E**2`` or 1 times a product of the run's data; ``exp(n L) = exp(m L) sum_k (t L)**k / k!``
    (``t = n - m``) makes each a polynomial in ``t`` whose coefficients are per-run sums. ``fit``:
    the weighted, thinned samples of the fit's objective; ``all``: every sample, unweighted (the
    test's NRMSE); ``cycle``: trapezoid weights of the whole cycles (loop work, travel work).
    Runs combine by adding their polynomials, in ``run_id`` order: deterministic.
    """

    run_id: str
    chamber: str
    p0_abs: float
    amplitude_m: float
    frequency_hz: float
    p_atm: float = P_ATM_PA
    static_force_n: float = float("nan")
    loop_energy_j: float = float("nan")
    cycles: int = 0
    f_noise_n: float = float("nan")
    f_span_n: float = float("nan")
    n_fit: int = 0
    n_all: int = 0
    fit: dict = field(default_factory=dict)
    all: dict = field(default_factory=dict)
    cycle: dict = field(default_factory=dict)
    message: str = ""

    @property
    def ok(self) -> bool:
        return not self.message

    _SECTIONS = ("fit", "all", "cycle")

    def __getstate__(self) -> dict:
        """Pickled with its polynomials as one block of bytes and their layout as one string (the
        stage's memo keeps one per run: a numpy array and a list of 27 tuples cost ~23 us to unpickle,
        0.15 CPU-s of every spring change at 10,000 runs; bytes and a string cost ~1 us); the same
        numbers, bit for bit."""
        state = dict(self.__dict__)
        if "_packed" in state:   # read back and never unpacked: as it was read
            return state
        layout, parts = [], []
        for sec in self._SECTIONS:
            for name, c in state.pop(sec).items():
                layout.append(f"{sec} {name} {len(c)}")
                parts.append(np.asarray(c, float))
        state["_packed"] = (",".join(layout), np.concatenate(parts).tobytes() if parts else b"")
        return state

    def __setstate__(self, state: dict) -> None:
        """The scalars at once, the polynomials when a section is first read (:meth:`__getattr__`): a
        stage that refits one chamber reads the other chamber's runs for their scalars only (issue 26)."""
        self.__dict__.update(state)
        if "_packed" not in state:
            for sec in self._SECTIONS:
                self.__dict__.setdefault(sec, {})

    def __getattr__(self, name: str):
        d = self.__dict__
        if name not in self._SECTIONS or "_packed" not in d:
            raise AttributeError(name)
        layout, blob = d.pop("_packed")
        flat = np.frombuffer(blob, dtype=float).copy() if blob else np.empty(0)   # float64, as written
        secs = {sec: d.pop(sec, {}) for sec in self._SECTIONS}
        for sec, key, a, b in _layout(layout):
            secs[sec][key] = flat[a:b]
        d.update(secs)
        return d[name]


@lru_cache(maxsize=256)
def _layout(text: str) -> tuple[tuple[str, str, int, int], ...]:
    """A packed :class:`SpringStats`' layout (``"section name length,..."``) as (section, name, start,
    end) in its flat block; a campaign's runs share a few layouts (parsed once each)."""
    out, at = [], 0
    for entry in text.split(",") if text else ():
        sec, key, n = entry.split(" ")
        out.append((sec, key, at, at + int(n)))
        at += int(n)
    return tuple(out)


def _n_terms(z: float) -> int:
    """Terms of ``exp(x)``'s series in ``x`` (``|x| <= z``) for a truncation under ``_SERIES_TOL``."""
    k, term = 0, 1.0
    while term * np.exp(2 * z) > _SERIES_TOL and k < 400:
        k += 1
        term *= z / k
    return k + 1


def _pg_sums(L, U, p0: float, pa: float) -> dict:
    """Polynomials in ``t`` of ``sum u pg``, ``sum u pg**2`` and ``sum u (P0 E)**2`` for each weight
    column ``u`` of ``U`` (``pg = P0 E - Pa``); coefficient ``k`` of ``t**k``."""
    z = 2 * float(np.max(np.abs(L))) * (PARAM_BOUNDS[1][0] - N_CENTRE) if len(L) else 0.0
    K = _n_terms(z)
    s1, s2 = np.empty((K, len(L))), np.empty((K, len(L)))
    s1[0] = np.exp(N_CENTRE * L)
    s2[0] = s1[0] ** 2
    for k in range(1, K):
        np.multiply(s1[k - 1], L / k, out=s1[k])
        np.multiply(s2[k - 1], 2 * L / k, out=s2[k])
    # numpy's pairwise sums, not BLAS: the same bits whatever the threads (memo equals --full)
    c1, c2 = (np.stack([np.sum(sk * u, axis=1) for u in U.T]) for sk in (s1, s2))
    c0 = U.sum(axis=0)
    pg, pg2 = p0 * c1, p0 * p0 * c2 - 2 * p0 * pa * c1
    pg[:, 0] -= pa * c0
    pg2[:, 0] += pa * pa * c0
    return {"pg": pg, "pg2": pg2, "ee": p0 * p0 * c2}


def _sample_sums(L, s, q, y, w2, p0: float, pa: float, jacobian: bool) -> dict:
    """The sums of :data:`_FIT_SUMS` (and ``ee*`` for the Jacobian) over samples weighted ``w2``."""
    U = np.column_stack([w2, w2 * s, w2 * s * s, w2 * q, w2 * s * q, w2 * y, w2 * s * y])
    t = _pg_sums(L, U, p0, pa)
    pg, pg2 = t["pg"], t["pg2"]
    out = {"pp1": pg2[0], "pps": pg2[1], "pps2": pg2[2], "pq": pg[3], "psq": pg[4], "py": pg[5], "psy": pg[6],
           "qq": np.array([np.sum(w2 * q * q)]), "qy": np.array([np.sum(w2 * q * y)]),
           "yy": np.array([np.sum(w2 * y * y)])}
    if jacobian:
        out.update(ee1=t["ee"][0], ees=t["ee"][1], ees2=t["ee"][2])
    return out


def spring_run_stats(run: SpringRun, max_samples_per_run: int | None = 4000) -> SpringStats:
    """The sufficient statistics of one prepared run for :func:`fit_spring_stats`.

    Parameters
    ----------
    run : SpringRun
        From :func:`prepare_spring_run`.
    max_samples_per_run : int, optional
        Longer runs are thinned (every k-th sample) in the fit's objective; the NRMSE and the
        loop work use every sample.

    Returns
    -------
    SpringStats
        ``message`` set (and no sums) when the run is unusable or its displacement reaches
        :data:`MAX_LOG_RATIO`.
    """
    st = SpringStats(run.run_id, run.chamber, run.p0_abs, run.amplitude_m, run.frequency_hz, run.p_atm,
                     run.static_force_n, run.loop_energy_j, run.cycles, run.f_noise_n, message=run.message)
    if not run.ok:
        return st
    half = 0.5 * run.stroke_m
    with np.errstate(divide="ignore", invalid="ignore"):
        L = np.log(half / (half + PRESSURE_SIGN[run.chamber] * run.d))
    if not np.all(np.isfinite(L)) or np.max(np.abs(L)) > MAX_LOG_RATIO:
        st.message = "the displacement reaches the stroke's end (outside the model)"
        return st
    q = run.v / (2 * np.pi * run.frequency_hz)
    s = np.sign(run.v)
    step = max(1, int(np.ceil(len(run.d) / max_samples_per_run))) if max_samples_per_run else 1
    sl = slice(None, None, step)
    m = len(run.d[sl])
    st.f_span_n, st.n_fit, st.n_all = float(np.ptp(run.f)), m, len(run.d)
    w2 = np.full(m, 1.0 / (np.ptp(run.f) ** 2 * m))
    st.fit = _sample_sums(L[sl], s[sl], q[sl], run.f[sl], w2, run.p0_abs, run.p_atm, True)
    st.all = _sample_sums(L, s, q, run.f, np.ones(len(L)), run.p0_abs, run.p_atm, False)
    span = cycle_span(run.d)
    if span is not None:
        a, b, _ = span
        dd = np.diff(run.d[a:b + 1])
        c, ca = np.zeros(len(L)), np.zeros(len(L))
        c[a:b] += 0.5 * dd
        c[a + 1:b + 1] += 0.5 * dd
        ca[a:b] += 0.5 * np.abs(dd)
        ca[a + 1:b + 1] += 0.5 * np.abs(dd)
        pg = _pg_sums(L, np.column_stack([c, c * s, ca]), run.p0_abs, run.p_atm)["pg"]
        st.cycle = {"cp1": pg[0], "cps": pg[1], "travel": pg[2], "cq": np.array([np.sum(c * q)])}
    return st


class _Sums:
    """Polynomials in ``t = n - N_CENTRE`` by name: one run's or the sum of a chamber's runs."""

    def __init__(self, parts: list[dict]):
        by_name: dict[str, list] = {}
        for part in parts:
            for name, c in part.items():
                by_name.setdefault(name, []).append(c)
        # the parts added one after another, in order (``np.add.accumulate`` along the parts never
        # reorders: its last row is ``((c0 + c1) + c2) + ...``), shorter ones padded with zeros
        self.poly: dict[str, np.ndarray] = {
            name: np.array(polys[0], float) if len(polys) == 1 else np.add.accumulate(_padded(polys), axis=0)[-1]
            for name, polys in by_name.items()}

    def at(self, name: str, n: float, der: int = 0) -> float:
        c = self.poly[name]
        if der:
            c = np.polynomial.polynomial.polyder(c, der) if len(c) > der else np.zeros(1)
        return float(np.polynomial.polynomial.polyval(n - N_CENTRE, c))

    def normal(self, n: float, sf: float, der: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """The normal equations ``G theta = h`` of (Ae, eps, delta) at ``n`` (or their derivative in n)."""
        return _normal({k: self.at(k, n, der) for k in _FIT_SUMS}, sf)

    def sum_sq(self, n: float, theta, sf: float) -> float:
        """Sum of squared residuals at ``(n, theta)`` (never below 0: rounding)."""
        return _sum_sq({k: self.at(k, n) for k in _FIT_SUMS}, theta, sf)


def _normal(v: dict, sf: float) -> tuple[np.ndarray, np.ndarray]:
    """The normal equations ``G theta = h`` from the sums' values ``v`` (by name, floats)."""
    G = np.array([[v["pp1"], sf * v["pps"], sf * v["pq"]],
                  [sf * v["pps"], v["pps2"], v["psq"]],
                  [sf * v["pq"], v["psq"], v["qq"]]])
    return G, np.array([v["py"], sf * v["psy"], sf * v["qy"]])


def _sum_sq(v: dict, theta, sf: float) -> float:
    """Sum of squared residuals at ``theta`` from the sums' values ``v`` at one ``n`` (never below 0)."""
    G, h = _normal(v, sf)
    return max(float(theta @ G @ theta - 2 * theta @ h + v["yy"]), 0.0)


def _padded(polys: list) -> np.ndarray:
    """The polynomials as the rows of one array, each padded with zeros to the longest."""
    lens = np.fromiter(map(len, polys), np.intp, len(polys))
    C = np.zeros((len(polys), int(lens.max()) if len(polys) else 1))
    if len(polys):
        starts = np.cumsum(lens) - lens
        C[np.repeat(np.arange(len(polys)), lens), np.arange(int(lens.sum())) - np.repeat(starts, lens)] = \
            np.concatenate(polys)
    return C


def _values_each(parts: list[dict], names, n: float) -> dict[str, np.ndarray]:
    """Per name, each part's polynomial at ``n``: ``_Sums([part]).at(name, n)`` of every part at once
    (issue 26: one ``_Sums`` and ten ``polyval`` calls per test cost ~0.15 ms, 0.5 CPU-s a chamber at
    10,000 runs). numpy's ``polyval`` steps (Horner: ``c0 = c[-1] + x*0``, then ``c0 = c[-i] + c0*x``)
    element by element over the parts, a shorter polynomial padded with leading zero coefficients: each
    pad step gives 0 and the part's own top coefficient then ``c + 0*x``, as ``polyval`` starts: the
    same bits, part by part."""
    x = n - N_CENTRE
    out = {}
    for name in names:
        C = _padded([p[name] for p in parts])
        c0 = C[:, -1] + x * 0
        for j in range(2, C.shape[1] + 1):
            c0 = C[:, -j] + c0 * x
        out[name] = c0
    return out


def _solve(G, h):
    """``G theta = h`` with G scaled to unit diagonal (the columns' units span ten decades)."""
    dg = np.diag(G)
    if not np.all(dg > 0):
        raise np.linalg.LinAlgError("a column of the design is zero")
    sc = 1.0 / np.sqrt(dg)
    return sc * np.linalg.solve(G * sc[:, None] * sc[None, :], h * sc)


def _minimise_n(objective, gradient, lo: float, hi: float) -> float:
    """The n in [lo, hi] of the lowest minimum of a smooth 1-D objective: bracketed on a grid by a
    sign change of its gradient, then the gradient's root (Brent); a bound when no interior one."""
    grid = np.linspace(lo, hi, _N_GRID)
    g = np.array([gradient(x) for x in grid])
    cands = [float(brentq(gradient, grid[i], grid[i + 1], xtol=1e-15, maxiter=200))
             for i in range(len(grid) - 1) if g[i] < 0 <= g[i + 1]]
    cands += [lo] if g[0] >= 0 else []
    cands += [hi] if g[-1] <= 0 else []
    return min(cands, key=objective) if cands else lo


def _seed(stats: list[SpringStats], sums: _Sums) -> dict:
    """Seeds as in section 3.2 of the paper."""
    # Ae: static force over gauge pressure at mid-stroke
    ratios = [r.static_force_n / (r.p0_abs - r.p_atm) for r in stats
              if np.isfinite(r.static_force_n) and r.p0_abs - r.p_atm > 1e3]
    ae = float(np.median(ratios)) if ratios else 1e-3
    # n: the force-displacement curve with the elastic term only (Ae fixed at its seed)
    lo, hi = PARAM_BOUNDS[0][0], PARAM_BOUNDS[1][0]
    n = _minimise_n(lambda x: ae * ae * sums.at("pp1", x) - 2 * ae * sums.at("py", x) + sums.at("yy", x),
                    lambda x: ae * ae * sums.at("pp1", x, 1) - 2 * ae * sums.at("py", x, 1), lo, hi)
    # delta: loop area of the lowest-pressure tests, U = pi delta D^2
    good = [r for r in stats if np.isfinite(r.loop_energy_j)]
    if good:
        pmin = min(r.p0_abs for r in good)
        low = [r for r in good if r.p0_abs <= pmin + 0.25e5]
        delta = float(np.median([r.loop_energy_j / (np.pi * r.amplitude_m ** 2) for r in low]))
    else:
        delta = 1e3
    delta = max(delta, 1.0)
    # eps last: the loop area structural damping leaves, in the small-amplitude tests, over
    # the integral of (P - Pa)|dd| of the elastic model
    eps_vals = []
    if good:
        amin = min(r.amplitude_m for r in good)
        small = [r for r in good if r.amplitude_m <= amin * 1.05 and r.cycle]
        travel = _values_each([r.cycle for r in small], ("travel",), n)["travel"] if small else ()
        for r, work in zip(small, travel):
            travel_work = float(work) / r.cycles
            if travel_work > 0:
                eps_vals.append((r.loop_energy_j - np.pi * delta * r.amplitude_m ** 2) / travel_work)
    eps = float(np.median(eps_vals)) if eps_vals else 1e-5
    eps = max(eps, 1e-7)
    return {"n_polytropic": n, "ae_m2": ae, "epsilon_m2": eps, "delta_n_m": delta}


def _jtj(sums: _Sums, x, sf: float) -> np.ndarray:
    """``J^T J`` of the weighted residuals in (n, Ae, eps, delta) at ``x``, from the sums."""
    n, ae, eps, _ = x
    G, _h = sums.normal(n, sf)
    d = {k: sums.at(k, n, 1) for k in ("pp1", "pps", "pps2", "pq", "psq")}
    e2 = {k: sums.at(k, n, 2) / 4 for k in ("ee1", "ees", "ees2")}
    j = np.empty((4, 4))
    j[1:, 1:] = G
    j[0, 0] = ae * ae * e2["ee1"] + 2 * ae * sf * eps * e2["ees"] + eps * eps * e2["ees2"]
    j[0, 1] = 0.5 * (ae * d["pp1"] + sf * eps * d["pps"])
    j[0, 2] = 0.5 * (sf * ae * d["pps"] + eps * d["pps2"])
    j[0, 3] = sf * ae * d["pq"] + eps * d["psq"]
    j[1:, 0] = j[0, 1:]
    return j


def fit_spring_stats(stats: list[SpringStats]) -> SpringFit:
    """Fit ``n``, ``Ae``, ``eps``, ``delta`` of one chamber from its runs' sufficient statistics.

    Separable least squares (variable projection): for each ``n`` the linear parameters solve the
    normal equations; ``n`` is where the derivative of the profiled objective vanishes (the
    lowest minimum over n's bounds). Exact: the same optimum as a nonlinear least-squares fit of
    the samples, in time independent of the number of samples.

    Parameters
    ----------
    stats : list of SpringStats
        Of one chamber (from :func:`spring_run_stats`); unusable ones are skipped.

    Returns
    -------
    SpringFit
        As :func:`fit_spring_chamber`.
    """
    usable = sorted((r for r in stats if r.ok), key=lambda r: r.run_id)
    chamber = stats[0].chamber if stats else ""
    if not usable:
        return SpringFit(chamber, message="no usable run", note="no usable run")
    chamber, sf = usable[0].chamber, FORCE_SIGN[usable[0].chamber]
    sums = _Sums([r.fit for r in usable])
    seeds = _seed(usable, sums)
    lo, hi = (np.array(b, float) for b in PARAM_BOUNDS)

    def theta(n):
        return _solve(*sums.normal(n, sf))

    def gradient(n):   # d/dn of the profiled objective: dSS/dn at theta(n) (envelope theorem)
        th = theta(n)
        dG, dh = sums.normal(n, sf, der=1)
        return float(th @ dG @ th - 2 * th @ dh)

    n = _minimise_n(lambda v: sums.sum_sq(v, theta(v), sf), gradient, lo[0], hi[0])
    x = np.clip(np.concatenate([[n], theta(n)]), lo, hi)
    fit = SpringFit(chamber, *map(float, x), n_tests=len(usable), seeds=seeds)
    _per_test(fit, usable)
    names = ("n_polytropic", "ae_m2", "epsilon_m2", "delta_n_m")
    gate = Gate()
    gate.enough_points(len(usable), 1, "usable tests")
    gate.within_bounds(np.concatenate([[n], theta(n)]), lo, hi, names, rtol=1e-6)   # bounds span decades from 0
    n_obs = sum(r.n_fit for r in usable)
    se, cond = gram_se(_jtj(sums, x, sf), sums.sum_sq(x[0], x[1:], sf), n_obs - 4)
    gate.identifiable(cond=cond, beta=x, se=se, names=names)
    per = np.array([v for v in fit.nrmse_pct.values() if np.isfinite(v)])
    if per.size:
        noise_ok = not fit.test_notes      # every test within the limit or at its noise level
        pooled = float(np.sqrt(np.mean(per ** 2)))
        if not noise_ok and pooled > NRMSE_LIMIT_PCT:
            gate.fail(f"model misses the data (RMS of the tests' NRMSE {pooled:.2g} % > {NRMSE_LIMIT_PCT:g} %)")
    fit.se = dict(zip(names, map(float, se)))
    if not gate.ok:
        fit.note = gate.note
        fit.n_polytropic = fit.ae_m2 = fit.epsilon_m2 = fit.delta_n_m = float("nan")
    return fit


def _per_test(fit: SpringFit, usable: list[SpringStats]) -> None:
    """Each test's NRMSE, model loop energy and note: NRMSE within the stated limit, or force
    residuals at the load cell's noise."""
    sf = FORCE_SIGN[fit.chamber]
    th = np.array(fit.params[1:])
    n = fit.n_polytropic
    each = _values_each([r.all for r in usable], _FIT_SUMS, n)
    cyc = [r for r in usable if r.cycle and r.cycles] if fit.ok else []
    work = _values_each([r.cycle for r in cyc], ("cp1", "cps", "cq"), n) if cyc else {}
    at = {r.run_id: i for i, r in enumerate(cyc)}
    for i, r in enumerate(usable):
        rms = float(np.sqrt(_sum_sq({k: float(a[i]) for k, a in each.items()}, th, sf) / r.n_all))
        fit.nrmse_pct[r.run_id] = 100.0 * rms / r.f_span_n if r.f_span_n > 0 else float("nan")
        j = at.get(r.run_id)
        fit.model_loop_energy_j[r.run_id] = (float("nan") if j is None else _loop_energy(
            r.chamber, fit.params, r.cycles, *(float(work[k][j]) for k in ("cp1", "cps", "cq"))))
        g = Gate().follows_data(fit.nrmse_pct[r.run_id], NRMSE_LIMIT_PCT, rms=rms, noise=r.f_noise_n)
        if not g.ok:
            fit.test_notes[r.run_id] = g.note


def fit_spring_chamber(runs: list[SpringRun], max_samples_per_run: int | None = 4000) -> SpringFit:
    """Fit ``n``, ``Ae``, ``eps``, ``delta`` over all usable runs of one chamber.

    Parameters
    ----------
    runs : list of SpringRun
        Runs of one chamber (from :func:`prepare_spring_run`); unusable ones are skipped.
    max_samples_per_run : int, optional
        Longer runs are thinned (every k-th sample) for the fit; NRMSE uses every sample.

    Returns
    -------
    SpringFit
        Parameters (NaN with ``note`` when no run is usable or the fit fails a quality gate),
        the seeds, the standard errors ``se``, the NRMSE of every usable run [%] (kept when the
        parameters are NaN: the evidence), its model loop energy [J] and ``test_notes`` for runs
        the model misses. Computed by :func:`fit_spring_stats` from :func:`spring_run_stats`.
    """
    return fit_spring_stats([spring_run_stats(r, max_samples_per_run) for r in runs])


def spring_model_force(run: SpringRun, fit: SpringFit):
    """The fitted model's force over a run's samples. [N]"""
    return spring_force(run.d, run.v, run.p0_abs, run.frequency_hz, *fit.params, run.chamber, run.stroke_m, run.p_atm)


def spring_nrmse(run: SpringRun, fit: SpringFit) -> float:
    """NRMSE of the fitted model over one run's force (Table 3). [%]"""
    return nrmse_pct(run.f, spring_model_force(run, fit))


def model_loop_energy(run: SpringStats, fit: SpringFit) -> float:
    """Loop area of the fitted model over the run's whole cycles, from its sums. [J]"""
    if not run.cycle or not run.cycles or not fit.ok:
        return float("nan")
    c, n = _Sums([run.cycle]), fit.n_polytropic
    return _loop_energy(run.chamber, fit.params, run.cycles, c.at("cp1", n), c.at("cps", n), c.at("cq", n))


def _loop_energy(chamber: str, params, cycles: int, cp1: float, cps: float, cq: float) -> float:
    """:func:`model_loop_energy` from the run's cycle sums at the fit's ``n``. [J]"""
    sf = FORCE_SIGN[chamber]
    _, ae, eps, delta = params
    work = ae * cp1 + sf * eps * cps + sf * delta * cq
    return float(sf * work / cycles)
