"""The result object's own behaviour: `TapAnalysis` keeps its fields in slots (issue 21, speed)."""

from __future__ import annotations

import copy
import dataclasses
import pickle
import weakref

import pytest
from native_kernel_inputs import generated_taps

from tapcell.tap import TapAnalysis, analyze_tap


@pytest.fixture(scope="module")
def analysed() -> list[TapAnalysis]:
    return [analyze_tap(tap) for tap in generated_taps(1)[:4]]


def test_an_analysed_tap_copies_pickles_and_replaces_to_an_equal_result(analysed):
    """What the pool (`bench probe_pool` copies results) and a user's own code do with a result."""
    assert any(result.valid for result in analysed)
    for result in analysed:
        for twin in (copy.copy(result), pickle.loads(pickle.dumps(result)), dataclasses.replace(result)):
            assert twin is not result
            assert twin == result
            assert twin.to_json() == result.to_json()
        assert weakref.ref(result)() is result


def test_a_misspelt_field_is_an_error_not_a_new_attribute(analysed):
    result = copy.copy(analysed[0])
    result.z_sigma_um = 1.5
    assert result.z_sigma_um == 1.5
    with pytest.raises(AttributeError):
        result.z_sigma = 1.5  # type: ignore[attr-defined]
    assert not hasattr(result, "__dict__")
