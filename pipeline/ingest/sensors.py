"""Sensor resolution and noise of a run, in SI: from rig.toml ``[sensors]`` and run metadata.

Stored under ``sensor_<channel>_resolution`` / ``sensor_<channel>_noise`` in the run's params,
where :class:`analyses.quality.Sensor` reads them.
"""
from __future__ import annotations

import math
import re

from pipeline.ingest.result import IngestError
from schemas.channels import CHANNELS, canonical_name
from schemas.kinds import implausible
from schemas.units import accepted_symbols, lookup_unit

SENSOR_FIELDS = ("resolution", "noise")
_SENSOR_KEY = re.compile(r"^sensor_(?P<channel>.+)_(?P<what>resolution|noise)$", re.IGNORECASE)
_NUMBER_UNIT = re.compile(r"^\s*(?P<num>[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*(?P<unit>\S.*)?$")


def sensor_value_si(value, channel: str, what: str, where: str) -> float:
    """A sensor resolution or noise (``"5 um"``, ``"0.01 bar"``, or a number in the channel's SI
    unit) -> float in SI. A pressure step or noise is a difference: no gauge offset.

    Zero is allowed and means what :class:`analyses.quality.Sensor` means by it: a resolution of 0
    is a sensor that is not quantised (an analog sensor), a noise of 0 an ideal signal (a
    commanded set-point). Raises IngestError naming ``where`` when the value is negative, not
    finite, or not a quantity of the channel's dimension.
    """
    quantity = CHANNELS[channel].quantity
    si = CHANNELS[channel].si_unit
    if isinstance(value, bool):
        raise IngestError(f"{where}: {what} must be a number or a number with a unit, got {value!r}")
    if isinstance(value, (int, float)):
        v, scale = float(value), 1.0
    else:
        m = _NUMBER_UNIT.match(str(value))
        if not m:
            raise IngestError(f"{where}: {what} {value!r} is not a number with a unit (e.g. \"5 um\")")
        v, unit_text = float(m.group("num")), m.group("unit")
        scale = 1.0
        if unit_text:
            unit = lookup_unit(unit_text)
            if unit is None or unit.quantity != quantity:
                raise IngestError(f"{where}: unit `{unit_text}` is not a {quantity} unit "
                                  f"(accepted: {', '.join(accepted_symbols(quantity))})")
            scale = unit.scale
    if not math.isfinite(v) or v < 0:
        raise IngestError(f"{where}: {what} must be zero or positive and finite, got {value!r}")
    out = v * scale
    div = round(1.0 / scale) if scale < 1.0 else 0
    if div > 1 and abs(div * scale - 1.0) < 1e-12:
        out = v / div        # 5 um -> 5e-06 exactly as the literal
    if not math.isfinite(out) or out < 0:
        raise IngestError(f"{where}: {what} must be zero or positive and finite in {si}, got {value!r}")
    why = implausible(f"sensor:{quantity}", out)
    if why is not None:
        raise IngestError(f"{where}: {what} {why}")
    return out


def resolve_sensors(sensors_cfg: dict, meta: dict, present: set[str]) -> tuple[dict, list[str]]:
    """Sensor resolution / noise of a run, in SI, under ``sensor_<channel>_resolution|noise``.

    Sources: run metadata keys ``sensor_<channel>_resolution`` / ``_noise`` (any channel
    spelling, case-insensitive) override rig.toml ``[sensors.<channel>]``; rig.toml values are
    kept only for channels the run has.

    Returns
    -------
    params : dict
        ``{"set": {sensor key: SI float}, "drop": [metadata keys as spelled, replaced by "set"]}``
    warnings : list of str
    """
    out: dict = {}
    warnings: list[str] = []
    for name, table in sorted((sensors_cfg or {}).items()):
        channel = canonical_name(name)
        if not isinstance(table, dict):
            raise IngestError(f"rig.toml [sensors.{name}] must be a table with `resolution` and/or `noise`")
        if channel is None:
            warnings.append(f"rig.toml [sensors.{name}] ignored: `{name}` is not a canonical channel")
            continue
        unknown = sorted(set(table) - set(SENSOR_FIELDS))
        if unknown:
            raise IngestError(f"rig.toml [sensors.{name}]: unknown key(s) {', '.join(unknown)} "
                              f"(expected {', '.join(SENSOR_FIELDS)})")
        for what in SENSOR_FIELDS:
            if what in table:
                v = sensor_value_si(table[what], channel, what, f"rig.toml [sensors.{name}]")
                if channel in present:
                    out[f"sensor_{channel}_{what}"] = v
    drop = []
    for key in sorted(meta):
        m = _SENSOR_KEY.match(str(key))
        if not m or meta[key] is None:
            continue
        channel = canonical_name(m.group("channel"))
        if channel is None:
            continue   # a non-canonical channel's: kept as written (unknown keys are kept)
        what = m.group("what").lower()
        out[f"sensor_{channel}_{what}"] = sensor_value_si(meta[key], channel, what, f"metadata `{key}`")
        drop.append(key)
    return {"set": out, "drop": drop}, warnings
