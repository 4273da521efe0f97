"""analyses.numerics_iir: scipy.signal's Butterworth design and zero-phase filtering to the bit, Welch's
PSD to 1e-12 of its peak, and what the filters must do (unit DC gain, a slow sine through, a fast one out)."""
import numpy as np
import pytest
import scipy.signal

from analyses.numerics_iir import butter_lowpass_sos, sosfiltfilt, sosfiltfilt2, welch_psd


@pytest.mark.parametrize("fs", [100.0, 977.3, 2500.0])
@pytest.mark.parametrize("order", [2, 4, 6])
def test_butter_gives_scipys_bits(order, fs):
    for fc in np.geomspace(0.499 * fs, 1e-4 * fs, 25):
        assert np.array_equal(butter_lowpass_sos(order, fc, fs), scipy.signal.butter(order, fc, fs=fs, output="sos"))


def test_butter_refuses_odd_orders_and_cutoffs_outside_nyquist():
    with pytest.raises(ValueError):
        butter_lowpass_sos(3, 10.0, 100.0)
    with pytest.raises(ValueError):
        butter_lowpass_sos(4, 50.0, 100.0)
    with pytest.raises(ValueError):
        butter_lowpass_sos(4, 0.0, 100.0)


def test_sosfiltfilt_gives_scipys_bits():
    rng = np.random.default_rng(3)
    for _ in range(12):
        n = int(rng.integers(40, 4000))
        x = np.cumsum(rng.normal(size=n)) + 0.1 * rng.normal(size=n)
        order = int(rng.choice([2, 4, 6]))
        sos = scipy.signal.butter(order, float(rng.uniform(0.5, 400.0)), fs=1000.0, output="sos")
        if n <= 3 * (2 * len(sos) + 1):
            continue
        assert np.array_equal(sosfiltfilt(sos, x), scipy.signal.sosfiltfilt(sos, x))


def test_sosfiltfilt_passes_dc_and_slow_motion_and_removes_fast():
    fs, n = 1000.0, 4000
    t = np.arange(n) / fs
    sos = butter_lowpass_sos(4, 20.0, fs)
    assert np.allclose(sosfiltfilt(sos, np.full(n, 3.5)), 3.5, rtol=0, atol=1e-12)
    slow, fast = np.sin(2 * np.pi * 1.0 * t), np.sin(2 * np.pi * 200.0 * t)
    y = sosfiltfilt(sos, slow + fast)
    inner = slice(200, -200)  # away from the edges' transients
    assert np.max(np.abs(y[inner] - slow[inner])) < 1e-3  # zero phase: no delay of the slow sine
    with pytest.raises(ValueError):
        sosfiltfilt(sos, np.zeros(15))


def test_welch_is_scipys_estimate():
    rng = np.random.default_rng(5)
    for n, fs in ((16, 100.0), (1000, 100.0), (10717, 500.0), (20000, 1000.0)):
        x = 0.1 * np.sin(2 * np.pi * 2.0 * np.arange(n) / fs) + 1e-5 * rng.normal(size=n) + 0.3 * np.arange(n) / n
        nper = int(min(n, 2 ** int(np.ceil(np.log2(max(16, min(n, 16 * fs)))))))
        f_ref, p_ref = scipy.signal.welch(x, fs=fs, nperseg=nper, detrend="linear")
        f, p = welch_psd(x, fs, nper)
        assert np.array_equal(f, f_ref)
        assert np.max(np.abs(p - p_ref)) <= 1e-12 * np.max(p_ref)


def test_welch_finds_a_tone_and_the_white_noise_level():
    fs, n = 1000.0, 64000
    rng = np.random.default_rng(7)
    sigma = 0.01
    x = np.sin(2 * np.pi * 50.0 * np.arange(n) / fs) + sigma * rng.normal(size=n)
    f, p = welch_psd(x, fs, 1024)
    assert abs(f[np.argmax(p)] - 50.0) <= fs / 1024
    floor = np.median(p[(f > 200) & (f < 450)])
    assert floor == pytest.approx(2 * sigma ** 2 / fs, rel=0.1)  # one-sided density of white noise


def test_butter_of_order_2_gives_scipys_bits_and_is_a_low_pass():
    import scipy.signal

    rng = np.random.default_rng(26)
    for fs in (100.0, 1000.0, 2000.0, 512.3, 1e4, 3.7):
        for cutoff in np.concatenate([[1e-5 * fs, 0.1 * fs, 0.25 * fs, 0.4999 * fs], rng.uniform(1e-4, 0.4999, 60) * fs]):
            assert np.array_equal(butter_lowpass_sos(2, cutoff, fs),
                                  scipy.signal.butter(2, cutoff, fs=fs, output="sos")), (cutoff, fs)
    # a low-pass: unit gain at DC, a double zero at Nyquist (b = b0 [1, 2, 1])
    sos = butter_lowpass_sos(2, 10.0, 1000.0)[0]
    assert sos[:3].sum() / sos[3:].sum() == pytest.approx(1.0, rel=1e-12)
    np.testing.assert_allclose(sos[:3] / sos[0], [1.0, 2.0, 1.0], rtol=1e-15)
    for bad in (0.0, 500.0, -1.0, 600.0):
        with pytest.raises(ValueError):
            butter_lowpass_sos(2, bad, 1000.0)


@pytest.mark.parametrize("n", [17, 29, 30, 31, 400, 21000])
def test_sosfiltfilt2_gives_scipys_bits(n):
    import scipy.signal

    rng = np.random.default_rng(n)
    x = np.cumsum(rng.standard_normal(n)) + (np.arange(n) > n // 2)
    for cutoff in (1.0, 37.3, 120.0, 399.0):
        sos = butter_lowpass_sos(2, cutoff, 1000.0)
        for padtype in ("odd", "constant"):
            for padlen in {0, 1, min(n - 1, 3 * int(1000.0 / cutoff))}:
                expected = scipy.signal.sosfiltfilt(sos, x, padtype=padtype, padlen=padlen)
                assert np.array_equal(sosfiltfilt2(sos, x, padtype, padlen), expected), (cutoff, padtype, padlen)
    # a constant passes unchanged (the steady state from sosfilt_zi: no start-up transient)
    np.testing.assert_allclose(sosfiltfilt2(butter_lowpass_sos(2, 5.0, 1000.0), np.full(n, 3.25), "odd", min(n - 1, 50)),
                               3.25, rtol=1e-12)
    with pytest.raises(ValueError):
        sosfiltfilt2(butter_lowpass_sos(2, 5.0, 1000.0), x, "odd", n)
    with pytest.raises(ValueError):
        sosfiltfilt2(butter_lowpass_sos(2, 5.0, 1000.0), x, "even", 3)
