"""The normal's tail and quantile and the chi-square's upper tail without scipy: scipy.special's bits."""

import numpy as np
import pytest
import scipy.special

from analyses.numerics import chi2_sf, norm_isf, norm_sf, two_sided_z
from analyses.numerics_special import _LGAM1P_HALF, chi2_sf_integer, erf, erfc, ndtr, ndtri
from tests.fresh import loaded_after


def _same(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    return bool(np.all((a == b) | (np.isnan(a) & np.isnan(b))))


def test_ndtr_erf_erfc_give_scipys_bits_over_200000_points():
    rng = np.random.default_rng(11)
    x = np.concatenate([rng.normal(0, 3, 100_000), rng.uniform(-40, 40, 100_000), np.linspace(-10, 10, 2001),
                        [0.0, -0.0, 1.0, -1.0, np.sqrt(2), -np.sqrt(2), 8 * np.sqrt(2), 37.5, 38.5, -38.5,
                         np.inf, -np.inf, np.nan]])
    assert _same(ndtr(x), scipy.special.ndtr(x))
    assert _same([erf(v) for v in x[::7]], scipy.special.erf(x[::7]))
    assert _same([erfc(v) for v in x[::7]], scipy.special.erfc(x[::7]))


def test_ndtri_gives_scipys_bits_over_200000_points_and_its_edges():
    rng = np.random.default_rng(12)
    q = np.concatenate([rng.uniform(0, 1, 100_000), 10.0 ** rng.uniform(-300, 0, 100_000),
                        1 - 10.0 ** rng.uniform(-16, 0, 5000),
                        [0.0, 1.0, -0.1, 1.1, np.nan, 0.5, 0.025, 0.975, 5e-324, np.exp(-2), 1 - np.exp(-2),
                         np.exp(-32)]])
    assert _same(ndtri(q), scipy.special.ndtri(q))
    assert ndtri(0.0) == -np.inf and ndtri(1.0) == np.inf and np.isnan(ndtri(-0.1))


def test_shapes_and_types_are_a_ufuncs():
    assert type(ndtr(0.3)) is np.float64 and type(norm_isf(0.05)) is np.float64
    assert ndtr(np.zeros((2, 3))).shape == (2, 3) and ndtri(np.array([])).shape == (0,)
    t = np.linspace(0.01, 1, 100)
    assert _same(norm_sf(norm_isf(0.025) / np.sqrt(t)), scipy.special.ndtr(scipy.special.ndtri(0.025) / np.sqrt(t)))


@pytest.mark.parametrize("df", range(1, 41))
def test_chi2_sf_of_integer_df_gives_scipys_bits(df):
    rng = np.random.default_rng(df)
    x = np.concatenate([rng.uniform(0, 5, 1000), rng.uniform(0, 3 * df + 20, 1000), 10 ** rng.uniform(-8, 3.2, 800),
                        [0.0, 1e-300, 0.5, 1.0, 2.0, 2.2, df, 0.9 * df, 1.1 * df, 2.0 * df, 400.0, 401.0, 1e4, np.inf]])
    assert _same([chi2_sf_integer(v, df) for v in x], scipy.special.chdtrc(df, x))
    assert _same([chi2_sf(v, df) for v in x[::10]], scipy.special.chdtrc(df, x[::10]))


def test_chi2_sf_outside_the_port_still_asks_scipy():
    assert chi2_sf_integer(3.0, 2.5) is None and chi2_sf_integer(3.0, 41) is None
    assert chi2_sf(3.0, 2.5) == scipy.special.chdtrc(2.5, 3.0) and chi2_sf(50.0, 60) == scipy.special.chdtrc(60, 50.0)
    assert _LGAM1P_HALF == scipy.special._ufuncs._lgam1p(0.5)


def test_two_sided_z_of_any_confidence_is_ndtri():
    for c in np.linspace(0.001, 0.999, 999):
        assert two_sided_z(float(c)) == float(scipy.special.ndtri(0.5 + float(c) / 2))


def test_the_normal_and_chi2_helpers_import_no_scipy_special():
    code = ("import numpy as np; from analyses.numerics import norm_sf, norm_isf, chi2_sf, two_sided_z; "
            "from analyses.sequential_boundaries import alpha_spent; "
            "norm_sf(np.ones(3)); norm_isf(0.05); chi2_sf(3.1, 4); two_sided_z(0.93); alpha_spent(np.ones(3) / 2)")
    assert loaded_after(code, ("scipy.special",)) == []
