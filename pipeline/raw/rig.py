"""``rig.toml``: reading one (size limit, TOML syntax, its tables), and merging the ones that
apply to a run (a subfolder's on top of its parent's).

A rig.toml over :data:`MAX_RIG_BYTES`, nested too deeply for the TOML parser, not TOML, or with
a table :data:`RIG_TABLES` does not name, is quarantined, and so is every run under it (the
metadata it was to give cannot be known: ingesting those runs with the remaining sources could
silently give them wrong metadata). So is a ``Rig.toml`` named in another case (the walk knows
it is not a run; unread, it would be a silent skip). Nothing here writes to the raw tree.
"""
from __future__ import annotations

import copy
import json
import tomllib
from pathlib import Path

from pipeline.raw.problems import ConfigError, Problem, os_reason
from pipeline.raw.rawfile import open_raw
from pipeline.readers.base import decode_text

#: Largest rig.toml read [bytes] (1 MiB: a real one is a few hundred bytes).
MAX_RIG_BYTES = 1 << 20

#: Tables a rig.toml may have (docs/inputs.md): each must be a table.
RIG_TABLES = ("read", "channels", "metadata", "sensors", "derived")


def deep_merge(base: dict, over: dict) -> dict:
    """``over`` on top of ``base``; nested tables merge key by key."""
    out = dict(base)
    for k, v in over.items():
        out[k] = deep_merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def read_rig(root: Path, f: Path) -> tuple[dict, str | None]:
    """One rig.toml (or the plan.toml, :mod:`pipeline.raw.plan`) parsed, opened from raw/
    without following a symlink out of it.

    Parameters
    ----------
    root : Path
        raw/, resolved.
    f : Path
        The rig.toml (its name is the one the size line gives).

    Returns
    -------
    (dict, str or None)
        Its tables, and why it cannot be used (too large, not TOML, unreadable) or None.
    """
    try:
        with open_raw(root, f) as opened:  # no symlink out of raw/ followed since the walk
            size = opened.size
            if size > MAX_RIG_BYTES:
                return {}, f"{size} bytes, larger than the {MAX_RIG_BYTES} bytes a {f.name} may have"
            return tomllib.loads(decode_text(opened.read_bytes())[0]), None
    except tomllib.TOMLDecodeError as exc:
        return {}, f"invalid TOML: {exc}"
    except (RecursionError, MemoryError):
        return {}, "invalid TOML: too deeply nested (arrays or inline tables inside each other)"
    except OSError as exc:
        return {}, f"cannot read: {os_reason(exc)}"


def bad_tables(cfg: dict) -> str | None:
    """Why a parsed rig.toml's tables cannot be used (one not in :data:`RIG_TABLES`, or one
    that is not a table), or None."""
    bad = [k for k in cfg if k not in RIG_TABLES]
    for k in RIG_TABLES:
        if k in cfg and not isinstance(cfg[k], dict):
            bad.append(k)
    if not bad:
        return None
    return (f"unknown or malformed table(s) {', '.join(sorted(set(bad)))} "
            f"(expected {', '.join(f'[{t}]' for t in RIG_TABLES)})")


class RigFiles:
    """The rig.toml files of a raw tree, each read once, merged once per folder.

    Parameters
    ----------
    tree : pipeline.raw.tree.RawTree
        The tree they are in: its paths (``real``, ``rel``, ``folders``), what the walk says
        about an entry (``entry_problem``, ``miscased``) and its ``problems``, where a rig.toml
        that cannot be used is recorded once.
    """

    def __init__(self, tree):
        self.tree = tree
        self._files: dict[Path, dict | ConfigError] = {}  # folder -> its rig.toml (or why not)
        self._merged: dict[Path, dict | ConfigError] = {}  # a run's folder -> the merged config
        self._json: dict[Path, str | ConfigError] = {}  # a run's folder -> the merged config as JSON

    def file(self, folder: Path) -> dict | ConfigError:
        """The tables of ``folder/rig.toml`` ({} when there is none), or a ConfigError when it
        cannot be used (its problem recorded once)."""
        if folder not in self._files:
            self._files[folder] = self._load(folder)
        return self._files[folder]

    def _load(self, folder: Path) -> dict | ConfigError:
        tree = self.tree
        f = tree.side_file(folder, "rig.toml")
        if f is None or isinstance(f, ConfigError):
            return {} if f is None else f
        cfg, msg = read_rig(tree.root, f)
        if msg is None:
            msg = bad_tables(cfg)
        if msg is not None:
            tree.problems.append(Problem(tree.rel(f), msg))
            return ConfigError(f"cannot use {tree.rel(f)}: {msg}")
        return cfg

    def config(self, path: Path) -> dict:
        """The merged rig.toml (``read``, ``channels``, ``metadata``, ``sensors``, ``derived``)
        that applies to a run (a copy: the caller may change it). Raises ConfigError when a
        rig.toml of its folder or above cannot be used."""
        folder = self.tree.real(path).parent
        cfg = self._merged.get(folder)
        if cfg is None:  # the same for every run of a folder: merged once
            cfg = {}
            for f in self.tree.folders(path):
                part = self.file(f)
                if isinstance(part, ConfigError):
                    cfg = part
                    break
                cfg = deep_merge(cfg, part)
            if not isinstance(cfg, ConfigError):
                cfg = {k: cfg.get(k, {}) for k in RIG_TABLES}
            self._merged[folder] = cfg
        if isinstance(cfg, ConfigError):
            raise cfg
        return copy.deepcopy(cfg)

    def config_json(self, path: Path) -> str:
        """:meth:`config` as canonical JSON (sorted keys), computed once per folder."""
        folder = self.tree.real(path).parent
        if folder not in self._json:
            try:
                self._json[folder] = json.dumps(self.config(path), sort_keys=True, default=str)
            except ConfigError as exc:
                self._json[folder] = exc
        out = self._json[folder]
        if isinstance(out, ConfigError):
            raise out
        return out

    def scan(self) -> None:
        """Read every rig.toml once so that a bad one is reported even if no run uses it."""
        for f in self.tree.side_files("rig.toml"):
            self.file(self.tree.real(f).parent)
