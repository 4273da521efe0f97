"""Butterworth low-pass design, zero-phase filtering and Welch's PSD without importing ``scipy.signal``.

A rebuild after one changed viscous run analyses that run by inverse dynamics
(:mod:`analyses.friction_dynamic`): one Welch spectrum for the cut-off, a handful of order-4
Butterworth filters run forwards and backwards; one after a changed step run one second-order
filter (:func:`sosfiltfilt2`, with ``sosfiltfilt``'s constant or odd padding, for
:mod:`analyses.step_response`). Importing ``scipy.signal`` for them (it imports
scipy.stats, optimize, interpolate, spatial, ndimage and parses some 800 docstrings) cost about a
second of CPU of such a rebuild, some twenty times the computation (issue 26, the cost of a
change). The filter design and the filtering are scipy's own steps (``butter``'s analog
prototype, pre-warped bilinear transform and ``zpk2sos`` pairing; ``sosfiltfilt``'s odd extension,
``sosfilt_zi`` steady state and the C recursion of ``sosfilt``) and give its bits
(``tests/analyses/test_numerics_iir.py``); the Welch spectrum is the same estimate by numpy's FFT
(within 1e-12 of scipy's, relative to the spectrum's peak).

References
----------
Butterworth, S. (1930). On the theory of filter amplifiers. Experimental Wireless 7, 536-541.
Welch, P. D. (1967). The use of fast Fourier transform for the estimation of power spectra.
IEEE Transactions on Audio and Electroacoustics 15(2), 70-73.
"""
from __future__ import annotations

import numpy as np


def butter_lowpass_sos(order: int, cutoff_hz: float, fs_hz: float) -> np.ndarray:
    """Second-order sections of a digital Butterworth low-pass of even ``order``: the bits of
    ``scipy.signal.butter(order, cutoff_hz, fs=fs_hz, output="sos")``.

    Parameters
    ----------
    order : int
        Filter order, even and positive. [-]
    cutoff_hz : float
        -3 dB frequency, ``0 < cutoff_hz < fs_hz / 2``. [Hz]
    fs_hz : float
        Sampling frequency. [Hz]

    Returns
    -------
    ndarray
        Shape ``(order // 2, 6)``: ``b0, b1, b2, 1, a1, a2`` per section, the gain in the first,
        the poles nearest the unit circle in the last. [-]
    """
    n = int(order)
    if n <= 0 or n % 2:
        raise ValueError(f"order {order!r} is not even and positive")
    wn = np.asarray(cutoff_hz, dtype=np.float64) / (float(fs_hz) / 2)
    if not 0 < wn < 1:
        raise ValueError(f"cutoff {cutoff_hz!r} Hz is not inside (0, fs/2) for fs = {fs_hz!r} Hz")
    wo = float(2 * 2.0 * np.tan(np.pi * wn / 2.0))  # pre-warped, fs = 2
    p = -np.exp(1j * np.pi * np.arange(-n + 1, n, 2, dtype=np.float64) / (2 * n))  # buttap
    z = np.asarray([], dtype=np.float64)
    k = 1.0 * wo ** n  # lp2lp_zpk
    z, p = wo * z, wo * p
    k = k * np.real(np.prod(4.0 - z) / np.prod(4.0 - p))  # bilinear_zpk
    p = (4.0 + p) / (4.0 - p)
    zeros = -np.ones(n)  # the analog zeros at infinity, at Nyquist
    return _zpk2sos_conjugate_poles(zeros, p, k)


def _zpk2sos_conjugate_poles(z: np.ndarray, p: np.ndarray, k) -> np.ndarray:
    """``scipy.signal.zpk2sos(z, p, k)`` (pairing "nearest", digital) for real zeros and poles in
    conjugate pairs, as many as zeros: the pole nearest the unit circle first, paired with the
    nearest zeros, its section last."""
    p = _conjugate_halves(p)
    n_sections = len(z) // 2
    sos = np.zeros((n_sections, 6))
    for si in range(n_sections - 1, -1, -1):
        i = np.argmin(np.abs(1 - np.abs(p)))
        p1 = p[i]
        p = np.delete(p, i)
        i = np.argsort(np.abs(z - p1))[0]
        z1 = z[i]
        z = np.delete(z, i)
        order = np.argsort(np.abs(z - p1))
        i = order[np.nonzero(np.isreal(z[order]))[0][0]]
        z2 = z[i]
        z = np.delete(z, i)
        sos[si, :3] = np.multiply(np.asarray([1.0]), _poly(np.asarray([z1, z2])))
        sos[si, 3:] = _poly(np.asarray([p1, p1.conj()]))
    sos[0][:3] *= np.asarray(k).real
    return sos


def _conjugate_halves(z: np.ndarray) -> np.ndarray:
    """One of each conjugate pair of ``z`` (none real), their parts averaged: scipy's ``_cplxreal``."""
    tol = 100 * np.finfo((1.0 * z).dtype).eps
    z = z[np.lexsort((abs(z.imag), z.real))]
    if np.any(abs(z.imag) <= tol * abs(z)):
        raise ValueError("a real pole: only conjugate pairs are handled")
    zp, zn = z[z.imag > 0], z[z.imag < 0]
    same_real = np.diff(zp.real) <= tol * abs(zp[:-1])
    diffs = np.diff(np.concatenate(([0], same_real, [0])))
    for start, stop in zip(np.nonzero(diffs > 0)[0], np.nonzero(diffs < 0)[0] + 1):
        for chunk in (zp[start:stop], zn[start:stop]):
            chunk[...] = chunk[np.lexsort([abs(chunk.imag)])]
    return (zp + zn.conj()) / 2


def _poly(roots: np.ndarray) -> np.ndarray:
    """The monic polynomial with these roots as scipy forms it (real for conjugate pairs)."""
    a = np.ones((1,), dtype=roots.dtype)
    one = np.ones_like(roots[0])
    for zero in roots:
        a = np.convolve(a, np.stack((one, -zero)), mode="full")
    if np.iscomplexobj(a):
        a = np.asarray(np.real(a), copy=True)
    return a


def sosfiltfilt(sos: np.ndarray, x) -> np.ndarray:
    """Zero-phase filtering by second-order sections, forward then backward: the bits of
    ``scipy.signal.sosfiltfilt(sos, x)`` (odd extension by ``3 (2 n_sections + 1)`` samples less the
    sections without a second-order term, each section's steady state, ``sosfilt``'s recursion).

    Parameters
    ----------
    sos : ndarray
        Shape ``(n_sections, 6)``, ``a0 = 1`` (:func:`butter_lowpass_sos`). [-]
    x : array_like
        Evenly sampled signal, 1-D, longer than the extension. [any unit]

    Returns
    -------
    ndarray
        The filtered signal, as long as ``x``. [unit of x]
    """
    sos = np.asarray(sos, dtype=np.float64)
    x = np.asarray(x, dtype=np.float64)
    n_sections = sos.shape[0]
    ntaps = 2 * n_sections + 1 - min((sos[:, 2] == 0).sum(), (sos[:, 5] == 0).sum())
    edge = ntaps * 3
    if x.shape[-1] <= edge:
        raise ValueError(f"The length of the input vector x must be greater than padlen, which is {edge}.")
    ext = np.concatenate((2 * x[:1] - x[edge:0:-1], x, 2 * x[-1:] - x[-2:-(edge + 2):-1]))
    zi = _sosfilt_zi(sos)
    y = _sosfilt(sos, ext, zi * ext[:1])
    y = _sosfilt(sos, y[::-1], zi * y[-1:])[::-1]
    return y[edge:-edge]


def _sosfilt_zi(sos: np.ndarray) -> np.ndarray:
    """Each section's state for a unit step's steady state, scaled by the gain before it:
    ``scipy.signal.sosfilt_zi`` (``lfilter_zi``'s linear solve)."""
    zi = np.empty((sos.shape[0], 2))
    scale = 1.0
    for s in range(sos.shape[0]):
        b, a = sos[s, :3], sos[s, 3:]
        if a[0] != 1.0:
            b, a = b / a[0], a / a[0]
        companion_t = np.array([[-a[1] / (1.0 * a[0]), 1.0], [-a[2] / (1.0 * a[0]), 0.0]])
        zi[s, ...] = scale * np.linalg.solve(np.eye(2) - companion_t, b[1:] - a[1:] * b[0])
        scale *= np.sum(b) / np.sum(a)
    return zi


def _sosfilt(sos: np.ndarray, x: np.ndarray, zi: np.ndarray) -> np.ndarray:
    """The sections over ``x`` from the states ``zi``: scipy's C loop (``_sosfilt``), sample by
    sample through every section, its operations in its order."""
    coeffs = [tuple(float(v) for v in s) for s in sos]
    state = [[float(v) for v in z] for z in zi]
    out = []
    append = out.append
    if len(coeffs) == 2:  # the order-4 filters of friction_dynamic: the two sections unrolled
        (b0, b1, b2, _, a1, a2), (c0, c1, c2, _, d1, d2) = coeffs
        (z0, z1), (w0, w1) = state
        for xc in x.tolist():
            xn = b0 * xc + z0
            z0 = b1 * xc - a1 * xn + z1
            z1 = b2 * xc - a2 * xn
            yn = c0 * xn + w0
            w0 = c1 * xn - d1 * yn + w1
            w1 = c2 * xn - d2 * yn
            append(yn)
        return np.asarray(out, dtype=np.float64)
    for xc in x.tolist():
        for s, (b0, b1, b2, _, a1, a2) in enumerate(coeffs):
            z = state[s]
            xn = b0 * xc + z[0]
            z[0] = b1 * xc - a1 * xn + z[1]
            z[1] = b2 * xc - a2 * xn
            xc = xn
        append(xc)
    return np.asarray(out, dtype=np.float64)


def welch_psd(x, fs_hz: float, nperseg: int) -> tuple[np.ndarray, np.ndarray]:
    """One-sided power spectral density by Welch's method: periodic Hann windows of ``nperseg``
    samples overlapping by half, each segment's least-squares line removed, periodograms averaged.
    The estimate of ``scipy.signal.welch(x, fs=fs_hz, nperseg=nperseg, detrend="linear")``
    (frequencies the same bits, densities within 1e-12 of its peak).

    Parameters
    ----------
    x : array_like
        Evenly sampled signal, 1-D, at least ``nperseg`` samples. [any unit]
    fs_hz : float
        Sampling frequency. [Hz]
    nperseg : int
        Segment length. [samples]

    Returns
    -------
    (ndarray, ndarray)
        Frequencies [Hz] and the density [unit of x squared / Hz].
    """
    x = np.asarray(x, dtype=np.float64)
    nperseg = int(nperseg)
    if not 1 <= nperseg <= x.size:
        raise ValueError(f"nperseg {nperseg} is not within 1..{x.size}")
    hop = nperseg - nperseg // 2
    n_seg = (x.size - nperseg // 2) // hop
    win = 0.5 - 0.5 * np.cos(2.0 * np.pi * np.arange(nperseg) / nperseg)
    segs = np.lib.stride_tricks.sliding_window_view(x, nperseg)[::hop][:n_seg]
    t = np.arange(nperseg, dtype=np.float64)
    design = np.column_stack([t, np.ones(nperseg)])
    coef = np.linalg.lstsq(design, segs.T, rcond=None)[0]
    detrended = segs - (design @ coef).T
    spec = np.fft.rfft(detrended * win, axis=-1)
    pxx = (spec.real ** 2 + spec.imag ** 2) / (float(fs_hz) * np.sum(win ** 2))
    pxx[:, 1:-1 if nperseg % 2 == 0 else None] *= 2
    return np.fft.rfftfreq(nperseg, 1 / fs_hz), pxx.mean(axis=0)


def sosfiltfilt2(sos: np.ndarray, x, padtype: str, padlen: int) -> np.ndarray:
    """Zero-phase filtering by one second-order section, forward then backward: the bits of
    ``scipy.signal.sosfiltfilt(sos, x, padtype=padtype, padlen=padlen)`` (its odd or constant
    extension, ``sosfilt_zi``'s steady state by the same linear solve, the C recursion of
    ``sosfilt`` in the same order of operations) without importing ``scipy.signal``.

    Parameters
    ----------
    sos : ndarray
        Shape (1, 6), ``a0 = 1`` (:func:`butter_lowpass_sos` of order 2). [-]
    x : array_like
        Evenly sampled signal, longer than ``padlen``. [any unit]
    padtype : {"odd", "constant"}
        How the ends are extended.
    padlen : int
        Samples added at each end. [samples]

    Returns
    -------
    ndarray
        The filtered signal, as long as ``x``. [unit of x]
    """
    x = np.asarray(x, dtype=np.float64)
    if len(x) <= padlen:
        raise ValueError(f"the signal ({len(x)} samples) must be longer than padlen ({padlen})")
    ext = x
    if padlen > 0:
        if padtype == "odd":
            ext = np.concatenate((2 * x[:1] - x[padlen:0:-1], x, 2 * x[-1:] - x[-2:-(padlen + 2):-1]))
        elif padtype == "constant":
            ones = np.ones(padlen, dtype=x.dtype)
            ext = np.concatenate((ones * x[:1], x, ones * x[-1:]))
        else:
            raise ValueError(f"padtype {padtype!r} is not 'odd' or 'constant'")
    b, a = sos[0, :3], sos[0, 3:]
    companion_t = np.array([[-a[1] / (1.0 * a[0]), 1.0], [-a[2] / (1.0 * a[0]), 0.0]])
    zi = 1.0 * np.linalg.solve(np.eye(2) - companion_t, b[1:] - a[1:] * b[0])
    y = _sosfilt2(sos[0], ext, zi * ext[0])
    y = _sosfilt2(sos[0], y[::-1], zi * y[-1])[::-1]
    return y[padlen:-padlen] if padlen > 0 else y


def _sosfilt2(s: np.ndarray, x: np.ndarray, zi: np.ndarray) -> np.ndarray:
    """One second-order section over ``x`` from the state ``zi``: ``scipy.signal``'s C loop
    (``_sosfilt``), its operations in its order."""
    b0, b1, b2, _, a1, a2 = (float(v) for v in s)
    z0, z1 = float(zi[0]), float(zi[1])
    out = []
    append = out.append
    for xc in x.tolist():
        xn = b0 * xc + z0
        z0 = b1 * xc - a1 * xn + z1
        z1 = b2 * xc - a2 * xn
        append(xn)
    return np.asarray(out, dtype=np.float64)


__all__ = ["butter_lowpass_sos", "sosfiltfilt", "sosfiltfilt2", "welch_psd"]
