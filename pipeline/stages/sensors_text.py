"""The ``sensors`` cell of result rows (``leakage_map.sensors``), read back: the one reader of that text.

The PLPA characterisation stage writes it as ``"; "``-joined parts ``"<channel>: <Sensor.describe()>
<SI unit>"`` (:meth:`analyses.quality.Sensor.describe`); the remaining_life stage reads the leak-flow
sensor from it and the report its flow floor. Plain Python (no numeric library): the report imports it.
"""
from __future__ import annotations

import re

#: One part of a ``sensors`` cell: ``"<channel>: resolution <r>, noise <n> (<source>) <SI unit>"``.
SENSOR_PART = re.compile(r"\s*(?P<name>[^:;]+): resolution (?P<res>\S+), noise (?P<noise>\S+) "
                         r"\((?P<src>[^)]*)\) (?P<unit>\S+)\s*")


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
        channel -> ``(resolution, noise, source, unit)``, the numbers as written, in ``unit`` (NaN
        stays NaN: the caller decides); a part that does not read that way, or whose numbers do not
        parse, is left out. Empty for a cell that is not text.
    """
    found = {}
    for part in (text.split(";") if isinstance(text, str) else []):
        m = SENSOR_PART.fullmatch(part)
        if m is None:
            continue
        try:
            found[m["name"]] = (float(m["res"]), float(m["noise"]), m["src"], m["unit"])
        except ValueError:
            continue
    return found
