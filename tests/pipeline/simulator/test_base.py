"""The simulator's shared pieces, checked by hand: quantisation, sensors, time vectors, lags, JSON."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from pipeline.simulator.base import (ENCODER_M, SimRun, encoder, first_order_steps, jsonable, l_min_anr_to_kg_s,
                                     make_rng, pressure_sensor, quantise, time_vector)


def test_quantise_rounds_to_the_step_and_prints_short():
    got = quantise([3.4999e-5, 3.5001e-5, -1.2e-6, 0.0], 5e-6)
    assert got.tolist() == [3.5e-05, 3.5e-05, 0.0, 0.0]
    assert repr(float(got[0])) == "3.5e-05"          # 7 / 2e5, not 7 * 5e-6 = 3.5000000000000004e-05
    assert quantise([1.26, -1.24], 0.1).tolist() == [1.3, -1.2]
    assert quantise([7.0, 8.0], 3.0).tolist() == [6.0, 9.0]   # a step whose inverse is no integer
    assert not np.signbit(quantise([-1e-9], 1.0)).any()       # no negative zero in the text


def test_encoder_counts_5_um():
    assert ENCODER_M == 5e-6
    assert encoder([0.0123456, -2.4e-6]).tolist() == [0.012345, 0.0]


def test_pressure_sensor_adds_noise_and_logs_whole_pascals():
    p = pressure_sensor(np.full(10_000, 2e5), make_rng(1))
    assert np.array_equal(p, np.round(p))
    assert abs(p.mean() - 2e5) < 10 and 290 < p.std() < 310


def test_time_vector_is_t0_plus_k_over_fs():
    assert time_vector(4, 4.0, t0=1.0).tolist() == [1.0, 1.25, 1.5, 1.75]


def test_first_order_steps_follow_the_exact_exponential():
    t = np.array([0.0, 1.0, 2.0, 3.0])
    out = first_order_steps(t, [1.0, 2.0], [1.0, 0.0], initial=0.0, tau_s=1.0)
    at2 = 1.0 - math.exp(-1.0)                           # risen towards 1 for one tau
    assert out.tolist() == pytest.approx([0.0, 0.0, at2, at2 * math.exp(-1.0)])


def test_standard_litres_per_minute_to_mass_flow():
    # 60 l/min ANR = 1e-3 m3/s at 1.185 kg/m3 (ISO 8778)
    assert float(l_min_anr_to_kg_s(60.0)) == pytest.approx(1.185e-3, rel=2e-3)


def test_make_rng_takes_a_generator_a_seed_or_none():
    g = np.random.default_rng(5)
    assert make_rng(g) is g
    assert make_rng(5).random() == np.random.default_rng(5).random()
    assert make_rng(None).random() == np.random.default_rng(0).random()


def test_jsonable_gives_plain_python_and_null_for_non_finite():
    value = {1: (np.float64(1.5), np.arange(2)), "x": [np.int32(3), float("nan")], "b": np.bool_(True)}
    got = jsonable(value)
    assert got == {"1": [1.5, [0, 1]], "x": [3, None], "b": True}
    json.dumps(got)


def test_simrun_kind_is_the_metadata_kind():
    assert SimRun(data=None, metadata={"kind": "step"}).kind == "step"
