"""The two-stage fit's compiled kernel (tapcell.tap._c_stage) against its numpy twin (tapcell.tap.stage).

Inputs are the two-stage fits the analysis runs on taplab's taps (the two-stage mount, the soft
sheet, mild ooze: the taps whose toe is wide enough to be checked). Both
sides repeat the same arithmetic per grid point; only the sums of the weights over the grid run in
another order.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tapcell.tap import analysis, stage
from native_kernel_inputs import OPTIONS, generated_taps, recorded_calls

pytestmark = pytest.mark.skipif(stage._C is None, reason="the stage kernel is not built (TAPCELL_NATIVE=0)")

# The fit runs under a wide toe only: on most soft sheets, on the two-stage taps the ramp check above
# the contact did not already reject, and on some ooze.
SCENARIO_NAMES = ("two_stage", "soft_sheet", "mild_ooze")
# 20 each: 21 fits, 2 of them showing the two stages (16 each gave 2 of 17 fits while the toe fit's walk was the
# approach's and departure's pooled, 1 of 16 since the walk is told apart from a pull curved in height).
TAPS_EACH = 20


@pytest.fixture(scope="module")
def fits():
    """The arguments of every two_stage_fit the analysis of the taps runs."""
    calls = recorded_calls(stage, "two_stage_fit", [OPTIONS["default"]],
                           generated_taps(TAPS_EACH, 7, SCENARIO_NAMES))
    assert len(calls) >= 15
    # The fits on the free air's drift (sxx infinite: the drift's column out of every projection), 15
    # of the 32 here: the kernels must agree with their twins on those too.
    held = [call for call in calls if call[5:] == (True,)]
    assert len(held) >= 10, len(held)
    return calls


def test_the_soft_stage_ramp_equals_the_numpy_twin_bit_for_bit(monkeypatch):
    # The kernel sums the force's mean pairwise as numpy does: on taplab, the reference taps and
    # sessions (2,023 ramps) kernel and twin agree to the last bit.
    taps = generated_taps(3, 7, (*SCENARIO_NAMES, "clean_hx717", "cable_drift", "mains_hum"))
    calls = recorded_calls(analysis, "departure_soft_stage", [OPTIONS["default"]], taps)
    found = [stage.departure_soft_stage(*call) for call in calls]
    monkeypatch.setattr(stage, "_C", None)
    twins = [stage.departure_soft_stage(*call) for call in calls]
    assert [None if fit is None else dataclasses.astuple(fit) for fit in found] == [
        None if fit is None else dataclasses.astuple(fit) for fit in twins]
    assert sum(fit is not None for fit in twins) >= 10
    assert any(stage.shows_soft_stage(fit, 1.0, 0.0) for fit in twins if fit)  # a ramp clearly there, too


def _grid_inputs(x_um, force_g, contact_um, noise_var_g2, window_um, drift_held=False):
    """two_stage_fit's arguments as its grid takes them (the same steps as two_stage_fit)."""
    near = (x_um > contact_um - stage.TWO_STAGE_BELOW_UM) & (x_um < contact_um + stage.TWO_STAGE_ABOVE_UM)
    x, _, f, sxx, ff = stage._sorted_detrended(x_um[near], force_g[near], drift_held)
    spacing_um = float(np.median(np.diff(x)))
    shortest_um = max(stage.TWO_STAGE_MIN_SPAN_UM, stage.TWO_STAGE_MIN_SPAN_WINDOWS * max(window_um, spacing_um))
    return x, f, contact_um, sxx, ff, noise_var_g2, shortest_um


def _kernel_grid(x, f, contact_um, sxx, ff, noise_var_g2, shortest_um):
    return stage._C.two_stage_grid(x, f, stage.TWO_STAGE_HINGES_UM, stage.TWO_STAGE_SPANS_UM, contact_um, sxx, ff,
                                   float(x.mean()), noise_var_g2, shortest_um, stage.TWO_STAGE_MIN_SOFT_SHARE,
                                   stage.TWO_STAGE_MAX_SOFT_SHARE)


def test_the_grid_equals_the_numpy_twin(fits):
    # Measured on these taps and on taplab's, the reference taps' and sessions' 486 fits: the least
    # residual, noise, best span, its share and the hinge's gain bit for bit; the top's mean and sd
    # (weighted sums over 1,520 grid points in another order) to 1.5e-15 relative.
    answered = 0
    for call in fits:
        inputs = _grid_inputs(*call)
        if len(inputs[0]) < 2 * stage.STAGE_MIN_SAMPLES:
            continue
        twin, kernel = stage._two_stage_grid(*inputs), _kernel_grid(*inputs)
        assert (twin is None) == (kernel is None)
        if twin is None:
            continue
        answered += 1
        least, noise, top_mean, top_sd, span, share, hinge_gain = twin
        assert (kernel[0], kernel[1], kernel[4], kernel[5], kernel[6]) == (least, noise, span, share, hinge_gain)
        assert kernel[2] == pytest.approx(top_mean, rel=1e-13)
        assert kernel[3] == pytest.approx(top_sd, rel=1e-11, abs=1e-12)
    assert answered >= 15


def test_the_fit_answers_the_same_with_and_without_the_kernel(fits, monkeypatch):
    shown = 0
    fast = [stage.two_stage_fit(*call) for call in fits]
    monkeypatch.setattr(stage, "_C", None)
    for call, kernel in zip(fits, fast):
        twin = stage.two_stage_fit(*call)
        assert (twin is None) == (kernel is None)
        if twin is None:
            continue
        # The evidence is a difference of two residuals of the force's size over the noise: 4.4e-12
        # noise variances apart on these taps (the one-stage grid sums in another order).
        assert kernel.evidence_chi2 == pytest.approx(twin.evidence_chi2, abs=1e-9)
        assert dataclasses.astuple(kernel)[1:] == pytest.approx(dataclasses.astuple(twin)[1:], rel=1e-12, abs=1e-12)
        shown += stage.shows_two_stage(twin, call[2])
    assert shown >= 2  # the one-stage toe's grid ran too: the evidence passed the hinge's bound


def test_the_kernel_refuses_wrong_arrays():
    x = np.arange(30.0)
    with pytest.raises(ValueError):
        stage._C.two_stage_grid(x, x[:-1], stage.TWO_STAGE_HINGES_UM, stage.TWO_STAGE_SPANS_UM,
                                10.0, 1.0, 1.0, 15.0, 1.0, 5.0, 0.08, 0.5)
    with pytest.raises(TypeError):
        stage._C.two_stage_grid(x.astype(np.float32), x, stage.TWO_STAGE_HINGES_UM, stage.TWO_STAGE_SPANS_UM,
                                10.0, 1.0, 1.0, 15.0, 1.0, 5.0, 0.08, 0.5)


def test_the_one_stage_toe_grid_equals_the_numpy_twin(fits, monkeypatch):
    # The kernel takes the samples on the toe's linear part from prefix sums, the twin sums every
    # shape: on taplab's, the reference taps' and sessions' 34 grids 2.4e-15 of the force's sum of squares.
    calls = []
    for x_um, force_g, contact_um, *rest in fits:
        near = (x_um > contact_um - stage.TWO_STAGE_BELOW_UM) & (x_um < contact_um + stage.TWO_STAGE_ABOVE_UM)
        if np.count_nonzero(near) >= 2 * stage.STAGE_MIN_SAMPLES:
            calls.append((*stage._sorted_detrended(x_um[near], force_g[near], *rest[2:]), contact_um))
    kernel = [stage._one_stage_rss(*call) for call in calls]
    monkeypatch.setattr(stage, "_C", None)
    twins = [stage._one_stage_rss(*call) for call in calls]
    for call, fast, twin in zip(calls, kernel, twins):
        ff = call[4]
        assert abs(fast - twin) <= 1e-12 * ff
        assert twin < ff  # a toe explains part of every departure here: the grid is not empty
    assert len(calls) >= 15
