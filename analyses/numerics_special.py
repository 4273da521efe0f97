"""The normal distribution's tail and quantile as ``scipy.special`` computes them, without importing it.

``scipy.special.ndtr`` and ``ndtri`` are Cephes' rational approximations (Moshier 1989, carried into
scipy's ``xsf`` library): Horner evaluations of fixed coefficients, one ``exp``, ``log`` or ``sqrt`` of the
C library. Python floats are the same IEEE doubles and ``math.exp`` / ``math.log`` / ``math.sqrt`` the same
C library calls, so the same steps in the same order give the same bits (``tests/analyses/
test_numerics_special.py`` holds them to scipy's over 100,000+ points). A rebuild whose decision stage takes
every result from its memo needs only these (the stored designs' spending, ``alpha_spent``), and importing
``scipy.special`` for them cost ~0.1-0.3 CPU-s of every one-file change (issue 26, "the cost of a change").

References
----------
Moshier, S. L. (1989). Methods and Programs for Mathematical Functions. Ellis Horwood (the Cephes
library: ``ndtr.c``, ``ndtri.c``).
"""
from __future__ import annotations

import math

import numpy as np

# erf on [0, 1]: x T(x^2) / U(x^2); erfc on [1, 8): exp(-x^2) P(x) / Q(x); on [8, inf): exp(-x^2) R(x) / S(x)
_T = (9.60497373987051638749E0, 9.00260197203842689217E1, 2.23200534594684319226E3, 7.00332514112805075473E3,
      5.55923013010394962768E4)
_U = (3.35617141647503099647E1, 5.21357949780152679795E2, 4.59432382970980127987E3, 2.26290000613890934246E4,
      4.92673942608635921086E4)
_P = (2.46196981473530512524E-10, 5.64189564831068821977E-1, 7.46321056442269912687E0, 4.86371970985681366614E1,
      1.96520832956077098242E2, 5.26445194995477358631E2, 9.34528527171957607540E2, 1.02755188689515710272E3,
      5.57535335369399327526E2)
_Q = (1.32281951154744992508E1, 8.67072140885989742329E1, 3.54937778887819891062E2, 9.75708501743205489753E2,
      1.82390916687909736289E3, 2.24633760818710981792E3, 1.65666309194161350182E3, 5.57535340817727675546E2)
_R = (5.64189583547755073984E-1, 1.27536670759978104416E0, 5.01905042251180477414E0, 6.16021097993053585195E0,
      7.40974269950448939160E0, 2.97886665372100240670E0)
_S = (2.26052863220117276590E0, 9.39603524938001434673E0, 1.20489539808096656605E1, 1.70814450747565897222E1,
      9.60896809063285878198E0, 3.36907645100081516050E0)

# ndtri: |y - 1/2| <= 3/8; z = sqrt(-2 log y) in [2, 8); in [8, 64)
_P0 = (-5.99633501014107895267E1, 9.80010754185999661536E1, -5.66762857469070293439E1, 1.39312609387279679503E1,
       -1.23916583867381258016E0)
_Q0 = (1.95448858338141759834E0, 4.67627912898881538453E0, 8.63602421390890590575E1, -2.25462687854119370527E2,
       2.00260212380060660359E2, -8.20372256168333339912E1, 1.59056225126211695515E1, -1.18331621121330003142E0)
_P1 = (4.05544892305962419923E0, 3.15251094599893866154E1, 5.71628192246421288162E1, 4.40805073893200834700E1,
       1.46849561928858024014E1, 2.18663306850790267539E0, -1.40256079171354495875E-1, -3.50424626827848203418E-2,
       -8.57456785154685413611E-4)
_Q1 = (1.57799883256466749731E1, 4.53907635128879210584E1, 4.13172038254672030440E1, 1.50425385692907503408E1,
       2.50464946208309415979E0, -1.42182922854787788574E-1, -3.80806407691578277194E-2, -9.33259480895457427372E-4)
_P2 = (3.23774891776946035970E0, 6.91522889068984211695E0, 3.93881025292474443415E0, 1.33303460815807542389E0,
       2.01485389549179081538E-1, 1.23716634817820021358E-2, 3.01581553508235416007E-4, 2.65806974686737550832E-6,
       6.23974539184983293730E-9)
_Q2 = (6.02427039364742014255E0, 3.67983563856160859403E0, 1.37702099489081330271E0, 2.16236993594496635890E-1,
       1.34204006088543189037E-2, 3.28014464682127739104E-4, 2.89247864745380683936E-6, 6.79019408009981274425E-9)

_MAXLOG = 7.09782712893383996843E2      # log(DBL_MAX)
_SQRT1_2 = 0.70710678118654752440       # 1 / sqrt(2)
_SQRT2PI = 2.50662827463100050242       # sqrt(2 pi)
_EXP_M2 = 0.13533528323661269189        # exp(-2)


def _polevl(x: float, coef: tuple) -> float:
    """``coef[0] x^n + ... + coef[n]`` by Horner's rule (Cephes ``polevl``)."""
    ans = coef[0]
    for c in coef[1:]:
        ans = ans * x + c
    return ans


def _p1evl(x: float, coef: tuple) -> float:
    """``x^n + coef[0] x^(n-1) + ... + coef[n-1]``: :func:`_polevl` with a leading 1 (Cephes ``p1evl``)."""
    ans = x + coef[0]
    for c in coef[1:]:
        ans = ans * x + c
    return ans


def erf(x: float) -> float:
    """The error function, Cephes' (``scipy.special.erf``'s bits). [-]"""
    if math.isnan(x):
        return math.nan
    if x < 0.0:
        return -erf(-x)
    if x > 1.0:
        return 1.0 - erfc(x)
    z = x * x
    return x * _polevl(z, _T) / _p1evl(z, _U)


def erfc(a: float) -> float:
    """The complementary error function, Cephes' (``scipy.special.erfc``'s bits): 0 (2 for negative ``a``)
    where ``exp(-a^2)`` underflows. [-]"""
    if math.isnan(a):
        return math.nan
    x = -a if a < 0.0 else a
    if x < 1.0:
        return 1.0 - erf(a)
    z = -a * a
    if z >= -_MAXLOG:
        z = math.exp(z)
        if x < 8.0:
            p, q = _polevl(x, _P), _p1evl(x, _Q)
        else:
            p, q = _polevl(x, _R), _p1evl(x, _S)
        y = (z * p) / q
        if a < 0:
            y = 2.0 - y
        if y != 0.0:
            return y
    return 2.0 if a < 0 else 0.0


def ndtr_scalar(a: float) -> float:
    """P(Z <= a) of the standard normal, ``scipy.special.ndtr``'s bits. [-]"""
    a = float(a)
    if math.isnan(a):
        return math.nan
    x = a * _SQRT1_2
    z = abs(x)
    if z < 1.0:
        return 0.5 + 0.5 * erf(x)
    y = 0.5 * erfc(z)
    return 1.0 - y if x > 0 else y


def ndtri_scalar(y0: float) -> float:
    """The standard normal deviate with P(Z <= x) = ``y0``, ``scipy.special.ndtri``'s bits: -inf at 0, inf
    at 1, NaN outside [0, 1]. [-]"""
    y0 = float(y0)
    if y0 == 0.0:
        return -math.inf
    if y0 == 1.0:
        return math.inf
    if y0 < 0.0 or y0 > 1.0 or math.isnan(y0):
        return math.nan
    upper = True
    y = y0
    if y > 1.0 - _EXP_M2:
        y = 1.0 - y
        upper = False
    if y > _EXP_M2:
        y = y - 0.5
        y2 = y * y
        x = y + y * (y2 * _polevl(y2, _P0) / _p1evl(y2, _Q0))
        return x * _SQRT2PI
    x = math.sqrt(-2.0 * math.log(y))
    x0 = x - math.log(x) / x
    z = 1.0 / x
    if x < 8.0:
        x1 = z * _polevl(z, _P1) / _p1evl(z, _Q1)
    else:
        x1 = z * _polevl(z, _P2) / _p1evl(z, _Q2)
    x = x0 - x1
    return -x if upper else x


def _elementwise(func, x):
    """``func`` of every element of ``x`` as a float64 array of its shape (a 0-d input gives ``numpy.float64``),
    as a ufunc returns it after ``[()]``."""
    arr = np.asarray(x, dtype=float)
    if arr.ndim == 0:
        return np.float64(func(float(arr)))
    out = np.fromiter((func(v) for v in arr.ravel().tolist()), dtype=float, count=arr.size)
    return out.reshape(arr.shape)


def ndtr(x):
    """``scipy.special.ndtr(x)[()]``: P(Z <= x), elementwise, the same bits.

    Parameters
    ----------
    x : float or array_like
        Standard normal deviate. [-]

    Returns
    -------
    numpy.float64 or numpy.ndarray
        The lower tail. [-]
    """
    return _elementwise(ndtr_scalar, x)


def ndtri(q):
    """``scipy.special.ndtri(q)[()]``: the deviate of a lower-tail probability, elementwise, the same bits.

    Parameters
    ----------
    q : float or array_like
        Lower-tail probability. [-]

    Returns
    -------
    numpy.float64 or numpy.ndarray
        The deviate (-inf at 0, inf at 1, NaN outside [0, 1]). [-]
    """
    return _elementwise(ndtri_scalar, q)


# ---- the chi-square upper tail of integer degrees of freedom: Cephes' igamc (scipy's xsf), step for step ----

_MACHEP = 1.11022302462515654042E-16     # 2^-53
_LS2PI = 0.91893853320467274178          # log(sqrt(2 pi))
_IGAM_MAXITER = 2000
_IGAM_BIG = 4.503599627370496e15
_IGAM_BIGINV = 2.22044604925031308085e-16
_LANCZOS_G = 6.024680040776729583740234375
# lgam on [2, 3]: x B(x) / C(x); Stirling's series beyond 13: A
_GAMMA_A = (8.11614167470508450300E-4, -5.95061904284301438324E-4, 7.93650340457716943945E-4,
            -2.77777777730099687205E-3, 8.33333333333331927722E-2)
_GAMMA_B = (-1.37825152569120859100E3, -3.88016315134637840924E4, -3.31612992738871184744E5,
            -1.16237097492762307383E6, -1.72173700820839662146E6, -8.53555664245765465627E5)
_GAMMA_C = (-3.51815701436523470549E2, -1.70642106651881159223E4, -2.20528590553854454839E5,
            -1.13933444367982507207E6, -2.53252307177582951285E6, -2.01889141433532773231E6)
# Lanczos' sum, e^g scaled (N = 13, g above), numerator and denominator in x
_LANCZOS_NUM = (0.006061842346248906525783753964555936883222, 0.5098416655656676188125178644804694509993,
                19.51992788247617482847860966235652136208, 449.9445569063168119446858607650988409623,
                6955.999602515376140356310115515198987526, 75999.29304014542649875303443598909137092,
                601859.6171681098786670226533699352302507, 3481712.15498064590882071018964774556468,
                14605578.08768506808414169982791359218571, 43338889.32467613834773723740590533316085,
                86363131.28813859145546927288977868422342, 103794043.1163445451906271053616070238554,
                56906521.91347156388090791033559122686859)
_LANCZOS_DEN = (1.0, 66.0, 1925.0, 32670.0, 357423.0, 2637558.0, 13339535.0, 45995730.0, 105258076.0, 150917976.0,
                120543840.0, 39916800.0, 0.0)
# log1p on [1/sqrt(2), sqrt(2)): x - x^2/2 + x^3 LP(x) / LQ(x); expm1 on [-1/2, 1/2]: 2x EP(x^2) / (EQ(x^2) - x EP(x^2))
_LP = (4.5270000862445199635215E-5, 4.9854102823193375972212E-1, 6.5787325942061044846969E0,
       2.9911919328553073277375E1, 6.0949667980987787057556E1, 5.7112963590585538103336E1,
       2.0039553499201281259648E1)
_LQ = (1.5062909083469192043167E1, 8.3047565967967209469434E1, 2.2176239823732856465394E2,
       3.0909872225312059774938E2, 2.1642788614495947685003E2, 6.0118660497603843919306E1)
_EP = (1.2617719307481059087798E-4, 3.0299440770744196129956E-2, 9.9999999999999999991025E-1)
_EQ = (3.0019850513866445504159E-6, 2.5244834034968410419224E-3, 2.2726554820815502876593E-1,
       2.0000000000000000000897E0)
#: ``lgam1p(1/2)``, log Gamma(3/2), as scipy's ``lgam1p`` gives it (its Taylor series in Riemann's zeta values,
#: tested equal); the one value of that series a chi-square of integer degrees of freedom needs (one degree).
_LGAM1P_HALF = -0.12078223763524884


def _lgam(x: float) -> float:
    """log |Gamma(x)| for ``0 < x < 1000``, Cephes' ``lgam``: recurrence to [2, 3] below 13, Stirling above."""
    if x < 13.0:
        z, p, u = 1.0, 0.0, x
        while u >= 3.0:
            p -= 1.0
            u = x + p
            z *= u
        while u < 2.0:
            z /= u
            p += 1.0
            u = x + p
        if u == 2.0:
            return math.log(z)
        p -= 2.0
        x = x + p
        return math.log(z) + x * _polevl(x, _GAMMA_B) / _p1evl(x, _GAMMA_C)
    q = (x - 0.5) * math.log(x) - x + _LS2PI
    p = 1.0 / (x * x)
    return q + _polevl(p, _GAMMA_A) / x


def _lanczos_sum_expg_scaled(x: float) -> float:
    """Lanczos' sum scaled by e^g (Boost's, in Cephes' ``ratevl``: in 1/x above 1)."""
    if abs(x) > 1:
        y = 1 / x
        num, den = _LANCZOS_NUM[-1], _LANCZOS_DEN[-1]
        for c in _LANCZOS_NUM[-2::-1]:
            num = num * y + c
        for c in _LANCZOS_DEN[-2::-1]:
            den = den * y + c
        return 1.0 * num / den     # pow(x, 0) * num / den
    num, den = _LANCZOS_NUM[0], _LANCZOS_DEN[0]
    for c in _LANCZOS_NUM[1:]:
        num = num * x + c
    for c in _LANCZOS_DEN[1:]:
        den = den * x + c
    return num / den


def _log1pmx(x: float) -> float:
    """log(1 + x) - x (Cephes: a series below 1/2, else its ``log1p``)."""
    if abs(x) < 0.5:
        xfac, res = x, 0.0
        for n in range(2, 500):
            xfac *= -x
            term = xfac / n
            res += term
            if abs(term) < _MACHEP * abs(res):
                break
        return res
    z = 1.0 + x
    if z < _SQRT1_2 or z > 1.41421356237309504880:
        return math.log(z) - x
    z = x * x
    z = -0.5 * z + x * (z * _polevl(x, _LP) / _p1evl(x, _LQ))
    return (x + z) - x


def _expm1(x: float) -> float:
    """e^x - 1, Cephes' ``expm1`` (finite x)."""
    if x < -0.5 or x > 0.5:
        return math.exp(x) - 1.0
    xx = x * x
    r = x * _polevl(xx, _EP)
    r = r / (_polevl(xx, _EQ) - r)
    return r + r


def _igam_fac(a: float, x: float) -> float:
    """x^a e^-x / Gamma(a)."""
    if abs(a - x) > 0.4 * abs(a):
        ax = a * math.log(x) - x - _lgam(a)
        return 0.0 if ax < -_MAXLOG else math.exp(ax)
    fac = a + _LANCZOS_G - 0.5
    res = math.sqrt(fac / math.exp(1.0)) / _lanczos_sum_expg_scaled(a)
    if a < 200 and x < 200:
        return res * (math.exp(a - x) * math.pow(x / fac, a))
    num = x - a - _LANCZOS_G + 0.5
    return res * math.exp(a * _log1pmx(num / fac) + x * (0.5 - _LANCZOS_G) / fac)


def _igam_series(a: float, x: float) -> float:
    ax = _igam_fac(a, x)
    if ax == 0.0:
        return 0.0
    r, c, ans = a, 1.0, 1.0
    for _ in range(_IGAM_MAXITER):
        r += 1.0
        c *= x / r
        ans += c
        if c <= _MACHEP * ans:
            break
    return ans * ax / a


def _igamc_continued_fraction(a: float, x: float) -> float:
    ax = _igam_fac(a, x)
    if ax == 0.0:
        return 0.0
    y = 1.0 - a
    z = x + y + 1.0
    c = 0.0
    pkm2, qkm2 = 1.0, x
    pkm1 = x + 1.0
    qkm1 = z * x
    ans = pkm1 / qkm1
    for _ in range(_IGAM_MAXITER):
        c += 1.0
        y += 1.0
        z += 2.0
        yc = y * c
        pk = pkm1 * z - pkm2 * yc
        qk = qkm1 * z - qkm2 * yc
        if qk != 0:
            r = pk / qk
            t = abs((ans - r) / r)
            ans = r
        else:
            t = 1.0
        pkm2, pkm1, qkm2, qkm1 = pkm1, pk, qkm1, qk
        if abs(pk) > _IGAM_BIG:
            pkm2 *= _IGAM_BIGINV
            pkm1 *= _IGAM_BIGINV
            qkm2 *= _IGAM_BIGINV
            qkm1 *= _IGAM_BIGINV
        if t <= _MACHEP:
            break
    return ans * ax


def _igamc_series(a: float, x: float, lgam1p_a: float) -> float:
    fac, total = 1.0, 0.0
    for n in range(1, _IGAM_MAXITER):
        fac *= -x / n
        term = fac / (a + n)
        total += term
        if abs(term) <= _MACHEP * abs(total):
            break
    logx = math.log(x)
    return -_expm1(a * logx - lgam1p_a) - math.exp(a * logx - _lgam(a)) * total


def chi2_sf_integer(x: float, df: int) -> float | None:
    """P(X > x) of a chi-square of ``df`` degrees of freedom, ``scipy.special.chdtrc(df, x)``'s bits, for
    ``df`` an integer from 1 to 40 (``igamc(df / 2, x / 2)`` without its asymptotic series, which starts
    above 40); None for any other ``df`` (the caller asks scipy).

    Parameters
    ----------
    x : float
        The statistic. [-]
    df : int
        Degrees of freedom. [-]

    Returns
    -------
    float or None
        The upper tail [-] (1 for ``x <= 0``, NaN for NaN ``x``), or None outside the ported domain.
    """
    if not (float(df).is_integer() and 1 <= df <= 40):
        return None
    x = float(x)
    if math.isnan(x):
        return math.nan
    if x < 0.0:
        return 1.0
    a, x = df / 2.0, x / 2.0
    if x == 0:
        return 1.0
    if math.isinf(x):
        return 0.0
    if x > 1.1:
        return 1.0 - _igam_series(a, x) if x < a else _igamc_continued_fraction(a, x)
    if x <= 0.5:
        use_series = -0.4 / math.log(x) < a
    else:
        use_series = x * 1.1 < a
    if use_series:
        return 1.0 - _igam_series(a, x)
    if a == 0.5:
        lg1p = _LGAM1P_HALF
    elif a == 1.0:
        lg1p = 0.0    # log(1) + the Taylor series at 0
    else:
        lg1p = _lgam(a + 1.0)
    return _igamc_series(a, x, lg1p)
