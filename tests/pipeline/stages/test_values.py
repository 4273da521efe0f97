"""The one "finite number or None" of the stages, and a run's params as a dict."""
import math

import numpy as np
import pytest

from pipeline.stages.values import finite_float, run_params


@pytest.mark.parametrize("value, expected", [
    (1, 1.0), ("2.5", 2.5), (np.float64(3.0), 3.0), (np.int64(4), 4.0), (True, 1.0),
    (None, None), ("", None), ("abc", None), (math.nan, None), (np.float32("nan"), None), (math.inf, None),
    (-math.inf, None), ([1], None), ({}, None),
])
def test_finite_float_is_a_finite_float_or_none(value, expected):
    got = finite_float(value)
    assert got == expected and (got is None or type(got) is float)


def test_finite_float_gives_its_default_for_what_is_not_a_finite_number():
    assert finite_float(None, 50.0) == 50.0 and finite_float(math.nan, 40.0) == 40.0 and finite_float(0, 50.0) == 0.0


@pytest.mark.parametrize("value, expected", [
    ({"a": 1}, {"a": 1}), ('{"a": 1}', {"a": 1}), ("not json", {}), (None, {}), (math.nan, {}),
])
def test_run_params_is_a_dict(value, expected):
    assert run_params(value) == expected
