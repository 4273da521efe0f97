"""Test kinds: the channels and metadata each kind needs, and the Arrow schema of its samples.

The table of bench-exports.md ("Test kinds") in code. Readers, validation, the simulator and
the docs all read it from here.
"""
from __future__ import annotations

import math
import re
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
class Plausible:
    """The physical range a stated value must lie in (both ends included), in ``unit``."""

    low: float
    high: float
    unit: str
    why: str

    def range_text(self) -> str:
        return f"{self.low:g} to {self.high:g} {self.unit}"


#: Plausible ranges of stated values: a value outside quarantines its run with one line naming the
#: key and the range (docs/inputs.md, "Plausible values"). The one table of them: metadata keys in
#: the unit of :data:`META_KEYS`, sensor resolution / noise (``sensor:<quantity>``) in SI. Each is
#: wide enough for any real lab (physics, not our simulator), and catches a unit slip of 100x or
#: more. Keys not here (``z_rollers_mm``, ``spring_force_n``, ``kp_v_m``, ``t0_s``: their sign is a
#: rig's convention) are only checked to be finite numbers.
PLAUSIBLE: dict[str, Plausible] = {
    "p_atm_pa": Plausible(50e3, 110e3, "Pa", "ambient air pressure from 5,400 m altitude (Everest base camp, "
                          "about 53 kPa) to below sea level (Dead Sea shore about 107 kPa, record high 108.4 kPa); "
                          "hPa written as Pa is 100 times too small"),
    "temperature_c": Plausible(-100.0, 250.0, "degC", "any lab or climate chamber: below the coldest air on Earth "
                               "(-89 degC) to above the 200 degC that elastomer hoses stand; kelvin is out"),
    "hose_area_m2": Plausible(1e-7, 1.0, "m2", "a 0.36 mm bore (micro tubing) to a 1.1 m bore (large air bellows); "
                              "mm2 or cm2 written as m2 are out"),
    "backpressure_bar": Plausible(-1.1, 100.0, "bar", "gauge: a full vacuum (-1.01 bar at sea level, -1.1 bar at "
                                  "110 kPa ambient) to 2.5 times the 40 bar of high-pressure compressed air; kPa or "
                                  "Pa written as bar are out"),
    "p0_bar_abs": Plausible(0.0, 101.0, "bar", "absolute: a vacuum to 100 bar gauge (the backpressure_bar range)"),
    "force_rate_n_s": Plausible(1e-3, 1e6, "N/s", "drive-force ramps from 1 N in 17 minutes to 10 kN in 10 ms "
                                "(faster is an impact, not a ramp)"),
    "sample_rate_hz": Plausible(1e-4, 1e9, "Hz", "one sample every 3 hours (a slow logger) to 1 GS/s (a fast "
                                "digitiser)"),
    "id_sample_rate_hz": Plausible(1e-4, 1e9, "Hz", "as sample_rate_hz"),
    "dt_s": Plausible(1e-9, 1e4, "s", "the sample intervals of the sample_rate_hz range"),
    "frequency_hz": Plausible(1e-4, 1e4, "Hz", "one cycle every 3 hours to the 10 kHz of electrodynamic shakers"),
    "amplitude_mm": Plausible(1e-4, 1e4, "mm", "0.1 um (a piezo stage) to 10 m (more than any actuator's stroke)"),
    "stroke_mm": Plausible(0.1, 1e4, "mm", "0.1 mm to 10 m (the longest rodless cylinders run about 6 m)"),
    "sensor:time": Plausible(0.0, 60.0, "s", "a time stamp coarser than a minute cannot time a test"),
    "sensor:pressure": Plausible(0.0, 1e5, "Pa", "1 bar is 1 % of a 100 bar sensor's span: a coarser sensor cannot "
                                 "measure compressed air"),
    "sensor:length": Plausible(0.0, 0.1, "m", "10 cm is coarser than any bench's position sensor; a bare number is "
                               "metres (5 meant as 5 um is out)"),
    "sensor:force": Plausible(0.0, 1e4, "N", "10 kN is 1 % of a 1 MN load cell's span"),
    "sensor:mass_flow": Plausible(0.0, 1.0, "kg/s", "1 kg/s is about 50,000 l/min (ANR), beyond the span of any "
                                  "leak or supply flow meter"),
    "sensor:voltage": Plausible(0.0, 100.0, "V", "control signals span 10 V, supplies 48 V"),
}


def implausible(key: str, value: float) -> str | None:
    """``"<value> <unit> is outside its plausible range <low> to <high> <unit> (<why>)"`` when a stated
    value lies outside its :data:`PLAUSIBLE` range, else None (also for keys without a range)."""
    spec = PLAUSIBLE.get(key)
    if spec is None or isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    if spec.low <= value <= spec.high:
        return None
    return f"{value:g} {spec.unit} is outside its plausible range {spec.range_text()} ({spec.why})"

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


#: A number with `,` digit grouping (`1,250`, `1,250,000`): 1.25 with a decimal comma, or 1250.
_GROUPED_COMMA = re.compile(r"^[+-]?[1-9]\d{0,2}(,\d{3})+$")


def coerce_value(key: str, value):
    """Type a metadata value by :data:`META_KEYS`. Raises ValueError with a short reason."""
    spec = META_KEYS.get(key)
    if spec is None or value is None:
        return value
    if spec.type == "float":
        if isinstance(value, bool):
            raise ValueError(f"`{key}` must be a number, got {value!r}")
        if isinstance(value, str) and _GROUPED_COMMA.match(value.strip()):
            text = value.strip()
            if text.count(",") > 1:
                raise ValueError(f"`{key}` = {value!r} has thousands separators: write it without digit grouping "
                                 f"({text.replace(',', '')})")
            raise ValueError(f"`{key}` = {value!r} reads as {float(text.replace(',', '.')):g} with a decimal comma "
                             f"or {text.replace(',', '')} with a thousands separator: write it without digit grouping "
                             "(or with a decimal point)")
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
           "missing_metadata", "missing_channels", "REQUIRED_METADATA", "PLAUSIBLE", "Plausible", "implausible"]
