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
_RESERVED = {"run_id", "kind", "campaign"} | set(COLUMN.values())


def sanitise_name(raw_name: str) -> str:
    """Column name for a non-canonical channel: lower case, ``[0-9a-z_]`` only.

    Names that would collide with a canonical column or a partition column get an ``x_``
    prefix, so a channel called ``Kind`` or ``x_m`` can never shadow real data.
    """
    name = _SANITISE.sub("_", str(raw_name).strip().casefold()).strip("_") or "channel"
    if name[0].isdigit():
        name = f"c_{name}"
    if name in _RESERVED:
        name = f"x_{name}"
    return name


def arrow_field(name: str, unit: str | None, description: str, nullable: bool = True) -> pa.Field:
    """A float64 Arrow field carrying its unit and description in the field metadata."""
    meta = {"unit": unit or "", "description": description}
    return pa.field(name, pa.float64(), nullable=nullable, metadata=meta)


def channel_field(name: str) -> pa.Field:
    """Arrow field of a canonical channel, in SI, as stored after ingest."""
    ch = CHANNELS[name]
    return arrow_field(ch.column, ch.si_unit, ch.description, nullable=name != "t")
