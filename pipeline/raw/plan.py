"""The lab's test plan: ``raw/plan.toml`` read once, each bad value one quarantine line.

The plan says what life ratio is worth acting on and how sure the verdict on force- vs
distance-set hoses must be (issue 23, "The decision"; docs/bench-exports.md, "plan.toml").
Only the file at the top of raw/ is read (a plan.toml deeper down is a quarantine line of the
walk, :mod:`pipeline.raw.walk`). Two kinds of table::

    [defaults]                      # every hose type
    margin = 1.25
    [hose_type."FLEXIGOM AIR"]      # one hose type, as the logbook names it: overrides [defaults]
    max_failures = 30

with the keys of :data:`KEYS`: ``margin`` (the smallest force/distance life ratio worth acting
on, > 1), ``alpha`` (two-sided error rate of the verdict, 0 < alpha < 0.5), ``power``
(0.5 <= power < 1), ``confidence`` (of the intervals, 0.5 < c < 1), ``max_failures`` (failures
of both adjustments together at which the test ends, an integer >= 2), ``spending`` (the
alpha-spending family: ``"obrien-fleming"`` or ``"pocock"``, the Lan & DeMets 1983 forms of
O'Brien & Fleming 1979 and Pocock 1977; Jennison & Turnbull 2000, ch. 7), ``benches`` (an
integer >= 1) and ``km_per_day`` (> 0) (the bench capacity), ``leak_limit_l_min`` and
``leak_pressure_bar`` (> 0, failure by leakage), ``b_life`` (the service-life table's B-life, in
percent failed, 0 < b_life < 100) and ``mission_km`` (> 0, the distance at which the
service-life table gives the reliability), ``rupture_shape`` (0 < shape <= :data:`MAX_RUPTURE_SHAPE`,
the Weibull shape of the failures other than the leak when the lab knows it: the remaining-life
models' Weibayes, :func:`analyses.remaining_life.rupture_model`).

Decisions where the spec is silent
----------------------------------
* **Untrusted input, one line per fault.** The file is opened once from raw/ without following a
  symlink out of it (:func:`pipeline.raw.rig.read_rig`, the rig.toml reader: same 1 MiB limit,
  same TOML parser). A value of the wrong type or out of range, an unknown key, an unknown table
  or a key outside any table is ONE quarantine line naming the file, the table and the key
  (``plan.toml: [hose_type."X"] margin: must be a number > 1, got "big"; using the default
  1.25``); the rest of the plan is used and the night goes on. A bad value falls back to what
  the hose type would have without it: the ``[defaults]`` value, else the built-in default.
* **A file that cannot be used at all** (not TOML, over the size limit, unreadable, a symlink out
  of raw/, ``Plan.toml`` named in another case) is one line and no plan: every hose type gets
  the built-in defaults and ``present=False``, so the verdict says ``no plan`` rather than
  deciding under settings the lab did not write. A symlink's line is the walk's (not repeated).
* **Strict types.** ``true`` is not a number; ``max_failures = 30.0`` is not an integer;
  ``inf`` and ``nan`` are refused; ``max_failures`` and ``benches`` have upper limits
  (:data:`MAX_FAILURES_LIMIT`, :data:`MAX_BENCHES`) so that a typo cannot make the stage's
  simulations run for days.
* **Built-in defaults** (:data:`KEYS`): margin 1.25, alpha 0.05, power 0.80, confidence 0.90,
  spending O'Brien-Fleming (it spends little alpha at the early looks, where a reliability test
  has few failures). ``max_failures`` unset means the sequential design's ``failures_needed``
  for the margin, alpha and power (``test_plan``); ``benches`` and ``km_per_day`` unset mean
  measured from the durability runs of the last 30 days. ``b_life`` 10 (B10); ``mission_km``
  unset means no reliability at a mission (NULL columns). None stands for "unset".
* **Its hash.** :attr:`Plan.digest` hashes what a stage can see (every setting of every hose type
  the plan names and of any other, where each came from, ``present``): a stage that declares
  ``Reads(plan=True)`` re-runs when that changes, not when a comment does.

Nothing here writes to the raw tree.
"""
from __future__ import annotations

import difflib
import hashlib
import json
import math
from dataclasses import dataclass, field
from datetime import date, datetime, time

from pipeline.raw.problems import ConfigError, Problem
from pipeline.raw.rig import read_rig

#: The plan's file name; read at the top of raw/ only.
PLAN_FILE = "plan.toml"

#: Largest ``max_failures`` accepted (a bench test with more failures is not a plan, it is a typo).
MAX_FAILURES_LIMIT = 10_000

#: Largest ``benches`` accepted.
MAX_BENCHES = 1_000

#: Largest ``rupture_shape`` accepted: Weibull shapes of wear-out in the reliability literature stay
#: below about 10 (Abernethy 2006, ch. 6 and appendix on Weibull libraries); 20 leaves room, a larger
#: value is a typo (it would put every rupture at one distance).
MAX_RUPTURE_SHAPE = 20.0

#: The alpha-spending families the verdict knows (Lan & DeMets 1983).
SPENDING = ("obrien-fleming", "pocock")

#: Where a setting came from (:attr:`PlanSettings.sources`).
FROM_HOSE_TYPE, FROM_DEFAULTS, BUILT_IN = "hose_type", "defaults", "built-in"


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _integer(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


#: key -> (what a value must be, its check, the built-in default, the default in words)
KEYS: dict[str, tuple] = {
    "margin": ("a number > 1", lambda v: _number(v) and v > 1, 1.25, "1.25"),
    "alpha": ("a number with 0 < alpha < 0.5", lambda v: _number(v) and 0 < v < 0.5, 0.05, "0.05"),
    "power": ("a number with 0.5 <= power < 1", lambda v: _number(v) and 0.5 <= v < 1, 0.80, "0.8"),
    "confidence": ("a number with 0.5 < confidence < 1", lambda v: _number(v) and 0.5 < v < 1, 0.90, "0.9"),
    "max_failures": (f"an integer from 2 to {MAX_FAILURES_LIMIT}",
                     lambda v: _integer(v) and 2 <= v <= MAX_FAILURES_LIMIT, None,
                     "unset: the sequential design's failures_needed"),
    "spending": (" or ".join(f'"{s}"' for s in SPENDING), lambda v: isinstance(v, str) and v in SPENDING,
                 "obrien-fleming", '"obrien-fleming"'),
    "benches": (f"an integer from 1 to {MAX_BENCHES}", lambda v: _integer(v) and 1 <= v <= MAX_BENCHES, None,
                "unset: measured from the durability runs of the last 30 days"),
    "km_per_day": ("a number > 0", lambda v: _number(v) and v > 0, None,
                   "unset: measured from the durability runs of the last 30 days"),
    # functional failure by leakage (spec bench-exports.md; used by the remaining-life issue)
    "leak_limit_l_min": ("a number > 0", lambda v: _number(v) and v > 0, None,
                         "unset: no failure by leakage"),
    "leak_pressure_bar": ("a number > 0", lambda v: _number(v) and v > 0, None,
                          "unset: no failure by leakage"),
    # the service-life table (issue 25, item 17): which B-life, and reliability at which mission distance
    "b_life": ("a number with 0 < b_life < 100 (percent failed)", lambda v: _number(v) and 0 < v < 100, 10,
               "10 (B10)"),
    "mission_km": ("a number > 0", lambda v: _number(v) and v > 0, None,
                   "unset: no reliability at a mission distance"),
    # the remaining-life models' other failure modes (issue 24): their Weibull shape, when known (Weibayes)
    "rupture_shape": (f"a number with 0 < rupture_shape <= {MAX_RUPTURE_SHAPE:g}",
                      lambda v: _number(v) and 0 < v <= MAX_RUPTURE_SHAPE, None,
                      "unset: the rupture shape not known, the intervals hold for every shape from 1 to the "
                      "logbook's bound"),
}

_TABLES_TEXT = '[defaults] and [hose_type."<hose type>"]'


@dataclass(frozen=True)
class PlanSettings:
    """The plan for one hose type: each key's value (None: unset, see :data:`KEYS`) and where it
    came from (``sources[key]``: ``"hose_type"``, its own table; ``"defaults"``, the
    ``[defaults]`` table; ``"built-in"``, no valid value in the plan)."""

    hose_type: str | None
    present: bool
    margin: float
    alpha: float
    power: float
    confidence: float
    max_failures: int | None
    spending: str
    benches: int | None
    km_per_day: float | None
    leak_limit_l_min: float | None
    leak_pressure_bar: float | None
    b_life: float
    mission_km: float | None
    rupture_shape: float | None
    sources: dict[str, str]


@dataclass(frozen=True)
class Plan:
    """``raw/plan.toml`` as read (:func:`read_plan`).

    Attributes
    ----------
    present : bool
        Whether a usable plan.toml was there (False: built-in defaults, the verdict says ``no plan``).
    defaults : dict
        The valid values of its ``[defaults]`` table.
    hose_types : dict of str to dict
        The valid values of each ``[hose_type."<name>"]`` table.
    note : str
        One line on the plan as a whole (where it came from, or why there is none).
    problems : tuple of Problem
        Its quarantine lines (also in the tree's ``problems``).
    """

    present: bool = False
    defaults: dict = field(default_factory=dict)
    hose_types: dict = field(default_factory=dict)
    note: str = f"no {PLAN_FILE} at the top of raw/: built-in defaults, the verdicts say `no plan`"
    problems: tuple = ()

    def for_hose_type(self, hose_type: str | None) -> PlanSettings:
        """The settings of one hose type (its table over ``[defaults]`` over the built-in
        defaults) and where each came from; None, or a hose type the plan does not name, gets
        ``[defaults]`` over the built-ins."""
        own = self.hose_types.get(hose_type, {}) if hose_type is not None else {}
        values, sources = {}, {}
        for key, (_rule, _ok, builtin, _text) in KEYS.items():
            if key in own:
                values[key], sources[key] = own[key], FROM_HOSE_TYPE
            elif key in self.defaults:
                values[key], sources[key] = self.defaults[key], FROM_DEFAULTS
            else:
                values[key], sources[key] = builtin, BUILT_IN
        return PlanSettings(hose_type=hose_type, present=self.present, sources=sources, **values)

    @property
    def digest(self) -> str:
        """Hash of everything a stage can read of the plan (the cache key's ``plan`` of a stage that
        declares ``Reads(plan=True)``): every key's value and source for any hose type and for each
        hose type the plan names (such a stage may list them), and ``present``."""
        return self._digest(tuple(KEYS), every_named=True)

    def digest_of(self, keys: tuple[str, ...]) -> str:
        """Hash of what a stage that reads only ``keys`` can see of the plan: those keys' values
        and sources for any hose type (``[defaults]`` over the built-ins), for each hose type whose
        table sets one of them, and ``present``. A hose type's table that sets none of ``keys`` (a
        ``power`` for the verdict) gives that hose type what any other gets: it changes nothing a
        stage reading only ``keys`` sees (issue 26: ``durability`` re-ran on such a change)."""
        return self._digest(tuple(keys), every_named=False)

    def _digest(self, keys: tuple[str, ...], every_named: bool) -> str:
        def seen(s: PlanSettings) -> dict:
            return {**{k: getattr(s, k) for k in keys}, "sources": {k: s.sources[k] for k in keys}}

        settings = {"*": seen(self.for_hose_type(None))}
        for t in sorted(self.hose_types):
            own = seen(self.for_hose_type(t))
            if every_named or own != settings["*"]:
                settings[t] = own
        blob = {"present": self.present, "settings": settings}
        return hashlib.sha256(json.dumps(blob, sort_keys=True).encode()).hexdigest()[:32]


def _shown(v) -> str:
    """A TOML value as a quarantine line shows it (``"big"``, ``0.7``, ``true``, ``a table``)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, dict):
        return "a table"
    if isinstance(v, list):
        return "an array"
    if isinstance(v, (datetime, date, time)):
        return f"the date/time {v.isoformat()}"
    if isinstance(v, str):
        return json.dumps(_cut(v), ensure_ascii=False)
    return repr(v)


def _cut(text: str) -> str:
    """A name or text of the file as a line shows it: its first 40 characters (a line stays one line)."""
    return text if len(text) <= 40 else text[:40] + "..."


def _where(table: str | None) -> str:
    """``[defaults]`` or ``[hose_type."X"]`` as a line names the table."""
    return "[defaults]" if table is None else f"[hose_type.{json.dumps(_cut(table), ensure_ascii=False)}]"


class _Reading:
    """One plan.toml being checked: its valid values so far and its quarantine lines."""

    def __init__(self, rel: str):
        self.rel = rel
        self.problems: list[Problem] = []
        self.defaults: dict = {}

    def problem(self, text: str) -> None:
        self.problems.append(Problem(self.rel, text))

    def table(self, table: str | None, values: dict) -> dict:
        """The valid values of one table (``table`` None: ``[defaults]``); each bad key a line."""
        out = {}
        for key, v in values.items():
            if key not in KEYS:
                close = difflib.get_close_matches(key, list(KEYS), n=1)
                hint = f"did you mean {close[0]}?" if close else f"expected {', '.join(KEYS)}"
                self.problem(f"{_where(table)} {_cut(key)}: unknown key ({hint}); ignored")
                continue
            rule, ok, builtin, text = KEYS[key]
            if ok(v):
                out[key] = v
                continue
            if table is not None and key in self.defaults:
                instead = f"the [defaults] value {_shown(self.defaults[key])}"
            else:
                instead = f"the default {text}" if builtin is not None else f"the default ({text})"
            self.problem(f"{_where(table)} {key}: must be {rule}, got {_shown(v)}; using {instead}")
        return out

    def plan(self, cfg: dict) -> Plan:
        """The plan of a parsed plan.toml: ``[defaults]`` first (a hose type's bad key falls back to it)."""
        defaults = cfg.get("defaults", {})
        if not isinstance(defaults, dict):
            self.problem(f"defaults: must be a table ([defaults]), got {_shown(defaults)}; ignored")
            defaults = {}
        self.defaults = self.table(None, defaults)
        hose_types: dict[str, dict] = {}
        types = cfg.get("hose_type", {})
        if not isinstance(types, dict):
            self.problem(f'hose_type: must be tables of hose types ([hose_type."<hose type>"]), got {_shown(types)}; '
                         "ignored")
            types = {}
        for name, values in types.items():
            if isinstance(values, dict):
                hose_types[name] = self.table(name, values)
            else:
                self.problem(f"{_where(name)}: must be a table, got {_shown(values)}; ignored")
        for key, v in cfg.items():
            if key in ("defaults", "hose_type"):
                continue
            if isinstance(v, dict):
                self.problem(f"[{_cut(key)}]: unknown table (expected {_TABLES_TEXT}); ignored")
            else:
                self.problem(f"{_cut(key)}: a key outside any table (put it under [defaults] or "
                             '[hose_type."<hose type>"]); ignored')
        return Plan(True, self.defaults, hose_types, f"{self.rel}: {len(hose_types)} hose type table(s)",
                    tuple(self.problems))


def read_plan(tree) -> Plan:
    """The lab's test plan, ``raw/plan.toml``, read once (module docstring).

    Parameters
    ----------
    tree : pipeline.raw.tree.RawTree
        The raw tree: its root, what the walk says about the file (``side_file``) and its
        ``problems``, where each quarantine line of the plan is recorded.

    Returns
    -------
    Plan
        ``present=False`` with built-in defaults when there is no usable plan.toml; its
        ``problems`` are the lines recorded.
    """
    before = len(tree.problems)
    f = tree.side_file(tree.root, PLAN_FILE)
    if f is None or isinstance(f, ConfigError):  # none, or a line already (the walk's, a miscased name)
        problems = tuple(tree.problems[before:])
        return Plan(problems=problems) if f is None else Plan(note=f"{f}; the verdicts say `no plan`",
                                                              problems=problems)
    rel = tree.rel(f)
    cfg, msg = read_rig(tree.root, f)
    if msg is not None:
        line = Problem(rel, f"{msg}; the plan is not used: built-in defaults, the verdicts say `no plan`")
        tree.problems.append(line)
        return Plan(note=f"cannot use {rel}: {msg}", problems=(line,))
    plan = _Reading(rel).plan(cfg)
    tree.problems.extend(plan.problems)
    return plan

