"""The ``sensors`` text of result rows (``leakage_map.sensors``), read back: the one reader of that text.

The PLPA characterisation stage writes it as ``"; "``-joined parts ``"<channel>: <Sensor.describe()>
<SI unit>"`` (:meth:`analyses.quality.Sensor.describe`); the remaining_life stage reads the leak-flow
sensor from it, the report its flow floor and :func:`schemas.units.display_sensors_text` shows it in
display units. Here, the lowest layer, so that all three read it alike (``schemas`` imports nothing of
ours); plain Python (no numeric library): the report's no-op path imports it.
"""
from __future__ import annotations

import re

#: One part of a ``sensors`` cell: ``"<channel>: resolution <r>, noise <n> (<source>) <SI unit>"``.
SENSOR_PART = re.compile(r"\s*(?P<name>[^:;]+): resolution (?P<res>\S+), noise (?P<noise>\S+) "
                         r"\((?P<src>[^)]*)\) (?P<unit>\S+)\s*")


def sensor_part(part: str) -> tuple | None:
    """One part of a ``sensors`` cell read: ``(channel, resolution, noise, source, unit)``, the numbers as
    written, in ``unit`` (NaN stays NaN); None when it does not read that way or its numbers do not parse."""
    m = SENSOR_PART.fullmatch(part)
    if m is None:
        return None
    try:
        return m["name"], float(m["res"]), float(m["noise"]), m["src"], m["unit"]
    except ValueError:
        return None


def sensor_parts(text) -> dict:
    """The sensors a ``sensors`` cell states.

    Parameters
    ----------
    text : str
        ``"; "``-joined parts, e.g. ``"p_supply: resolution 100, noise 40 (metadata) Pa; q_leak:
        resolution 2e-08, noise 4e-08 (metadata) kg/s"``.

    Returns
    -------
    dict
        channel -> ``(resolution, noise, source, unit)`` (:func:`sensor_part`); a part that does not read
        that way is left out. Empty for a cell that is not text.
    """
    found = {}
    for part in (text.split(";") if isinstance(text, str) else []):
        read = sensor_part(part)
        if read is not None:
            found[read[0]] = read[1:]
    return found
