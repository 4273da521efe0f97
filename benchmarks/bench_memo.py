"""Per-run memo benchmark: one changed run out of 10,000, the memo's own cost (no analysis).

One command::

    python -m benchmarks.bench_memo                     # 10,000 entries of ~35 KB (models at 10,000 runs)
    python -m benchmarks.bench_memo --memo-file old.py  # the same with another version of pipeline/rebuild/memo.py
                                                        # (e.g. ``git show <rev>:pipeline/rebuild/memo.py > old.py``)

A synthetic memo of ``--entries`` results of ``--kb`` KB each (random bytes: pickled arrays cost
the same to copy) is written once in a temp folder (``write all``: a ``--full`` rebuild's save).
Then a stage's run where one item changed is timed, ``--repeat`` times: ``map`` over every item
(all hits but one, the page cache warm) and ``save``. Printed: seconds, best of the repeats.
"""
from __future__ import annotations

import argparse
import importlib.util
import os
import sys
import tempfile
import time
from pathlib import Path

_PAYLOAD: dict[int, bytes] = {}


def result_of(item):
    """The "analysis": a result of ~``kb`` KB per item (the same bytes for the same item)."""
    i, kb = item
    if i not in _PAYLOAD:
        _PAYLOAD[i] = os.urandom(kb * 1024)
    return {"item": i, "data": _PAYLOAD[i]}


def _compute(func, items, label):
    return [func(it) for it in items]


def bench(memo_module, entries: int = 10_000, kb: int = 35, repeat: int = 3) -> dict[str, float]:
    """Seconds of ``save`` writing everything, and of a one-change run's ``map`` and ``save``."""
    out: dict[str, float] = {}
    with tempfile.TemporaryDirectory(dir=os.environ.get("TMPDIR")) as wh:
        items = [(i, kb) for i in range(entries)]
        m = memo_module.Memo(wh, "models", read=False)
        m.map(_compute, result_of, items)
        t0 = time.perf_counter()
        m.save()
        out["write all"] = time.perf_counter() - t0
        maps, saves = [], []
        for r in range(repeat):
            changed = list(items)
            changed[r * 7 % entries] = (entries + r, kb)  # a run's file changed: a new item
            m = memo_module.Memo(wh, "models")
            t0 = time.perf_counter()
            m.map(_compute, result_of, changed)
            maps.append(time.perf_counter() - t0)
            assert (m.hits, m.computed) == (entries - 1, 1), (m.hits, m.computed)
            t0 = time.perf_counter()
            m.save()
            saves.append(time.perf_counter() - t0)
            items = changed
        out["one change: map"] = min(maps)
        out["one change: save"] = min(saves)
        out["memo size MB"] = sum(f.stat().st_size for f in Path(wh, "memo").rglob("*.pkl")) / 1e6
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--entries", type=int, default=10_000)
    ap.add_argument("--kb", type=int, default=35)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--memo-file", type=Path, help="another version of pipeline/rebuild/memo.py to time")
    args = ap.parse_args(argv)
    if args.memo_file:
        spec = importlib.util.spec_from_file_location("memo_under_test", args.memo_file)
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
    else:
        import pipeline.rebuild.memo as mod
    res = bench(mod, args.entries, args.kb, args.repeat)
    print(f"memo {args.memo_file or 'pipeline/rebuild/memo.py'}: {args.entries} entries of {args.kb} KB")
    for k, v in res.items():
        print(f"  {k:18} {v:8.3f}" + ("" if k.endswith("MB") else " s"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
