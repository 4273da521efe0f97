"""How a raw file's columns become samples columns: canonical channels, units and names.

A column maps onto a canonical channel (:data:`schemas.channels.CHANNELS`) by a rig.toml
``[channels]`` entry or by its own name, in a unit of that channel's quantity; any other column
is kept as a non-canonical channel under its sanitised name with its unit. A column named like a
canonical channel in a unit of another dimension (``F`` in ``g``) is set aside as non-canonical
(:func:`set_aside_lookalikes`).
"""
from __future__ import annotations

from dataclasses import dataclass

from pipeline.ingest.result import IngestError
from pipeline.readers import RawColumn
from pipeline.readers.base import MAX_CHANNELS
from schemas.channels import CHANNELS, canonical_name, noncanonical_column, other_dimension, reserved_clash
from schemas.units import accepted_symbols, lookup_unit


@dataclass
class ColumnMap:
    """How one raw column becomes one samples column."""

    key: str
    column: str
    channel: str | None
    raw_name: str
    raw_unit: str | None
    unit: str | None          # unit of the stored values
    scale: float = 1.0        # rig.toml scale
    offset: float = 0.0       # rig.toml offset
    si_scale: float = 1.0     # unit conversion (see schemas.units.Unit.to_si)
    absolute: bool = False    # absolute pressure: subtract p_atm
    si_divisor: float | None = None
    numeric: bool = True
    reserved: str | None = None  # the reserved column name the channel's own name gave (it got ``x_``)

    def describe(self) -> dict:
        """The column as a ``channels`` table row (without ``run_id``)."""
        return {"column": self.column, "channel": self.channel, "raw_name": self.raw_name,
                "raw_unit": self.raw_unit, "unit": self.unit, "type": "DOUBLE" if self.numeric else "VARCHAR"}



def _rig_entry(col: RawColumn, channels_cfg: dict) -> dict | None:
    """The rig.toml ``[channels]`` entry of a raw column (as a table), or None."""
    # The bare name, name[unit], the header text exactly as written (`time(sec)`, `Time (s)`),
    # then the 1-based index (headerless files) and the reader's key.
    for key in (col.name, f"{col.name}[{col.unit}]" if col.unit else None, col.header, str(col.index), col.key):
        if key is not None and key in channels_cfg:
            entry = channels_cfg[key]
            return entry if isinstance(entry, dict) else {"channel": str(entry)}
    return None


def map_columns(columns: list[RawColumn], channels_cfg: dict) -> list[ColumnMap]:
    """Map raw columns onto canonical channels (rig.toml ``[channels]`` first, then names).

    Linear in the number of columns (a dict of names taken and, per sanitised name, the next
    free suffix); more than :data:`pipeline.readers.base.MAX_CHANNELS` columns are refused.
    """
    if len(columns) > MAX_CHANNELS:
        raise IngestError(f"{len(columns)} columns: more than the limit of {MAX_CHANNELS} channels per file")
    maps: list[ColumnMap] = []
    seen: dict[str, str] = {}
    next_suffix: dict[str, int] = {}   # sanitised name -> next suffix to try
    for col in columns:
        entry = _rig_entry(col, channels_cfg or {})
        name = col.name
        unit_text = col.unit
        scale, offset = 1.0, 0.0
        if entry is not None:
            name = str(entry.get("channel", name))
            unit_text = entry.get("unit", unit_text)
            try:
                scale = float(entry.get("scale", 1.0))
                offset = float(entry.get("offset", 0.0))
            except (TypeError, ValueError):
                raise IngestError(f"rig.toml scale/offset of column `{col.name}` is not a number") from None
        channel = canonical_name(name)
        label = f"`{col.name}`" if col.name == str(col.index) or not col.name else f"`{col.name}` (column {col.index})"
        if channel is None:
            column = noncanonical_column(name, unit_text)
            base, k = column, next_suffix.get(column, 2)
            while column in seen:  # "Foo Bar" and "foo-bar" both sanitise to foo_bar: keep both
                column, k = f"{base}_{k}", k + 1
            next_suffix[base] = k
            maps.append(ColumnMap(col.key, column, None, col.name, col.unit, unit_text, scale, offset,
                                  numeric=col.dtype != "string", reserved=reserved_clash(name, unit_text)))
        else:
            quantity = CHANNELS[channel].quantity
            if unit_text is None or str(unit_text).strip() == "":
                raise IngestError(f"no unit for channel `{channel}` in column {label} "
                                  f"(accepted: {', '.join(accepted_symbols(quantity))})")
            unit = lookup_unit(unit_text)
            if unit is None or unit.quantity != quantity:
                raise IngestError(f"unit `{unit_text}` not accepted for `{channel}` "
                                  f"(accepted: {', '.join(accepted_symbols(quantity))})")
            column = CHANNELS[channel].column
            maps.append(ColumnMap(col.key, column, channel, col.name, unit_text, CHANNELS[channel].si_unit,
                                  scale, offset, unit.scale, unit.absolute, unit.divisor))
        if column in seen:
            raise IngestError(f"channel `{channel or column}` appears twice (`{seen[column]}` and `{col.name}`)")
        seen[column] = col.name
    return maps


def map_export_columns(columns: list[RawColumn], channels_cfg: dict) -> tuple[list[ColumnMap], dict]:
    """Map an export's columns (:func:`map_columns`), look-alikes set aside first
    (:func:`set_aside_lookalikes`) and named by their raw name.

    Returns
    -------
    maps : list of ColumnMap
    lookalikes : dict
        Column key -> (raw name, canonical channel it looks like, raw unit).
    """
    raw_columns, lookalikes = set_aside_lookalikes(columns, channels_cfg)
    maps = map_columns(raw_columns, channels_cfg)
    for m in maps:
        if m.key in lookalikes:
            m.raw_name = lookalikes[m.key][0]
    return maps, lookalikes


# -- channels that only look canonical -------------------------------------------------------
def set_aside_lookalikes(columns: list[RawColumn], channels_cfg: dict) -> tuple[list[RawColumn], dict]:
    """Raw columns named like a canonical channel but recorded in a unit of another dimension.

    ``F`` in ``g`` is an accelerometer, not the force: without a rig.toml ``[channels]`` entry
    for it, such a column is renamed to its non-canonical column name (``f_g``) so that
    :func:`map_columns` keeps it as a non-canonical channel. Units in no table at all (a typo
    such as ``psig``) are not set aside: on a canonical name they stay an error.

    Returns
    -------
    columns : list of RawColumn
        The columns, look-alikes renamed.
    lookalikes : dict
        Column key -> (raw name, canonical channel it looks like, raw unit).
    """
    out, looks = [], {}
    for col in columns:
        channel = canonical_name(col.name)
        if channel is not None and _rig_entry(col, channels_cfg or {}) is None and other_dimension(col.unit):
            looks[col.key] = (col.name, channel, col.unit)
            col = RawColumn(key=col.key, name=noncanonical_column(col.name, col.unit), unit=col.unit,
                            index=col.index, dtype=col.dtype, header=col.header)
        out.append(col)
    return out, looks


def lookalike_hint(channel: str, looks: dict) -> str:
    """How to map a look-alike column as the missing canonical ``channel`` ("" when none looks like it)."""
    for raw_name, ch, unit in looks.values():
        if ch == channel:
            si = CHANNELS[channel].si_unit
            return (f"; column `{raw_name}` is in `{unit}`, not a {CHANNELS[channel].quantity}: if it is `{channel}`, "
                    f"map it in rig.toml: [channels.\"{raw_name}\"] channel = \"{channel}\" unit = \"{si}\"")
    return ""
