"""The sigma parts' compiled kernel (tapcell.tap._c_uncertainty) against its twin
(tapcell.tap.uncertainty.tap_sigma_parts: the dozen small functions it stands for).

The kernel repeats the twin's operations in the same order (Python's max and min keep a NaN where
it comes first, x ** 2 is x * x, the squares summed first to last), so every part and the sum agree
bit for bit: on the calls the analysis makes, and on edge cases (None for every optional value,
no stiffness, a NaN pull, no pullback samples, a ringing over no samples in reach).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from native_kernel_inputs import OPTIONS, generated_taps, recorded_calls
from tapcell.tap import uncertainty
from tapcell.tap.stage import Ringing
from tapcell.tap.toe import PENETRATION_REACH_UM

pytestmark = pytest.mark.skipif(uncertainty._C is None, reason="the uncertainty kernel is not built (TAPCELL_NATIVE=0)")


def twin(monkeypatch, *args):
    with monkeypatch.context() as patch:
        patch.setattr(uncertainty, "_C", None)
        return uncertainty.tap_sigma_parts(*args)


def assert_bit_for_bit(found, reference):
    """The same parts and sum to the last bit (a NaN where the twin has one)."""
    (parts, total), (twin_parts, twin_total) = found, reference
    values = [*dataclasses.astuple(parts), total]
    twin_values = [*dataclasses.astuple(twin_parts), twin_total]
    assert [v.hex() for v in map(float, values)] == [v.hex() for v in map(float, twin_values)]
    assert type(parts) is uncertainty.ZSigmaParts


@pytest.fixture(scope="module")
def calls():
    """The arguments of every tap_sigma_parts the analysis of taplab's taps makes (every scenario:
    toe and sharp Z, threads, films, hum, the ringing gantry)."""
    return recorded_calls(uncertainty, "tap_sigma_parts", [OPTIONS["default"], OPTIONS["sharp"]],
                          generated_taps(3, 5))


def test_the_kernel_equals_the_twin_bit_for_bit_on_the_analysis_calls(monkeypatch, calls):
    assert len(calls) >= 60
    for call in calls:
        assert_bit_for_bit(uncertainty.tap_sigma_parts(*call), twin(monkeypatch, *call))
    # the comparison covers the parts that are not always there
    twins = [twin(monkeypatch, *call)[0] for call in calls]
    assert sum(p.thread_um > 0 for p in twins) >= 3
    assert sum(p.shape_um > 0 for p in twins) >= 10
    assert sum(p.ringing_um > 0 for p in twins) >= 1
    assert sum(p.squeeze_um > 0 for p in twins) >= 1


def _call(**changes):
    """A tap's arguments as the analysis passes them (a clean 320 sps tap: 60 pullback samples 2.5 µm
    apart), with `changes`."""
    x_lo = np.arange(60) * 2.5 - 20.0
    args = dict(x_lo_um=x_lo, x_hi_um=x_lo + 1.25, contact_um=12.0, stiffness_g_um=4.0, noise_um=0.6,
                shape_um=0.3, walk_var_g2=0.01, near_pull_g=0.8, far_pull_g=0.2, scatter_g=0.5, residual_g=0.9,
                step_g=0.1, down_um=14.0, up_um=12.0, allowance_um=0.5, toe_lift_um=1.2, window_staircase_um=0.4,
                z_step_um=2.5, delay_um=0.2, ringing=Ringing(0.5, 12.0), stage_um=0.0)
    args.update(changes)
    return tuple(args.values())


EDGE_CASES = {
    "a clean tap": {},
    "every optional value missing": dict(near_pull_g=None, far_pull_g=None, residual_g=None, step_g=None,
                                         down_um=None, up_um=None, ringing=None),
    "no far pull": dict(far_pull_g=None),
    "no stiffness": dict(stiffness_g_um=0.0),
    "a negative stiffness": dict(stiffness_g_um=-3.0),
    "a NaN stiffness": dict(stiffness_g_um=math.nan),
    "a NaN pull (Python's max keeps it)": dict(near_pull_g=math.nan),
    "a NaN contact down (squeeze and film NaN)": dict(down_um=math.nan),
    "a NaN step": dict(step_g=math.nan),
    "a step of 0": dict(step_g=0.0),
    "no Z step": dict(z_step_um=0.0),
    "a Z step above the reach": dict(z_step_um=500.0),
    "no pullback samples": dict(x_lo_um=np.zeros(0), x_hi_um=np.zeros(0)),
    "no sample in reach": dict(contact_um=1e4),
    "a ringing faster than the samples in reach": dict(ringing=Ringing(2.0, 3.0)),
    "a residual under the noise": dict(residual_g=0.1),
    "up above down": dict(up_um=30.0),
    "a negative toe lift": dict(toe_lift_um=-0.7),
    "an unnamed stage": dict(stage_um=8.5),
}


@pytest.mark.parametrize("changes", EDGE_CASES.values(), ids=EDGE_CASES.keys())
def test_the_kernel_equals_the_twin_on_edge_cases(monkeypatch, changes):
    assert_bit_for_bit(uncertainty.tap_sigma_parts(*_call(**changes)), twin(monkeypatch, *_call(**changes)))


def test_the_parts_are_what_the_functions_give():
    # A clean tap's parts by hand: the windows' middles are 2.5 k - 19.375, within the reach (30 µm) of
    # the contact at 12 for k = 1..24: 24 samples, over which a 12-sample period is 6 of its variance.
    assert PENETRATION_REACH_UM == 30.0
    parts, total = uncertainty.tap_sigma_parts(*_call())
    assert uncertainty.samples_in_reach(*_call()[:3]) == 24
    assert parts.thread_um == pytest.approx(math.sqrt(0.6 ** 2 - 0.01) / 4.0)
    assert parts.misfit_um == pytest.approx(math.sqrt(0.81 - 0.25 - 0.01) / 4.0)
    assert parts.squeeze_um == pytest.approx(1.5) and parts.film_um == pytest.approx(1.2)
    assert parts.floor_um == 0.25
    assert parts.ringing_um == pytest.approx(2.0 * math.sqrt(0.5 * 6.0 / 24) / 4.0)
    assert parts.staircase_um == pytest.approx(0.4 / math.sqrt(12.0))
    assert total == pytest.approx(uncertainty.z_sigma_um(parts))
    assert total > 1.25 * 0.6


def test_a_wrong_argument_is_an_error_not_garbage():
    args = list(_call())
    args[7] = "0.8"  # near_pull_g
    with pytest.raises(TypeError, match="near_pull_g"):
        uncertainty._C.tap_sigma_parts(args[0], args[1], args[2], 15.0, *args[3:19], None, None, 0.0,
                                       uncertainty._DEFAULT_WEIGHT_VALUES)
    with pytest.raises(ValueError, match="x_hi_um"):
        uncertainty.tap_sigma_parts(*_call(x_hi_um=np.zeros(3)))


def test_a_strided_or_integer_array_reads_as_the_twin_reads_it(monkeypatch):
    # every other sample of a longer pullback (not C-contiguous), and whole-µm heights as integers
    x_lo = np.arange(120) * 1.25 - 20.0
    strided = _call(x_lo_um=x_lo[::2], x_hi_um=(x_lo + 1.25)[::2])
    assert_bit_for_bit(uncertainty.tap_sigma_parts(*strided), twin(monkeypatch, *strided))
    integers = _call(x_lo_um=np.arange(60) * 2 - 20, x_hi_um=np.arange(60) * 2 - 19)
    assert_bit_for_bit(uncertainty.tap_sigma_parts(*integers), twin(monkeypatch, *integers))
