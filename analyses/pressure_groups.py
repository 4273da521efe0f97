"""PLA chamber pressure dynamics pooled per rig, and per part under test and age (issue 25).

:func:`group_pressure_steps` makes a ``rig`` group per (campaign, rig, chamber, direction) with
every step of that rig, and, for runs that name the part under test (``valve_id`` or ``hose_id``),
a ``part`` group per (campaign, rig, chamber, direction, part, age): the same valve new and after
594 h are two groups. :func:`age_changes` gives each later age's change of ``wn`` / ``zeta`` /
``tau`` from the part's youngest fitted age, and :func:`plot_pressure_ageing` draws them against
the part's hours (or distance). The fits themselves: :mod:`analyses.pressure_dynamics` (which
names these too).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# PressureStep and PressureFit (analyses.pressure_dynamics, which re-exports this module) appear in annotations
# only, never evaluated (``from __future__ import annotations``): not imported, so the two modules form no circle.

__all__ = ["RunPart", "StepGroup", "group_pressure_steps", "age_changes", "plot_pressure_ageing"]


@dataclass(frozen=True)
class RunPart:
    """Where a pressure-step run was recorded and what it tested: campaign, rig and, when the run
    names one, the part under test (``part_kind`` ``valve`` / ``hose``, ``part_id``) and its age
    (hours of use ``age_h``, distance run ``distance_km``; None when not stated)."""

    campaign: str = ""
    rig: str = ""
    part_kind: str | None = None
    part_id: str | None = None
    age_h: float | None = None
    distance_km: float | None = None


@dataclass(frozen=True)
class StepGroup:
    """The steps one fit pools. ``level`` ``rig``: every step of (campaign, rig, chamber,
    direction), part fields None; ``part``: the steps of one part at one age on that rig."""

    level: str
    campaign: str
    rig: str
    chamber: str
    direction: str
    part_kind: str | None = None
    part_id: str | None = None
    age_h: float | None = None
    distance_km: float | None = None

    def sort_key(self) -> tuple:
        """Campaign, rig, chamber, direction; the rig's row first, then parts by id and age."""
        def num(v):
            return (v is None, v if v is not None else 0.0)
        return (self.campaign, self.rig, self.chamber, self.direction, self.level != "rig",
                self.part_kind or "", self.part_id or "", num(self.age_h), num(self.distance_km))


def group_pressure_steps(steps: list[PressureStep], runs: dict) -> dict[StepGroup, list[PressureStep]]:
    """Group steps for fitting: one ``rig`` group per (campaign, rig, chamber, direction) holding
    all its steps, and one ``part`` group per (campaign, rig, chamber, direction, part, age) for
    the steps of runs that name a part.

    Parameters
    ----------
    steps : list of PressureStep
    runs : dict of str to RunPart
        Per run id; a run missing here is pooled under an empty campaign and rig.

    Returns
    -------
    dict of StepGroup to list of PressureStep
        In :meth:`StepGroup.sort_key` order; steps keep their order within a group.
    """
    out: dict[StepGroup, list[PressureStep]] = {}
    for s in steps:
        r = runs.get(s.run_id) or RunPart()
        base = (r.campaign or "", r.rig or "", s.chamber, s.direction)
        out.setdefault(StepGroup("rig", *base), []).append(s)
        if r.part_id:
            out.setdefault(StepGroup("part", *base, r.part_kind, r.part_id, r.age_h, r.distance_km), []).append(s)
    return {g: out[g] for g in sorted(out, key=StepGroup.sort_key)}


def _age_axis(groups) -> str | None:
    """``age_h`` when every group states hours, else ``distance_km`` when every one states a
    distance, else None (the ages cannot be ordered)."""
    for name in ("age_h", "distance_km"):
        if all(getattr(g, name) is not None for g in groups):
            return name
    return None


def age_changes(fits: dict) -> dict[StepGroup, dict[str, float]]:
    """Change of each ``part`` group's parameters from its part's youngest fitted age.

    A part's series is its groups with the same rig, chamber, direction, part kind and id (any
    campaign: the new valve may have been tested in another campaign than the aged one), ordered
    by ``age_h`` (or ``distance_km`` when not every age states hours). The reference is the
    youngest group with a model; a later group's change is ``100 (value / reference - 1)`` for
    ``wn_rad_s``, ``zeta`` and ``tau_s`` when both have that model's value, NaN otherwise (and for
    the reference itself, and for parts whose ages cannot be ordered).

    Parameters
    ----------
    fits : dict of StepGroup to PressureFit

    Returns
    -------
    dict of StepGroup to dict
        Per ``part`` group: ``wn_change_pct``, ``zeta_change_pct``, ``tau_change_pct``. [%]
    """
    keys = ("wn_rad_s", "zeta", "tau_s")
    nan = {f"{k.split('_')[0]}_change_pct": float("nan") for k in keys}
    series: dict[tuple, list[StepGroup]] = {}
    for g in fits:
        if g.level == "part":
            series.setdefault((g.rig, g.chamber, g.direction, g.part_kind, g.part_id), []).append(g)
    out: dict[StepGroup, dict[str, float]] = {}
    for groups in series.values():
        axis = _age_axis(groups)
        for g in groups:
            out[g] = dict(nan)
        if axis is None or len(groups) < 2:
            continue
        ordered = sorted(groups, key=lambda g: getattr(g, axis))
        ref = next((g for g in ordered if fits[g].ok), None)
        if ref is None:
            continue
        for g in ordered:
            if g is ref or getattr(g, axis) == getattr(ref, axis):
                continue
            for k in keys:
                a, b = getattr(fits[ref], k), getattr(fits[g], k)
                if np.isfinite(a) and np.isfinite(b) and a != 0:
                    out[g][f"{k.split('_')[0]}_change_pct"] = 100.0 * (b / a - 1.0)
    return out


def plot_pressure_ageing(table, title: str = ""):
    """``wn``, ``zeta`` and ``tau`` of every part against its age: one line per (rig, part,
    chamber, direction), the part's ages in order, each later age labelled with its change from
    the youngest (``*_change_pct``, when the table has it); the x axis in hours of use when every
    plotted row states them, else in km.

    Parameters
    ----------
    table : DataFrame
        ``pressure_dynamics`` rows (the ``part`` rows are drawn): ``rig``, ``chamber``,
        ``direction``, ``part_kind``, ``part_id``, ``part_age_h``, ``part_distance_km``,
        ``wn_rad_s``, ``zeta``, ``tau_s``.
    title : str

    Returns
    -------
    matplotlib.figure.Figure
    """
    import pandas as pd
    from matplotlib.figure import Figure

    rows = table[table["level"] == "part"] if "level" in table.columns else table
    use_h = bool(rows["part_age_h"].notna().all()) if len(rows) else True
    xcol = "part_age_h" if use_h else "part_distance_km"
    rows = rows[rows[xcol].notna()]
    fig = Figure(figsize=(12, 4))
    axes = fig.subplots(1, 3)
    panels = (("wn_rad_s", "natural frequency wn [rad/s]"), ("zeta", "damping ratio zeta [-]"),
              ("tau_s", "time constant tau [ms]"))
    keys = ["rig", "part_kind", "part_id", "chamber", "direction"]
    for ax, (col, label) in zip(axes, panels):
        scale = 1e3 if col == "tau_s" else 1.0
        for key, grp in rows.groupby(keys, dropna=False, sort=True):
            grp = grp.sort_values(xcol)
            y = pd.to_numeric(grp[col], errors="coerce") * scale
            if y.notna().any():
                rig, kind, part, chamber, direction = key
                line, = ax.plot(grp[xcol].to_numpy(float), y.to_numpy(float), marker="o",
                                ls="-" if direction == "charge" else "--",
                                label=f"{kind or 'part'} {part}, {chamber} {direction} ({rig})")
                change = f"{col.split('_')[0]}_change_pct"
                for x, v, c in zip(grp[xcol], y, grp[change] if change in grp.columns else [None] * len(grp)):
                    if c is not None and pd.notna(c) and pd.notna(v):   # the change from the youngest age
                        ax.annotate(f"{c:+.1f} %", (float(x), float(v)), textcoords="offset points",
                                    xytext=(-6, 6), ha="right", fontsize=7, color=line.get_color())
        ax.set_xlabel("age of the part [h]" if use_h else "distance run by the part [km]")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        if ax.lines:
            ax.legend(fontsize=7)
        else:
            ax.text(0.5, 0.5, "no part fitted with this model", ha="center", va="center",
                    transform=ax.transAxes, color="0.5")
    fig.suptitle(title or "Pressure dynamics of each part against its age (per chamber and direction)")
    fig.tight_layout()
    return fig
