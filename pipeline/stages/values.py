"""Cells the stages read and write: a number that is finite or None, a run's params as a dict."""
from __future__ import annotations

import json
import math


def finite_float(value, default: float | None = None) -> float | None:
    """``value`` as a finite float; ``default`` (None) when it is missing, not a number, NaN or infinite.

    Parameters
    ----------
    value : object
        A metadata value, a statistic, a table cell (None, NaN, text, a number).
    default : float or None
        What to give when ``value`` is not a finite number.

    Returns
    -------
    float or None
    """
    try:
        out = float(value)
    except (TypeError, ValueError):
        return default
    return out if math.isfinite(out) else default


def run_params(value) -> dict:
    """A run's ``params`` as a dict (the dict itself, its JSON text decoded, else empty)."""
    if isinstance(value, dict):
        return value
    if isinstance(value, str):
        try:
            return json.loads(value)
        except ValueError:
            return {}
    return {}
