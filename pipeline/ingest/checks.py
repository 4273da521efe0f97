"""What refuses a run once its columns and metadata are known (each a one-line IngestError).

The channels its kind needs (:func:`check_channels`, with a hint on how to get a missing one),
the metadata its kind needs, its chamber, and every stated value within its physical range
(:func:`check_metadata`, :func:`check_plausible`).
"""
from __future__ import annotations

from pipeline.ingest.columns import lookalike_hint
from pipeline.ingest.result import IngestError
from pipeline.ingest.timebase import MAT_DT_KEYS, MAT_RATE_KEYS, TimeBase
from schemas.kinds import KINDS, META_KEYS, implausible, missing_channels, missing_metadata


def check_channels(kind: str, present: set[str], lookalikes: dict, derived_warnings: list[str]) -> None:
    """Refuse a run without the channels its kind needs; the message says how each missing one
    could be had (a look-alike to map, a rate to state, a derived channel that was not computed).

    Parameters
    ----------
    kind : str
        The run's kind.
    present : set of str
        Canonical channels the run has (mapped, a computed ``t``, derived).
    lookalikes : dict
        Column key -> (raw name, canonical channel it looks like, raw unit).
    derived_warnings : list of str
        Why derived channels were not computed.
    """
    gaps = missing_channels(kind, present)
    if gaps:
        hint = "".join(lookalike_hint(c, lookalikes) for c in gaps)
        if "t" in gaps:
            hint += "; no time column: state `sample_rate_hz` or `dt_s` (and `t0_s`) in the run's metadata"
        hint += "".join(f"; {w}" for w in derived_warnings
                        if any(f"`{c}`" in w.split(" not computed")[0] for c in gaps))
        raise IngestError(f"missing channel {', '.join(f'`{c}`' for c in gaps)} (kind {kind} needs "
                          + " or ".join(", ".join(s) for s in KINDS[kind].channel_sets) + ")" + hint)


def check_metadata(kind: str, meta: dict, present: set[str], time_base: TimeBase | None) -> None:
    """Refuse a run without the metadata its kind needs (for the channels it has), with a chamber
    its kind does not know, or with a value outside its range (:func:`check_plausible`)."""
    miss = missing_metadata(kind, meta, present)
    if miss:
        raise IngestError(f"missing metadata {', '.join(f'`{k}`' for k in miss)} (kind {kind})")
    if KINDS[kind].chambers and meta.get("chamber") not in KINDS[kind].chambers:
        raise IngestError(f"metadata `chamber` must be one of {', '.join(KINDS[kind].chambers)} "
                          f"for kind {kind}, got {meta.get('chamber')!r}")
    check_plausible(meta, time_base)


def check_plausible(meta: dict, time_base: TimeBase | None = None) -> None:
    """Refuse a stated value outside its physical range (:data:`schemas.kinds.PLAUSIBLE`): one
    line naming the key, the value and the range. A MAT scalar rate is held to the range of
    ``sample_rate_hz`` / ``dt_s``."""
    for key in sorted(meta):
        why = implausible(key, meta[key])
        if why is not None:
            raise IngestError(f"metadata `{key}` = {why}")
    mat_scalar = time_base is not None and time_base.source in MAT_RATE_KEYS + MAT_DT_KEYS
    if mat_scalar and time_base.source not in META_KEYS:  # `sample_rate_hz` is checked above
        key, value = (("sample_rate_hz", time_base.rate_hz) if time_base.rate_hz is not None
                      else ("dt_s", time_base.dt_s))
        why = implausible(key, value)
        if why is not None:
            raise IngestError(f"MAT scalar `{time_base.source}` = {why}")
