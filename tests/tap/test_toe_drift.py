"""The toe fit's free-air drift: the approach's, or the departure's own where the two disagree.

A bowden tube or a cable can pull on the toolhead in proportion to Z, and differently on the way
up than on the way down. The approach's drift then tilts the departure's baseline under the toe
and moves Z (`analysis.toe_drift_g_um`). Numbers: tapcell.tap.synth taps at 320 sps, 0.7 g
noise, 0.2 mm pullback, 20 seeds (measured: clean +0.52 ± 0.18 um, the same taps with a cable of
0.02 g/um down and -0.04 g/um up +0.55 ± 0.20 with the departure's drift, +1.44 ± 0.41 with the
approach's).
"""

from __future__ import annotations

import numpy as np
import pytest

from tapcell.tap import analysis, analyze_tap
from tapcell.tap.synth import synth_tap
from tapcell.tap.toe import Wander, fit_toe

SEEDS = range(20)


def _cable_tap(seed: int, down_g_um: float, up_g_um: float):
    """A synthetic tap with a cable pulling down_g_um per µm of height on the approach and
    up_g_um on the pullback (both from the halt's height: the force is continuous there)."""
    tap = synth_tap(seed=seed, sample_rate_sps=320.0, noise_g=0.7, pullback_distance_mm=0.2)
    height_um = (tap.z_mm - tap.z_mm.min()) * 1000.0
    pulling = np.where(tap.time_s < tap.events["pullback_start_time"], down_g_um, up_g_um)
    tap.force_g = tap.force_g + pulling * height_um
    return tap


def _errors_um(down_g_um: float, up_g_um: float) -> np.ndarray:
    errors = []
    for seed in SEEDS:
        tap = _cable_tap(seed, down_g_um, up_g_um)
        result = analyze_tap(tap)
        assert result.valid, result.message
        errors.append((result.z_mm - tap.truth["z_contact"]) * 1000.0)
    return np.array(errors)


def _approach_drift_only(monkeypatch):
    monkeypatch.setattr(analysis, "toe_drift_g_um",
                        lambda dec, ps, motion, *walk: analysis.free_air_slope_g_um(dec, motion))


def test_a_cable_pulling_differently_on_the_way_up_does_not_move_z(monkeypatch):
    clean = _errors_um(0.0, 0.0)
    cable = _errors_um(0.02, -0.04)
    # Measured shift +0.03 um (sd of the mean ~0.05): within 0.25 um of the same taps without a cable.
    assert abs(cable.mean() - clean.mean()) < 0.25
    _approach_drift_only(monkeypatch)
    tilted = _errors_um(0.02, -0.04)
    # The approach's drift under the departure reads it ~0.9 um high.
    assert tilted.mean() - clean.mean() > 0.6


@pytest.mark.parametrize("up_g_um, fitted", [(0.02, False), (-0.04, True)])
def test_the_departure_drift_is_fitted_only_where_the_approach_does_not_hold(monkeypatch, up_g_um, fitted):
    seen = []
    real = analysis.toe_drift_g_um

    def spy(*args):
        seen.append(real(*args))
        return seen[-1]

    monkeypatch.setattr(analysis, "toe_drift_g_um", spy)
    for seed in range(5):
        analyze_tap(_cable_tap(seed, 0.02, up_g_um))
    assert len(seen) == 5
    if fitted:
        assert all(drift is None for drift in seen)
    else:
        assert seen == pytest.approx([0.02] * 5, abs=0.005)


def _hinge_pullback(seed: int, drift_g_um: float):
    """Pullback samples of a hinge (contact at 0 µm, 4 g/µm) averaged over 1 µm windows, with a
    free-air drift and 0.5 g white noise."""
    rng = np.random.default_rng(seed)
    x_lo = np.arange(-30.0, 80.0, 1.0)
    x_hi = x_lo + 1.0
    pressed_lo, pressed_hi = np.maximum(-x_lo, 0.0), np.maximum(-x_hi, 0.0)
    force_g = (4.0 * (pressed_lo ** 2 - pressed_hi ** 2) / 2.0 + drift_g_um * 0.5 * (x_lo + x_hi)
               + rng.normal(0.0, 0.5, len(x_lo)))
    return x_lo, x_hi, force_g


def test_a_drift_to_fit_is_fitted_when_the_baseline_walks():
    # The walk-weighted fit has no drift column: a drift left to the fit (None) must not be dropped
    # there. 30 seeds, 0.3 g/um: +0.48 um with the drift fitted, +0.51 with it known; dropped, +0.29.
    walk = Wander(white_var_g2=0.25, walk_var_g2=0.05)
    assert walk.matters(100)
    fitted = [fit_toe(*_hinge_pullback(seed, 0.3), 0.0, 1.0, None, walk).contact_um for seed in range(30)]
    known = [fit_toe(*_hinge_pullback(seed, 0.3), 0.0, 1.0, 0.3, walk).contact_um for seed in range(30)]
    assert abs(np.mean(fitted) - np.mean(known)) < 0.1
