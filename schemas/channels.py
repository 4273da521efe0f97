"""Canonical channels: names, quantities, SI units and the warehouse column each becomes.

After ingest every canonical channel ``name`` is stored in SI under the column
``<name>_<unit suffix>`` (``p_a`` -> ``p_a_pa``, ``q_leak`` -> ``q_leak_kg_s``). The same column
names are used by the samples Parquet files, the ``samples_<kind>`` views, the simulator's
ground truth and the analyses, so a notebook can pass a warehouse query straight to an
analysis function.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

import pyarrow as pa

from schemas.units import QUANTITIES


@dataclass(frozen=True)
class Channel:
    """A canonical channel of bench-exports.md."""

    name: str
    quantity: str
    description: str

    @property
    def si_unit(self) -> str:
        return QUANTITIES[self.quantity].si_unit

    @property
    def column(self) -> str:
        """Warehouse column name: the channel name with its SI unit suffix."""
        return f"{self.name}_{QUANTITIES[self.quantity].suffix}"


CHANNELS: dict[str, Channel] = {
    c.name: c
    for c in (
        Channel("t", "time", "Time since run start."),
        Channel("p_a", "pressure", "PLPA chamber A pressure, gauge."),
        Channel("p_b", "pressure", "PLPA chamber B pressure, gauge."),
        Channel("p_supply", "pressure", "Pressure in the pressurised chamber (leakage tests), gauge."),
        Channel("p", "pressure", "PLA chamber pressure, gauge."),
        Channel("p_ref", "pressure", "Pressure set-point, gauge."),
        Channel("x", "length", "Carriage position."),
        Channel("x_ref", "length", "Carriage position reference."),
        Channel("d", "length", "PLA rod displacement (+ = extension)."),
        Channel("f", "force", "Force at the load cell."),
        Channel("q_leak", "mass_flow", "Leakage flow."),
        Channel("u", "voltage", "Valve command."),
        Channel("u_d", "voltage", "Disturbance added to the valve command."),
    )
}

#: Warehouse column of every canonical channel, e.g. ``COLUMN["p_a"] == "p_a_pa"``.
COLUMN: dict[str, str] = {name: c.column for name, c in CHANNELS.items()}

_CANONICAL_FOLDED = {name.casefold(): name for name in CHANNELS}


def canonical_name(raw_name: str) -> str | None:
    """The canonical channel a raw name denotes (case-insensitive), or None."""
    return _CANONICAL_FOLDED.get(str(raw_name).strip().casefold())


_SANITISE = re.compile(r"[^0-9a-z]+")
#: Columns the samples views and the ``samples()`` macro add to a samples file's own
#: (``pipeline.warehouse``): ``run_id``, ``kind``, ``campaign``, and DuckDB's ``filename`` (the
#: file each row comes from, which they join on). No channel may be stored under one of them.
VIEW_COLUMNS = frozenset({"run_id", "kind", "campaign", "filename"})
_RESERVED = set(VIEW_COLUMNS) | set(COLUMN.values())


def sanitise_name(raw_name: str) -> str:
    """Column name for a non-canonical channel: lower case, ``[0-9a-z_]`` only.

    Names that would collide with a canonical column or a column the samples views add
    (:data:`VIEW_COLUMNS`) get an ``x_`` prefix, so a channel called ``Kind``, ``FileName`` or
    ``x_m`` can never shadow real data.
    """
    name = _SANITISE.sub("_", str(raw_name).strip().casefold()).strip("_") or "channel"
    if name[0].isdigit():
        name = f"c_{name}"
    if name in _RESERVED:
        name = f"x_{name}"
    return name


_UNIT_WORDS = (("%", "pct"), ("°", "deg"), ("µ", "u"), ("μ", "u"), ("Ω", "ohm"), ("²", "2"), ("³", "3"),
               ("^", ""), ("/", "_"))


def unit_suffix(unit: str | None) -> str:
    """Column suffix of a raw unit: lower case ``[0-9a-z_]``, ``%`` -> ``pct``, ``°`` -> ``deg``,
    ``µ`` -> ``u``, ``/`` -> ``_``, ``^`` dropped (``"degC"`` -> ``"degc"``, ``"m/s^2"`` ->
    ``"m_s2"``, ``"%"`` -> ``"pct"``); empty when there is no unit."""
    text = str(unit or "").strip()
    for a, b in _UNIT_WORDS:
        text = text.replace(a, b)
    return _SANITISE.sub("_", text.casefold()).strip("_")


def noncanonical_column(raw_name: str, unit: str | None) -> str:
    """Warehouse column of a non-canonical channel: ``<sanitised name>_<unit suffix>``.

    Warehouse columns end in their unit (``valve_temp[degC]`` -> ``valve_temp_degc``,
    ``F[g]`` -> ``f_g``, ``rel_humidity[%]`` -> ``rel_humidity_pct``). A name that already ends
    in its suffix keeps it once (``valve_temp_degc[degC]`` -> ``valve_temp_degc``); a channel
    without a unit keeps its sanitised name alone.
    """
    name = sanitise_name(raw_name)
    suffix = unit_suffix(unit)
    if not suffix or name == suffix or name.endswith(f"_{suffix}"):
        return name
    column = f"{name}_{suffix}"
    return f"x_{column}" if column in _RESERVED else column


def reserved_clash(raw_name: str, unit: str | None) -> str | None:
    """The reserved column (canonical or :data:`VIEW_COLUMNS`) that :func:`noncanonical_column`
    kept the channel ``raw_name`` [``unit``] out of with its ``x_`` prefix, or None."""
    name = _SANITISE.sub("_", str(raw_name).strip().casefold()).strip("_") or "channel"
    if name[0].isdigit():
        name = f"c_{name}"
    if name in _RESERVED:
        return name
    suffix = unit_suffix(unit)
    column = f"{name}_{suffix}"
    return column if suffix and name != suffix and not name.endswith(f"_{suffix}") and column in _RESERVED else None


#: Units of a dimension no canonical channel has (acceleration, temperature, angle, current,
#: frequency, speed, mass, ratio, ...). A raw name that looks canonical (``F``) recorded in one
#: of these (``g``) is another sensor (an accelerometer): ingest keeps it as a non-canonical
#: channel instead of refusing the file. Units in no table at all stay errors on canonical names.
OTHER_DIMENSION_UNITS = frozenset(u.casefold() for u in (
    "g", "m/s2", "m/s^2", "m/s²", "mm/s2", "mm/s^2", "degC", "°C", "C", "degF", "°F", "K", "%", "pct",
    "%RH", "deg", "°", "rad", "rad/s", "deg/s", "rpm", "Hz", "kHz", "A", "mA", "uA", "Ohm", "kOhm",
    "m/s", "mm/s", "um/s", "kg", "g/min", "Nm", "N.m", "mN.m", "W", "kW", "J", "counts", "count",
    "cnt", "1", "-", "ratio", "m3/s", "m^3/s", "l", "ml", "mm2", "m2", "lux", "dB",
))


def other_dimension(unit: str | None) -> bool:
    """Whether ``unit`` is a unit of a dimension no canonical channel has (see
    :data:`OTHER_DIMENSION_UNITS`)."""
    return unit is not None and str(unit).strip().replace(" ", "").casefold() in OTHER_DIMENSION_UNITS


def arrow_field(name: str, unit: str | None, description: str, nullable: bool = True) -> pa.Field:
    """A float64 Arrow field carrying its unit and description in the field metadata."""
    meta = {"unit": unit or "", "description": description}
    return pa.field(name, pa.float64(), nullable=nullable, metadata=meta)


def channel_field(name: str) -> pa.Field:
    """Arrow field of a canonical channel, in SI, as stored after ingest."""
    ch = CHANNELS[name]
    return arrow_field(ch.column, ch.si_unit, ch.description, nullable=name != "t")
