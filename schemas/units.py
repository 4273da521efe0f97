"""The canonical unit table: which raw units are accepted and how they become SI.

One source of truth for readers, validation and docs. Every accepted raw unit maps to a
:class:`Unit` that converts a value to the SI unit of its quantity::

    si = value * scale + offset          (and for absolute pressures: - p_atm_pa)

Pressures are stored as gauge pressures [Pa]. A unit spelled ``bara``, ``bar(a)``, ``kPa(a)``
... is absolute and converted to gauge with the run's ``p_atm_pa``; ``barg``, ``bar(g)`` and the
plain units are gauge.

Flows are stored as mass flows [kg/s]. ``l/min`` is standard litres per minute at ANR reference
conditions (ISO 8778: 20 degC, 100 kPa, 65 % RH; rho = 1.185 kg/m3) and ``Nl/min`` is normal
litres per minute at DIN 1343 conditions (0 degC, 101.325 kPa; rho = 1.293 kg/m3).
"""
from __future__ import annotations

from dataclasses import dataclass

from schemas.sensors_text import sensor_part

#: Air density at ANR reference conditions (ISO 8778). [kg/m3]
RHO_ANR_KG_M3 = 1.185
#: Air density at DIN 1343 normal conditions. [kg/m3]
RHO_DIN1343_KG_M3 = 1.293
#: Standard atmosphere, the default ``p_atm_pa`` of a run. [Pa]
P_ATM_DEFAULT_PA = 101325.0
#: One litre per minute in cubic metres per second. [m3/s]
L_MIN_M3_S = 1e-3 / 60.0


@dataclass(frozen=True)
class Quantity:
    """A physical quantity: its SI unit and the suffix its warehouse columns carry."""

    name: str
    si_unit: str
    suffix: str


QUANTITIES: dict[str, Quantity] = {
    q.name: q
    for q in (
        Quantity("time", "s", "s"),
        Quantity("pressure", "Pa", "pa"),
        Quantity("length", "m", "m"),
        Quantity("force", "N", "n"),
        Quantity("mass_flow", "kg/s", "kg_s"),
        Quantity("voltage", "V", "v"),
    )
}


@dataclass(frozen=True)
class Unit:
    """An accepted raw unit.

    Attributes
    ----------
    symbol : str
        The unit as written in an export, e.g. ``"bar(a)"``.
    quantity : str
        Key of :data:`QUANTITIES`.
    scale : float
        Factor to the SI unit of the quantity.
    absolute : bool
        True for absolute pressures, converted to gauge with the run's atmospheric pressure.
    """

    symbol: str
    quantity: str
    scale: float
    absolute: bool = False

    @property
    def divisor(self) -> float | None:
        """For sub-units (mm, ms, mV, ...): the power of ten to divide by, else None.

        Dividing by 1e3 is correctly rounded where multiplying by 1e-3 is not
        (``10 * 1e-6 != 1e-5`` but ``10 / 1e6 == 1e-5``), so converted values equal their
        decimal literals.
        """
        if self.scale < 1.0:
            inv = round(1.0 / self.scale)
            if inv > 1 and abs(inv * self.scale - 1.0) < 1e-12:
                return float(inv)
        return None

    def to_si(self, values, p_atm_pa: float = P_ATM_DEFAULT_PA):
        """Convert raw values (scalar or numpy array) to SI (gauge for pressures)."""
        div = self.divisor
        out = values / div if div else (values * self.scale if self.scale != 1.0 else values)
        if self.absolute:
            out = out - p_atm_pa
        return out


def _build_table() -> dict[str, Unit]:
    table: dict[str, Unit] = {}

    def add(symbol, quantity, scale, absolute=False):
        table[symbol] = Unit(symbol, quantity, float(scale), absolute)

    for sym, scale in (("s", 1.0), ("ms", 1e-3), ("us", 1e-6), ("µs", 1e-6), ("μs", 1e-6)):
        add(sym, "time", scale)
    pressure = {"Pa": 1.0, "kPa": 1e3, "MPa": 1e6, "bar": 1e5, "mbar": 1e2, "psi": 6894.757293168361}
    for sym, scale in pressure.items():
        add(sym, "pressure", scale)
        add(f"{sym}(g)", "pressure", scale)
        add(f"{sym}(a)", "pressure", scale, absolute=True)
    for sym in ("bar", "mbar", "psi"):
        add(f"{sym}g", "pressure", pressure[sym])
        add(f"{sym}a", "pressure", pressure[sym], absolute=True)
    for sym, scale in (("m", 1.0), ("mm", 1e-3), ("um", 1e-6), ("µm", 1e-6), ("μm", 1e-6)):
        add(sym, "length", scale)
    for sym, scale in (("N", 1.0), ("kN", 1e3)):
        add(sym, "force", scale)
    add("kg/s", "mass_flow", 1.0)
    add("g/s", "mass_flow", 1e-3)
    add("l/min", "mass_flow", L_MIN_M3_S * RHO_ANR_KG_M3)
    add("Nl/min", "mass_flow", L_MIN_M3_S * RHO_DIN1343_KG_M3)
    for sym, scale in (("V", 1.0), ("mV", 1e-3)):
        add(sym, "voltage", scale)
    return table


#: Every accepted raw unit, by its exact spelling.
UNITS: dict[str, Unit] = _build_table()

# Case-insensitive spellings that name exactly one accepted unit ("kpa", "BAR(A)", "L/min").
_FOLDED: dict[str, Unit] = {}
for _unit in UNITS.values():
    _FOLDED.setdefault(_unit.symbol.casefold(), _unit)
for _key in [k for k in _FOLDED if sum(u.symbol.casefold() == k for u in UNITS.values()) > 1]:
    del _FOLDED[_key]


def normalise_unit_text(text: str | None) -> str:
    """Strip brackets and white space a DAQ puts around a unit: ``" [bar] "`` -> ``"bar"``."""
    if text is None:
        return ""
    text = str(text).strip()
    if len(text) >= 2 and text[0] + text[-1] in ("[]", "()", "{}") and text.count(text[0]) == 1:
        text = text[1:-1].strip()
    return text.replace(" ", "")


def lookup_unit(text: str | None) -> Unit | None:
    """The accepted :class:`Unit` spelled ``text``, or None if it is not accepted.

    Exact spellings win; a case-insensitive spelling is accepted when it names one unit only
    and keeps the case of an ``m`` / ``M`` prefix or symbol (``KPA`` is kPa, ``L/MIN`` is l/min,
    but ``mPa``, ``MV``, ``Mm`` and ``Ms`` are refused: milli and mega differ by case alone).
    """
    sym = normalise_unit_text(text)
    unit = UNITS.get(sym)
    if unit is not None:
        return unit
    unit = _FOLDED.get(sym.casefold())
    if unit is not None and (sym[:1] in "mM" or unit.symbol[:1] in "mM") and sym[:1] != unit.symbol[:1]:
        return None
    return unit


def accepted_symbols(quantity: str) -> list[str]:
    """The spellings accepted for a quantity, for error messages and docs."""
    return [u.symbol for u in UNITS.values() if u.quantity == quantity]


def kg_s_to_l_min_anr(q_kg_s):
    """Mass flow to standard litres per minute at ANR conditions (ISO 8778).

    Parameters
    ----------
    q_kg_s : float or array
        Mass flow. [kg/s]

    Returns
    -------
    float or array
        Volume flow at ANR reference conditions. [l/min]
    """
    return q_kg_s / (L_MIN_M3_S * RHO_ANR_KG_M3)


def pa_to_bar(p_pa):
    """Pressure in bar from pascal (gauge stays gauge). [bar]"""
    return p_pa / 1e5


def m_to_mm(x_m):
    """Length in millimetres from metres. [mm]"""
    return x_m * 1e3


# -- display: one convention for people (Parquet and warehouse columns stay SI) -------------------------

#: Units of warehouse column-name suffixes (a column's name ends in its unit; longest match wins):
#: suffix -> (unit, short unit). The long form is for ``describe`` and plots, the short one for
#: table headers. One table for the catalogue (``pipeline.serve.query``) and the report.
COLUMN_UNITS: dict[str, tuple[str, str]] = {
    s: (u if isinstance(u, str) else u[0], u if isinstance(u, str) else u[1]) for s, u in {
        "_pa": "Pa", "_bar": ("bar (gauge)", "bar"), "_bar_abs": ("bar (absolute)", "bar abs"), "_m": "m",
        "_mm": "mm", "_km": "km", "_n": "N", "_s": "s", "_h": "h", "_hz": "Hz", "_v": "V", "_pct": "%",
        "_kg": "kg", "_kg_s": "kg/s", "_m_s": "m/s", "_mm_s": "mm/s", "_m_s2": "m/s²", "_n_s": "N/s",
        "_n_s_m": "N s/m", "_n_m": "N/m", "_rad_s": "rad/s", "_m2": "m²", "_l_min": ("l/min (ANR)", "l/min"),
        "_m_v_s": "m/(V s)", "_j": "J", "_w": "W", "_degc": "°C", "_c": "°C", "_k": "K", "_bytes": "bytes",
        "_ns": "ns", "_kg_s_pa": "kg/(s Pa)", "_v_m": "V/m",
    }.items()}


def column_unit(column: str, short: bool = False) -> tuple[str, str] | None:
    """(suffix, unit) of the longest unit suffix ``column`` ends in, else None."""
    name = str(column).lower()
    best = max((s for s in COLUMN_UNITS if name.endswith(s) and len(name) > len(s)), key=len, default=None)
    return None if best is None else (best, COLUMN_UNITS[best][1 if short else 0])


#: How people see SI channels: SI column suffix -> (display column suffix, conversion of values).
#: Pressures in bar gauge, positions in mm, forces in N, flows in l/min ANR, times in s.
DISPLAY: dict[str, tuple[str, object]] = {
    "_pa": ("_bar", pa_to_bar),
    "_m": ("_mm", m_to_mm),
    "_kg_s": ("_l_min", kg_s_to_l_min_anr),
    "_n": ("_n", lambda v: v),
    "_s": ("_s", lambda v: v),
    "_v": ("_v", lambda v: v),
}


def to_display(column: str, values):
    """An SI column's values as people read them: ``(values, name, unit)``.

    ``p_a_pa`` -> (values in bar, ``"p_a"``, ``"bar (gauge)"``); a column without an SI suffix of
    :data:`DISPLAY` is returned as it is, with the unit of its suffix if any.
    """
    name = str(column)
    found = column_unit(name)
    if found is None:
        return values, name, ""
    suffix, unit = found
    if suffix in DISPLAY:
        shown, convert = DISPLAY[suffix]
        return convert(values), name[: -len(suffix)], COLUMN_UNITS[shown][0]
    return values, name[: -len(suffix)], unit


#: SI unit symbol -> the column suffix of its quantity (for SI values quoted in text).
_SI_SUFFIX = {q.si_unit: "_" + q.suffix for q in QUANTITIES.values()}


def display_sensors_text(text: str) -> str:
    """A ``sensors`` text of result rows in display units (read by :func:`schemas.sensors_text.sensor_part`).

    ``"p_supply: resolution 100, noise 40 (metadata) Pa; q_leak: ... kg/s"`` ->
    ``"p_supply: resolution 0.001 bar, noise 0.0004 bar (metadata); q_leak: ... l/min"``.
    A part that does not read that way, or whose unit has no display unit, is left as it is.
    """
    def one(part: str) -> str:
        read = sensor_part(part)
        suffix = _SI_SUFFIX.get(read[4]) if read is not None else None
        if suffix not in DISPLAY:
            return part.strip()
        name, res, noise, src, _ = read
        shown, convert = DISPLAY[suffix]
        unit = COLUMN_UNITS[shown][1]
        return f"{name}: resolution {float(convert(res)):.3g} {unit}, noise {float(convert(noise)):.3g} {unit} ({src})"

    return "; ".join(one(p) for p in str(text).split(";"))
