"""Test kinds: the channels and metadata each kind needs, and the Arrow schema of its samples.

The table of bench-exports.md ("Test kinds") in code. Readers, validation, the simulator and
the docs all read it from here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import pyarrow as pa

from schemas.channels import CHANNELS, COLUMN, arrow_field, channel_field
from schemas.kind_names import KIND_NAMES


@dataclass(frozen=True)
class MetaKey:
    """A metadata key whose value pneubench interprets.

    ``type`` is ``"str"``, ``"float"`` or ``"enum"`` (one of ``choices``, matched
    case-insensitively and stored in the spelling of ``choices``), or ``"name"`` (any text; a
    value that matches one of ``choices`` case-insensitively is stored in its spelling).
    """

    name: str
    type: str
    description: str
    choices: tuple[str, ...] = ()
    default: object = None


META_KEYS: dict[str, MetaKey] = {
    k.name: k
    for k in (
        MetaKey("kind", "enum", "Test kind.", choices=()),  # choices filled below
        MetaKey("run_id", "str", "Unique run identifier; default <campaign>/<file stem>."),
        MetaKey("started_at", "str", "Start of the run, ISO 8601 (no offset = UTC)."),
        MetaKey("rig", "str", "The bench, e.g. plpa-1."),
        MetaKey("operator", "str", "Who ran the test."),
        MetaKey("notes", "str", "Free text."),
        MetaKey("p_atm_pa", "float", "Atmospheric pressure, for absolute pressure units. [Pa]", default=101325.0),
        MetaKey("temperature_c", "float", "Ambient temperature. [degC]"),
        MetaKey("hose_id", "str", "The hose under test."),
        MetaKey("chamber", "name", "Chamber: A/B (PLPA), front/rear (PLA), or any name another rig gives it "
                "(a kind's analysis may need one of its own, e.g. spring: front/rear).",
                choices=("A", "B", "front", "rear")),
        MetaKey("valve_id", "str", "The valve under test (e.g. a ventilator's pinch valve)."),
        MetaKey("age_h", "float", "Hours of use of the part under test (valve_id, else hose_id) at the run. [h]"),
        MetaKey("distance_km", "float",
                "Distance run by the part under test (valve_id, else hose_id) at the run. [km]"),
        MetaKey("adjustment", "enum", "How the rollers are set.", choices=("distance", "force")),
        MetaKey("z_rollers_mm", "float", "Roller distance setting. [mm]"),
        MetaKey("spring_force_n", "float", "Roller spring force setting. [N]"),
        MetaKey("direction", "enum", "P: driven by A toward +x; N: driven by B toward -x.", choices=("P", "N")),
        MetaKey("backpressure_bar", "float", "Backpressure in the passive chamber, gauge. [bar]"),
        MetaKey("force_rate_n_s", "float", "Rate at which the drive force is ramped. [N/s]"),
        MetaKey("hose_area_m2", "float", "Hose cross-section. [m2]"),
        MetaKey("kp_v_m", "float", "Gain of the stabilising P controller. [V/m]"),
        MetaKey("id_sample_rate_hz", "float", "Identification sample rate. [Hz]", default=50.0),
        MetaKey("amplitude_mm", "float", "Harmonic displacement amplitude. [mm]"),
        MetaKey("frequency_hz", "float", "Harmonic displacement frequency. [Hz]"),
        MetaKey("stroke_mm", "float", "PLA stroke. [mm]", default=40.0),
        MetaKey("p0_bar_abs", "float", "Initial absolute chamber pressure of a spring test. [bar]"),
        MetaKey("group", "str", "TDMS group holding the channels."),
        MetaKey("sample_rate_hz", "float", "Sample rate of an export without a time column. [Hz]"),
        MetaKey("dt_s", "float", "Sample interval of an export without a time column. [s]"),
        MetaKey("t0_s", "float", "Time of the first sample of an export without a time column. [s]"),
    )
}


@dataclass(frozen=True)
class KindSpec:
    """One row of the "Test kinds" table.

    Attributes
    ----------
    channel_sets : tuple of tuple of str
        Alternatives: a run must carry every channel of at least one set.
    metadata : tuple of str
        Keys every run of this kind needs.
    conditional : tuple of (str, str, str)
        ``(key, when_key, when_value)``: ``key`` is needed when ``when_key`` has
        ``when_value``; ``when_key == "channels"`` tests whether ``when_value`` is a channel.
    """

    name: str
    rig: str
    channel_sets: tuple[tuple[str, ...], ...]
    metadata: tuple[str, ...] = ()
    conditional: tuple[tuple[str, str, str], ...] = ()
    chambers: tuple[str, ...] = ()
    description: str = ""

    @property
    def channels(self) -> tuple[str, ...]:
        """Every channel named by any alternative, in table order."""
        seen: list[str] = []
        for s in self.channel_sets:
            seen += [c for c in s if c not in seen]
        return tuple(seen)


KINDS: dict[str, KindSpec] = {
    k.name: k
    for k in (
        KindSpec("leakage", "PLPA", (("t", "p_supply", "q_leak"),),
                 ("chamber", "adjustment"),
                 (("z_rollers_mm", "adjustment", "distance"), ("spring_force_n", "adjustment", "force")),
                 chambers=("A", "B"), description="Leakage between chambers vs pressure."),
        KindSpec("breakaway", "PLPA", (("t", "p_a", "p_b", "x"),),
                 ("direction", "backpressure_bar", "force_rate_n_s", "hose_area_m2"),
                 description="Static friction: pressure ramp until the carriage moves."),
        KindSpec("viscous", "PLPA", (("t", "x", "p_a", "p_b"), ("t", "x", "f")),
                 ("backpressure_bar",), (("hose_area_m2", "channels", "p_a"),),
                 description="Constant-velocity passes for the friction-velocity curve."),
        KindSpec("identification", "PLPA", (("t", "x", "u", "u_d", "x_ref"),), ("kp_v_m",),
                 description="Closed-loop identification with persistent excitation."),
        KindSpec("step", "PLPA", (("t", "x", "x_ref"),), description="Closed-loop position step."),
        KindSpec("spring", "PLA", (("t", "d", "f", "p"),),
                 ("chamber", "amplitude_mm", "frequency_hz"), chambers=("front", "rear"),
                 description="Closed pressurised chamber under harmonic displacement."),
        KindSpec("pressure_step", "PLA", (("t", "p", "p_ref"),), ("chamber",),
                 description="Pressure response to set-point steps (any chamber name; valve_id or hose_id, "
                             "age_h, distance_km optional)."),
        KindSpec("durability", "PLPA", (("t", "x", "p_a", "p_b"),), ("hose_id",),
                 description="Long back-and-forth strokes for hose service life."),
        KindSpec("timeseries", "any", (("t",),), description="Any export: catalogued, no analysis."),
    )
}

object.__setattr__(META_KEYS["kind"], "choices", tuple(KINDS))

#: Metadata every run needs, whatever its kind.
REQUIRED_METADATA = ("kind", "run_id", "started_at", "rig")


def coerce_value(key: str, value):
    """Type a metadata value by :data:`META_KEYS`. Raises ValueError with a short reason."""
    spec = META_KEYS.get(key)
    if spec is None or value is None:
        return value
    if spec.type == "float":
        if isinstance(value, bool):
            raise ValueError(f"`{key}` must be a number, got {value!r}")
        try:
            out = float(str(value).strip().replace(",", ".")) if isinstance(value, str) else float(value)
        except (TypeError, ValueError):
            raise ValueError(f"`{key}` must be a number, got {value!r}") from None
        if not math.isfinite(out):
            raise ValueError(f"`{key}` must be a finite number, got {value!r}")
        return out
    if spec.type == "enum" and spec.choices:
        text = str(value).strip()
        for choice in spec.choices:
            if text.casefold() == choice.casefold():
                return choice
        raise ValueError(f"`{key}` must be one of {', '.join(spec.choices)}, got {value!r}")
    if spec.type == "name":
        text = str(value).strip()
        return next((c for c in spec.choices if c.casefold() == text.casefold()), text)
    if spec.type == "str":
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        return str(value).strip()
    return value


def missing_metadata(kind: str, meta: dict, channels: set[str]) -> list[str]:
    """Keys this run of ``kind`` needs and does not have (empty strings count as missing)."""
    spec = KINDS[kind]
    need = list(REQUIRED_METADATA) + list(spec.metadata)
    for key, when, value in spec.conditional:
        if (when == "channels" and value in channels) or (when != "channels" and meta.get(when) == value):
            need.append(key)
    return [k for k in need if meta.get(k) is None or (isinstance(meta.get(k), str) and not meta[k].strip())]


def missing_channels(kind: str, channels: set[str]) -> list[str]:
    """Channels missing for the closest alternative of ``kind`` (empty if one is complete)."""
    spec = KINDS[kind]
    gaps = [[c for c in s if c not in channels] for s in spec.channel_sets]
    return min(gaps, key=len)


def samples_schema(canonical: list[str], extra: list[tuple] | None = None) -> pa.Schema:
    """Arrow schema of an ingested run's samples.

    Parameters
    ----------
    canonical : list of str
        Canonical channels present (``"t"`` is always first).
    extra : list of (column, unit) or (column, unit, arrow type)
        Non-canonical channels, by sanitised column name and raw unit (float64 unless a
        type is given).
    """
    fields = [pa.field("run_id", pa.dictionary(pa.int32(), pa.string()), nullable=False,
                       metadata={"description": "Run identifier."})]
    names = ["t"] + [c for c in CHANNELS if c in canonical and c != "t"]
    fields += [channel_field(c) for c in names]
    for col, unit, *typ in extra or []:
        f = arrow_field(col, unit, "Non-canonical channel, kept as recorded (unit not converted).")
        fields.append(f.with_type(typ[0]) if typ else f)
    return pa.schema(fields)


if tuple(KINDS) != KIND_NAMES:  # pragma: no cover - a kind added in one place only
    raise ImportError(f"schemas.kind_names.KIND_NAMES {KIND_NAMES} differs from the kinds defined here {tuple(KINDS)}")


__all__ = ["KINDS", "META_KEYS", "KindSpec", "MetaKey", "COLUMN", "samples_schema", "coerce_value",
           "missing_metadata", "missing_channels", "REQUIRED_METADATA"]
