"""The JSON output's rounding kernel (c/output.c) against its twin, Python's round (model._round_num):
the same double, bit for bit, for every number, the half-way points and their neighbours included."""

from __future__ import annotations

import json
import math
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tapcell.tap import analyze_tap, model
from tapcell.tap.synth import synth_tap

pytestmark = pytest.mark.skipif(model._C is None, reason="output kernel not built")
DIGITS = st.integers(-4, 30)  # the output uses 2, 3, 4, 6 and 9; 23 and up, and negatives, take round() itself


def _bits(value):
    return None if value is None else struct.pack("=d", value)


def _same_as_round(value, digits):
    assert _bits(model._C.json_number(value, digits)) == _bits(model._round_num(value, digits)), (value, digits)


@settings(max_examples=3000, deadline=None)
@given(st.floats(), DIGITS)
def test_any_float_rounds_as_round_does(value, digits):
    _same_as_round(value, digits)


@settings(max_examples=3000, deadline=None)
@given(st.integers(-10**15, 10**15), st.integers(0, 15), st.integers(-3, 3))
def test_half_way_points_and_their_neighbours_round_as_round_does(k, digits, ulps):
    """(k + 1/2) / 10^digits and a few ulps either side: where the scaled value's own rounding could
    move the answer, the kernel must leave the decision to round()."""
    value = (k + 0.5) / 10.0**digits
    for _ in range(abs(ulps)):
        value = math.nextafter(value, math.copysign(math.inf, ulps))
    _same_as_round(value, digits)


@pytest.mark.parametrize("value", [0.0, -0.0, 5e-324, -5e-324, 2.675, 0.125, 0.375, -0.5, 1.5, 2.5,
                                   4503599627370495.5, 2.0**52, 1e22, 1e300, -1e-12, 1382.691788481123])
@pytest.mark.parametrize("digits", [0, 2, 3, 4, 6, 9, 22, 23])
def test_edges_round_as_round_does(value, digits):
    """Signed zeros, subnormals, exact ties (half to even), the largest exactly scaled values."""
    _same_as_round(value, digits)


def test_what_is_not_a_finite_number_is_none_and_other_numbers_are_floats():
    number = model._C.json_number
    assert [number(None), number(math.nan), number(math.inf, 4), number(-math.inf)] == [None] * 4
    assert number(1.23456789012) == 1.23456789 and number(True, 2) == 1.0 and number(3, 1) == 3.0
    assert type(number(3, 1)) is float
    with pytest.raises(TypeError):
        number("1.5", 2)
    with pytest.raises(OverflowError):  # as math.isfinite(10**400) in the twin
        number(10**400, 2)


def test_an_analysis_writes_the_same_json_with_the_kernel_and_without(monkeypatch):
    results = [analyze_tap(synth_tap(seed=seed)) for seed in range(3)]
    fast = [json.dumps(result.to_json()) for result in results]
    monkeypatch.setattr(model, "_num", model._round_num)
    assert [json.dumps(result.to_json()) for result in results] == fast
