"""The even designs' boundaries as plain arrays: computed once, kept between processes (issue 23).

Every sequential design of the stages (:func:`analyses.sequential.design_for`) visits the even designs
``k / M`` of ``M`` from :data:`FIRST_MAXIMUM` to :data:`~analyses.sequential_boundaries.DESIGN_LOOKS`
looks: the rare-failure bisection reads their boundaries
(:func:`analyses.sequential_information.rare_failure_power`) and the inflation factor their power at any
drift (:meth:`analyses.sequential_boundaries._Design.upper_power`, from the continuation grids the
recursion leaves). Those depend on ``alpha`` and the spending function only, not
on the margin, shape, hoses or power, and their recursion costs about 1 CPU-s a process (every worker of
a rebuild's pool paid it). :func:`design_table` gives them as arrays (computed here when this process has
not got them); :func:`adopt_table` takes such arrays back, after checking them, so that a process that
read them from a file computes none of them: the same float64 values, so the same designs bit for bit.
Reading and writing the file is the stage's (:mod:`pipeline.stages.decision`); nothing here touches disk.
"""
from __future__ import annotations

import numpy as np

from analyses.sequential_boundaries import (_DESIGNS, _NO_BOUNDARY, DESIGN_LOOKS, SPENDING, _Design, _design_of,
                                           alpha_spent)

#: The smallest maximum a design visits (:func:`analyses.sequential._smallest_rare_maximum` starts at 4).
FIRST_MAXIMUM = 4
#: Rows of a design's flattened grids (:meth:`analyses.sequential_boundaries._Design.upper_power`): score,
#: mass, previous fraction, increment, boundary times sqrt(t).
_FLAT_ROWS = 5
#: The most grid points one design may hold in a table (a design of 100 looks holds ~25,000).
_MAX_POINTS = 1_000_000


def table_names() -> list[str]:
    """The arrays of a table, in order: ``c_M`` (the ``M`` boundaries [-]) and ``flat_M`` (the grids)."""
    return [f"{kind}_{m}" for m in range(FIRST_MAXIMUM, DESIGN_LOOKS + 1) for kind in ("c", "flat")]


def design_table(alpha: float, spending: str) -> dict[str, np.ndarray]:
    """The even designs of :data:`FIRST_MAXIMUM`..``DESIGN_LOOKS`` looks as arrays.

    Parameters
    ----------
    alpha : float
        Two-sided error rate [-].
    spending : {"obrien-fleming", "pocock"}
        Lan-DeMets spending family.

    Returns
    -------
    dict
        ``c_M``: float64 ``(M,)`` boundaries on the z scale [-]; ``flat_M``: float64 ``(5, n)``, the
        continuation grids :meth:`~analyses.sequential_boundaries._Design.upper_power` reads [-]. Computed in
        this process where it has not got them (and kept there, as any design is).
    """
    out = {}
    for m in range(FIRST_MAXIMUM, DESIGN_LOOKS + 1):
        design = _design_of(m, alpha, spending, record=True)
        design.upper_power(0.0)    # the boundaries and the flattened grids, once
        out[f"c_{m}"], out[f"flat_{m}"] = np.array(design.c[:m], dtype=np.float64), design._flat
    return out


def _valid(table, m: int) -> bool:
    """Whether ``table``'s arrays of the design of ``m`` looks have the form :func:`design_table` gives."""
    c, flat = table.get(f"c_{m}"), table.get(f"flat_{m}")
    if not (isinstance(c, np.ndarray) and isinstance(flat, np.ndarray)):
        return False
    if c.dtype != np.float64 or flat.dtype != np.float64 or c.shape != (m,) or flat.ndim != 2:
        return False
    if flat.shape[0] != _FLAT_ROWS or flat.shape[1] > _MAX_POINTS:
        return False
    if not (np.all(np.isfinite(c)) and np.all(c > 0) and np.all(c <= _NO_BOUNDARY) and np.all(np.isfinite(flat))):
        return False
    _score, mass, t_prev, inc, _bound = flat
    return bool(np.all(mass >= 0) and np.all(t_prev > 0) and np.all(t_prev < 1) and np.all(inc > 0)
                and np.all(inc <= 1))


def adopt_table(table, alpha: float, spending: str) -> bool:
    """Keep the designs of a :func:`design_table` in this process, in place of computing them.

    Parameters
    ----------
    table : mapping
        Arrays by name, as :func:`design_table` returns them (read from a file: any content).
    alpha : float
        Two-sided error rate [-] they were computed for.
    spending : {"obrien-fleming", "pocock"}
        Their spending family.

    Returns
    -------
    bool
        True when every array has the form :func:`design_table` gives (names, float64, shapes, finite,
        boundaries in ``(0, 40]``, grids of non-negative mass); then each design not already computed
        here is kept. False (nothing kept) otherwise: a table of another form is never read in part.
    """
    if spending not in SPENDING or not hasattr(table, "keys") or set(table.keys()) != set(table_names()):
        return False
    if not all(_valid(table, m) for m in range(FIRST_MAXIMUM, DESIGN_LOOKS + 1)):
        return False
    for m in range(FIRST_MAXIMUM, DESIGN_LOOKS + 1):
        key = (m, alpha, spending)
        held = _DESIGNS.get(key)
        if held is not None and held.terms is not None:
            continue   # computed here already: the same values
        _DESIGNS[key] = _from_table(np.arange(1, m + 1) / m, alpha, spending, table[f"c_{m}"], table[f"flat_{m}"])
    return True


def _from_table(t: np.ndarray, alpha: float, spending: str, c: np.ndarray, flat: np.ndarray) -> _Design:
    """The :class:`analyses.sequential_boundaries._Design` of looks ``t`` whose every boundary ``c`` and flattened
    grids ``flat`` are known already: no recursion left to run (``boundaries`` reads ``c``, ``upper_power`` the
    grids)."""
    design = _Design.__new__(_Design)
    design.t, design.spend = t, np.diff(np.concatenate([[0.0], alpha_spent(t, alpha, spending)]))
    design.rec, design.c, design.terms, design._flat = None, c.tolist(), [], flat
    return design


def holds_table(alpha: float, spending: str) -> bool:
    """Whether this process holds every design of a :func:`design_table` of ``alpha`` and ``spending``."""
    return all((m, alpha, spending) in _DESIGNS for m in range(FIRST_MAXIMUM, DESIGN_LOOKS + 1))
