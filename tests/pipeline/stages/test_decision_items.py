"""pipeline/stages/decision_items.py: a hose type as plain data and back, times to the nanosecond."""
import pandas as pd

from pipeline.stages import decision_items as di


def test_columns_picked_and_read_back_keep_every_value_and_time_to_the_nanosecond():
    t = pd.Series(pd.to_datetime(["2026-03-01T08:00:00.000000123Z", None, "2026-03-02T09:30:00Z"], utc=True, format="ISO8601"))
    df = pd.DataFrame({"hose_id": ["b", "a", None], "started_at": t, "duration_h": [1.5, float("nan"), 2.0],
                       "distance_km": [1.0, 2.0, 3.0]})
    cols = di._columns(df, di.RUN_SPEC)
    assert cols["started_at"][0] % 1000 == 123 and cols["started_at"][1] in (None, di._NAT) and cols["hose_id"][2] is None
    back = di._frame(di._pick(cols, [2, 0]), di.RUN_SPEC)
    assert list(back.columns) == list(di.RUN_SPEC) and back["hose_id"].tolist() == [None, "b"]
    assert back["started_at"].tolist() == [t[2], t[0]] and str(back["started_at"].dt.tz) == "UTC"
    assert back["duration_h"].tolist() == [2.0, 1.5]
