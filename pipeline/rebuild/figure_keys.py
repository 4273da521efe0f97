"""A stage figure keyed by its own inputs: a figure whose data did not change is not drawn again.

A stage that re-runs hands the rebuild every figure again as a recipe
(:class:`pipeline.stages.FigureRecipe`: ``func(*args, **kwargs)``), although most of them usually
show data that did not change (one changed leakage check re-runs ``plpa_characterisation``, whose
breakaway and viscous figures show other runs). :func:`figure_key` hashes what a figure's bytes
depend on: the plot function (module, name and the code version of its module and of the project
code it imports, :func:`pipeline.versions.function_code_version`), the content of its arguments
(:func:`content_hash`), the numerical and plotting libraries' versions and how the PNG is saved
(:data:`FIGURE_FORMAT`). The stage folder's ``output.json`` keeps each figure's key; the next run
of the stage takes a figure whose key is unchanged from the previous folder (a hard link: the
files are immutable) instead of drawing it (:func:`reusable_figures`). Drawing is deterministic
(no date or software in the PNG), so a reused file has the bytes a new drawing would have; a
``--full`` rebuild trusts no stored figure and draws them all.

The content hash is canonical: equal data give equal keys however they were built (computed
tonight or read back from the memo). What it cannot hash canonically it hashes as its pickle;
what cannot be pickled makes the figure keyless (drawn every time): a key is never equal for
figures whose inputs differ.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import pickle
import sys
from datetime import date, datetime, time, timedelta
from functools import lru_cache
from importlib import metadata
from pathlib import Path

from pipeline.rebuild.memo import environment
from pipeline.versions import function_code_version

#: How a stage figure is saved (``pipeline.rebuild.stage_store``); part of every key.
FIGURE_FORMAT = {"format": "png", "dpi": 110, "metadata": {"Software": None}, "key_version": 1}


class _Unkeyable(Exception):
    pass


@lru_cache(maxsize=1)
def plotting_environment() -> str:
    """Python and the libraries a figure's bytes depend on (part of every key)."""
    parts = [f"python {sys.version_info[0]}.{sys.version_info[1]}.{sys.version_info[2]}"]
    for name in ("numpy", "pandas", "matplotlib"):
        mod = sys.modules.get(name)  # else its installed version: not imported for a key (issue 26)
        try:
            parts.append(f"{name} {getattr(mod, '__version__', '?') if mod else metadata.version(name)}")
        except metadata.PackageNotFoundError:
            parts.append(f"{name} -")
    return "; ".join(parts)


def figure_key(recipe) -> str | None:
    """The key of a :class:`pipeline.stages.FigureRecipe` [64 hex digits]; None when it has none
    (a lambda or local function, a function without a module file, arguments that cannot be hashed)."""
    named = _named_call(recipe.func, (recipe.args, recipe.kwargs))
    if named is None:
        return None
    blob = json.dumps({**named, "env": plotting_environment(), "save": FIGURE_FORMAT}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()


def _named_call(func, args) -> dict | None:
    """``{"func": module:name, "code": its code version, "args": the content hash of args}`` of a
    call; None when it cannot be keyed (a lambda or local function, no module file, arguments
    that cannot be hashed)."""
    qualname, module = getattr(func, "__qualname__", "") or "", getattr(func, "__module__", "") or ""
    if not qualname or not module or "<" in qualname:
        return None
    code = function_code_version(func)
    if code is None:
        return None
    try:
        content = content_hash(args)
    except (_Unkeyable, RecursionError):
        return None
    return {"func": f"{module}:{qualname}", "code": code, "args": content}


def table_key(func, args: tuple) -> str | None:
    """The key of a pooled table ``func(*args)`` (:class:`pipeline.rebuild.stage_store.PooledTables`)
    [64 hex digits]: the function (module, name, code version), the content of its arguments and
    the numerical libraries' versions (:func:`pipeline.rebuild.memo.environment`); None when it has none."""
    named = _named_call(func, args)
    if named is None:
        return None
    blob = json.dumps({**named, "env": environment(), "key_version": 1}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()


def content_hash(value) -> str:
    """A canonical hash of ``value``'s content [64 hex digits]: numbers, strings, None, dates,
    lists, tuples, dicts (in their order), sets, dataclasses, numpy arrays and scalars, pandas
    DataFrames, Series and Index (names, dtypes, index and values). Raises ``_Unkeyable`` for what
    neither this nor pickle can represent."""
    h = hashlib.sha256()
    _feed(h, value)
    return h.hexdigest()


def _tag(h, tag: str, text: str = "") -> None:
    h.update(f"{tag}:{len(text)}:{text};".encode("utf-8", "surrogatepass"))


def _feed(h, value) -> None:
    import numpy as np
    import pandas as pd

    if value is None or isinstance(value, (bool, int, float, str, complex)):
        _tag(h, type(value).__name__, repr(value))  # repr: exact for floats, NaN and -0.0 included
    elif isinstance(value, bytes):
        _tag(h, "bytes", value.hex())
    elif isinstance(value, (datetime, date, time, timedelta, pd.Timestamp, pd.Timedelta, np.generic, Path)):
        _tag(h, type(value).__name__, repr(value))
    elif isinstance(value, (list, tuple)):
        _tag(h, type(value).__name__, str(len(value)))
        for v in value:
            _feed(h, v)
    elif isinstance(value, dict):
        _tag(h, "dict", str(len(value)))
        for k, v in value.items():  # in order: a plot may draw them in that order
            _feed(h, k)
            _feed(h, v)
    elif isinstance(value, (set, frozenset)):
        _tag(h, "set", " ".join(sorted(content_hash(v) for v in value)))
    elif isinstance(value, np.ndarray):
        _feed_array(h, value)
    elif isinstance(value, (pd.DataFrame, pd.Series, pd.Index)):
        _feed_pandas(h, value)
    elif dataclasses.is_dataclass(value) and not isinstance(value, type):
        _tag(h, "dataclass", f"{type(value).__module__}.{type(value).__qualname__}")
        for f in dataclasses.fields(value):
            _feed(h, f.name)
            _feed(h, getattr(value, f.name))
    else:
        try:
            _tag(h, f"pickle {type(value).__module__}.{type(value).__qualname__}",
                 pickle.dumps(value, protocol=5).hex())
        except Exception as exc:  # anything pickle refuses: no key, the figure is drawn
            raise _Unkeyable(type(value).__name__) from exc


def _feed_array(h, arr) -> None:
    _tag(h, "ndarray", f"{arr.dtype.str} {arr.shape}")
    if arr.dtype.hasobject:
        for v in arr.ravel(order="C"):
            _feed(h, v)
    else:
        import numpy as np

        h.update(np.ascontiguousarray(arr).tobytes())


def _feed_pandas(h, obj) -> None:
    import pandas as pd

    if isinstance(obj, pd.DataFrame):
        _tag(h, "DataFrame", str(obj.shape))
        _feed_pandas(h, obj.columns)
        _feed_pandas(h, obj.index)
        for i in range(obj.shape[1]):
            _feed_pandas(h, obj.iloc[:, i])
        return
    if isinstance(obj, pd.Series):
        _tag(h, "Series", str(len(obj)))
        _feed(h, obj.name)
        _feed_pandas(h, obj.index)
    else:
        _tag(h, type(obj).__name__, str(len(obj)))
        _feed(h, list(obj.names))
    _tag(h, "dtype", str(obj.dtype))
    values = obj.to_numpy(dtype=object) if not _plain(obj.dtype) else obj.to_numpy()
    _feed_array(h, values)


def _plain(dtype) -> bool:
    """Whether a pandas dtype is a plain numpy one whose bytes are its values."""
    import numpy as np

    return isinstance(dtype, np.dtype) and not dtype.hasobject


def reusable_figures(folder: Path | None) -> dict[str, Path]:
    """Figure key -> PNG file of a stage folder (the previous run of the stage), for the figures it
    keyed; empty without a folder or with a damaged ``output.json``."""
    if folder is None:
        return {}
    try:
        meta = json.loads((Path(folder) / "output.json").read_text())
        out = {}
        for v in (meta.get("figures") or {}).values():
            key, file = v.get("key"), v.get("file")
            if isinstance(key, str) and isinstance(file, str) and "/" not in file:
                path = Path(folder) / "figures" / file
                if path.is_file() and not path.is_symlink():
                    out[key] = path
        return out
    except (OSError, ValueError, TypeError, AttributeError):
        return {}
