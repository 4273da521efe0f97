"""Derived channels: safe arithmetic over a run's channels and numeric metadata.

A ``rig.toml`` may state channels computed from others (bench-exports.md, docs/inputs.md)::

    [derived]
    f = "f_cell - p_b * hose_area_m2"      # a load-cell rig's drive force [N]

rig.toml is untrusted input, so an expression is never handed to Python's ``eval``. It is
parsed with ``ast.parse(mode="eval")`` and walked against a whitelist: numeric literals, names,
``+ - * /``, ``**`` with a literal exponent of at most :data:`MAX_POWER`, unary ``-`` / ``+``,
parentheses and the functions ``abs``, ``sqrt``, ``min``, ``max`` (element-wise). Anything else
(attribute access, subscripts, calls of other names, lambdas, comprehensions, strings,
comparisons) is refused with a one-line :class:`DerivedError`. The text is at most
:data:`MAX_LENGTH` characters and the tree at most :data:`MAX_DEPTH` levels deep, so neither
parsing nor evaluation can be made to run away.

The checked expression is evaluated with numpy on whole arrays (one record batch at a time);
names resolve to channel arrays first, then to numeric metadata values (scalars).
:func:`plan_derived` checks a rig.toml's ``[derived]`` table against one run: which channels it
can compute, from which columns and metadata (:class:`DerivedChannel`).
"""
from __future__ import annotations

import ast
import math
from dataclasses import dataclass

import numpy as np

from pipeline.ingest.columns import ColumnMap
from pipeline.ingest.result import IngestError
from schemas.channels import CHANNELS, canonical_name, noncanonical_column, sanitise_name

#: Longest expression accepted. [characters]
MAX_LENGTH = 500
#: Deepest expression tree accepted (nested operations / parentheses). [levels]
MAX_DEPTH = 32
#: Largest literal exponent of ``**`` accepted (``x ** 2``, ``x ** 0.5``; no ``9 ** 9 ** 9``).
MAX_POWER = 4.0

_FUNCTIONS = {"abs": (1, np.abs), "sqrt": (1, np.sqrt), "min": (2, np.minimum), "max": (2, np.maximum)}
_BINARY = {ast.Add: np.add, ast.Sub: np.subtract, ast.Mult: np.multiply, ast.Div: np.divide}


class DerivedError(ValueError):
    """A derived-channel expression that is refused or cannot be evaluated (one line)."""


@dataclass(frozen=True)
class Expression:
    """A checked expression: its text, its parse tree and the names it reads."""

    text: str
    tree: ast.Expression
    names: tuple[str, ...]

    def evaluate(self, values: dict, n: int) -> np.ndarray:
        """Evaluate on arrays (channels) and scalars (metadata).

        Parameters
        ----------
        values : dict
            Name -> numpy array of length ``n`` or a float.
        n : int
            Rows of the batch; a constant expression is broadcast to it.

        Returns
        -------
        numpy.ndarray
            float64, length ``n`` (non-finite where the arithmetic is, e.g. division by zero).
        """
        missing = [k for k in self.names if k not in values]
        if missing:
            raise DerivedError(f"`{self.text}` names unknown {', '.join(f'`{k}`' for k in missing)}")
        with np.errstate(all="ignore"):
            out = _eval(self.tree.body, values)
        out = np.asarray(out, dtype=np.float64)
        if out.ndim == 0:
            out = np.full(n, float(out))
        return out


def parse_expression(text) -> Expression:
    """Check an expression against the whitelist (see the module docstring).

    Parameters
    ----------
    text : str
        The expression as written in rig.toml.

    Returns
    -------
    Expression

    Raises
    ------
    DerivedError
        With a one-line reason when the expression is refused.
    """
    if not isinstance(text, str):
        raise DerivedError(f"expression must be text, got {type(text).__name__}")
    if len(text) > MAX_LENGTH:
        raise DerivedError(f"expression longer than {MAX_LENGTH} characters")
    if not text.strip():
        raise DerivedError("expression is empty")
    # A cheap bound before parsing: CPython's parser itself recurses on nesting.
    if text.count("(") > MAX_DEPTH:
        raise DerivedError(f"expression nested deeper than {MAX_DEPTH} levels")
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except (SyntaxError, ValueError, RecursionError, MemoryError) as exc:
        raise DerivedError(f"expression `{text[:60]}` is not valid arithmetic ({type(exc).__name__})") from None
    names: list[str] = []
    _check(tree.body, 1, names, text)
    return Expression(text, tree, tuple(dict.fromkeys(names)))


def _literal_number(node) -> float | None:
    """The value of a numeric literal node (``2``, ``-0.5``), else None."""
    if isinstance(node, ast.Constant) and isinstance(node.value, (int, float)) and not isinstance(node.value, bool):
        return float(node.value)
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        v = _literal_number(node.operand)
        return None if v is None else (-v if isinstance(node.op, ast.USub) else v)
    return None


def _check(node, depth: int, names: list, text: str) -> None:
    """Walk ``node`` against the whitelist (module docstring); the names it reads go to ``names``."""
    where = f"in `{text[:60]}`"
    if depth > MAX_DEPTH:
        raise DerivedError(f"expression nested deeper than {MAX_DEPTH} levels")
    if isinstance(node, ast.Constant):
        if isinstance(node.value, bool) or not isinstance(node.value, (int, float)):
            raise DerivedError(f"only numbers may be literals {where}")
        if not math.isfinite(float(node.value)):
            raise DerivedError(f"non-finite literal {where}")
        return
    if isinstance(node, ast.Name):
        if node.id.startswith("_"):
            raise DerivedError(f"name `{node.id}` not allowed {where}")
        names.append(node.id)
        return
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        _check(node.operand, depth + 1, names, text)
        return
    if isinstance(node, ast.BinOp):
        if isinstance(node.op, ast.Pow):
            exp = _literal_number(node.right)
            if exp is None or abs(exp) > MAX_POWER:
                raise DerivedError(f"`**` needs a literal exponent of at most {MAX_POWER:g} {where}")
            _check(node.left, depth + 1, names, text)
            return
        if type(node.op) not in _BINARY:
            raise DerivedError(f"operator {type(node.op).__name__} not allowed {where} (use + - * / **)")
        _check(node.left, depth + 1, names, text)
        _check(node.right, depth + 1, names, text)
        return
    if isinstance(node, ast.Call):
        if not isinstance(node.func, ast.Name) or node.func.id not in _FUNCTIONS:
            raise DerivedError(f"only {', '.join(_FUNCTIONS)} may be called {where}")
        if node.keywords or len(node.args) != _FUNCTIONS[node.func.id][0]:
            raise DerivedError(f"`{node.func.id}` takes {_FUNCTIONS[node.func.id][0]} argument(s) {where}")
        for a in node.args:
            if isinstance(a, ast.Starred):
                raise DerivedError(f"`*` arguments not allowed {where}")
            _check(a, depth + 1, names, text)
        return
    raise DerivedError(f"{type(node).__name__} not allowed {where} (arithmetic on channels and numbers only)")


def _eval(node, values: dict):
    """Evaluate a checked node on ``values`` (name -> array or float)."""
    if isinstance(node, ast.Constant):
        return float(node.value)
    if isinstance(node, ast.Name):
        return values[node.id]
    if isinstance(node, ast.UnaryOp):
        v = _eval(node.operand, values)
        return -v if isinstance(node.op, ast.USub) else v
    if isinstance(node, ast.BinOp):
        left = _eval(node.left, values)
        if isinstance(node.op, ast.Pow):
            return np.power(np.asarray(left, dtype=np.float64), _literal_number(node.right))
        return _BINARY[type(node.op)](np.asarray(left, dtype=np.float64), _eval(node.right, values))
    if isinstance(node, ast.Call):
        _, fn = _FUNCTIONS[node.func.id]
        return fn(*[np.asarray(_eval(a, values), dtype=np.float64) for a in node.args])
    raise DerivedError(f"{type(node).__name__} not allowed")  # unreachable after _check



# -- a rig.toml's [derived] table against one run -----------------------------------------------
#: Most derived channels a rig.toml may state (rig.toml is untrusted: bounded work per batch).
MAX_DERIVED = 64


@dataclass
class DerivedChannel:
    """A rig.toml ``[derived]`` channel of one run: its column and where each name comes from."""

    name: str
    channel: str | None
    column: str
    unit: str | None
    expression: Expression
    inputs: dict            # name -> samples column (str) or metadata value (float)

    def describe(self) -> dict:
        """The channel as a ``channels`` table row (without ``run_id``)."""
        return {"column": self.column, "channel": self.channel, "raw_name": f"= {self.expression.text}",
                "raw_unit": None, "unit": self.unit, "type": "DOUBLE"}


def plan_derived(derived_cfg: dict, maps: list[ColumnMap], meta: dict,
                 time_column: bool) -> tuple[list[DerivedChannel], list[str]]:
    """Check rig.toml ``[derived]`` against a run: which channels it can compute.

    Names in an expression are, in this order: canonical channels (in SI), non-canonical
    channels by their sanitised raw name (as recorded), channels derived before it, numeric
    metadata values. A derived channel whose names the run does not have is skipped with a
    warning (its rig.toml may serve other files); a derived canonical channel that the file
    also carries is an error.
    """
    names: dict = {}
    for key, v in meta.items():
        if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(float(v)):
            names[key] = float(v)
    for m in maps:
        if m.numeric and m.channel is None:
            alias = sanitise_name(m.raw_name)
            if canonical_name(alias) is None:   # a look-alike `F[g]` is `f_g`, never `f`
                names[alias] = m.column
            names[m.column] = m.column
    for m in maps:
        if m.channel is not None:
            names[m.channel] = m.column
    if time_column:
        names["t"] = "t_s"
    taken = {m.column for m in maps} | ({"t_s"} if time_column else set())
    if len(derived_cfg or {}) > MAX_DERIVED:
        raise IngestError(f"rig.toml [derived] has {len(derived_cfg)} channels (at most {MAX_DERIVED})")
    out, warnings = [], []
    for name, entry in (derived_cfg or {}).items():
        unit = None
        text = entry
        if isinstance(entry, dict):
            unknown = sorted(set(entry) - {"expr", "unit"})
            if unknown or "expr" not in entry:
                raise IngestError(f"rig.toml [derived] `{name}` must be an expression or a table with `expr` "
                                  "(and optional `unit`)")
            text, unit = entry["expr"], entry.get("unit")
        try:
            expr = parse_expression(text)
        except DerivedError as exc:
            raise IngestError(f"rig.toml [derived] `{name}`: {exc}") from None
        channel = canonical_name(name)
        if channel is not None:
            column, unit = CHANNELS[channel].column, CHANNELS[channel].si_unit
        else:
            column = noncanonical_column(name, unit)
        if column in taken:
            raise IngestError(f"rig.toml [derived] `{name}`: the file already has channel `{channel or column}`")
        missing = [k for k in expr.names if k not in names]
        if missing:
            warnings.append(f"derived channel `{name}` not computed: no channel or numeric metadata "
                            + ", ".join(f"`{k}`" for k in missing))
            continue
        out.append(DerivedChannel(name, channel, column, None if unit is None else str(unit), expr,
                                  {k: names[k] for k in expr.names}))
        taken.add(column)
        names[channel or sanitise_name(name)] = column
        names[column] = column
    return out, warnings


__all__ = ["DerivedError", "DerivedChannel", "Expression", "parse_expression", "plan_derived", "MAX_LENGTH",
           "MAX_DEPTH", "MAX_POWER", "MAX_DERIVED"]
