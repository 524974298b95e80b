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


# JSON-ready values as the analysis makes them, and beyond: every float (NaN, infinities, subnormals,
# 17-digit ones), short decimals like the rounded output's, ints of any size, any text.
SHORT_DECIMALS = st.builds(lambda m, e: m / 10.0**e, st.integers(-10**15, 10**15), st.integers(0, 22))
LEAVES = (st.none() | st.booleans() | st.integers() | st.integers(-2**70, 2**70) | st.floats() | SHORT_DECIMALS
          | st.text())
VALUES = st.recursive(LEAVES, lambda inner: st.lists(inner, max_size=5) | st.tuples(inner, inner)
                      | st.dictionaries(st.text(max_size=8), inner, max_size=5), max_leaves=30)


@settings(max_examples=1500, deadline=None)
@given(VALUES)
def test_json_text_writes_what_json_dumps_writes(value):
    assert model._C.json_text(value) == json.dumps(value)


@settings(max_examples=3000, deadline=None)
@given(st.floats() | SHORT_DECIMALS)
def test_json_text_writes_each_float_as_repr(value):
    assert model._C.json_text([value, -value]) == json.dumps([value, -value])


@pytest.mark.parametrize("value", [1e-4, 0.0001000000000000001, 9.999999999999999e-05, 1e15, 999999999999999.9,
                                   999999999999999.0, 123456789012345.6, 0.1 + 0.2, 1 / 3, 2.0**-1074, 1e300,
                                   5e-324, 230.0, 1382.691788481, -28267125.3997, 100.0, 1e14, 9.5, 0.5])
def test_json_text_at_the_short_decimals_edges(value):
    """Where repr turns to an exponent (1e-4, 1e16), around 15 and 17 significant digits, powers of ten."""
    assert model._C.json_text([value, -value]) == json.dumps([value, -value])


def _around_each_power_of_ten() -> list[float]:
    """Each power of ten where repr writes a plain decimal, its neighbouring doubles, and the
    decimals of 15 and 16 significant digits just below and above it: where the kernel counts
    the digits before the point (a count one off must only send the number to repr)."""
    import math

    values = []
    for exponent in range(-5, 17):
        power = float(f"1e{exponent}")
        values += [power, math.nextafter(power, 0.0), math.nextafter(power, math.inf),
                   float(f"9.99999999999999e{exponent - 1}"), float(f"1.00000000000001e{exponent}"),
                   float(f"9.999999999999999e{exponent - 1}"), float(f"1.000000000000001e{exponent}")]
    return values


def test_json_text_around_each_power_of_ten():
    values = _around_each_power_of_ten()
    assert model._C.json_text(values) == json.dumps(values)
    assert model._C.json_text([-v for v in values]) == json.dumps([-v for v in values])


def test_json_text_leaves_to_json_what_it_does_not_take():
    import numpy as np

    assert model._C.json_text([np.float64(0.1), True, 3]) == "[0.1, true, 3]"  # float64 is a float
    for value in ({1: 2}, [np.int64(3)], {"a": {1.5}}, object()):
        with pytest.raises(TypeError):
            model._C.json_text(value)


def test_analyze_writes_through_the_kernel_and_json_writes_the_rest():
    from tapcell.tap import cli

    result = {"file": "tap.json", **analyze_tap(synth_tap(seed=4)).to_json()}
    assert cli.json_text(result) == json.dumps(result) == model._C.json_text(result)
    assert cli.json_text({1: [2.5]}) == '{"1": [2.5]}'  # an int key: json's own rule, not the kernel's
