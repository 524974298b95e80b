"""The baseline's random walk in the toe fit (tapcell.tap.toe.Wander).

A load cell's baseline wanders (temperature, a cable settling). Over the ~100 samples of a toe fit
a walk of a few g/sqrt(s) bends the baseline as much as the white noise shakes it, and a fit
that assumes white noise reads the bend as toe. The walk is estimated from the tap's free air
(approach and departure) and, where it matters, the fit weighs the samples by white + walk
covariance.
"""

from __future__ import annotations

import numpy as np
import pytest

from tapcell.tap import AnalysisOptions, analysis, analyze_tap, read_tap_file
from tapcell.tap.toe import (free_air_variogram, walk_beside_height_pull, wander_from_free_air,
                             wander_from_variograms, wanders_from_variograms)
from tapcell.taplab.generate import generate_set

TOE = AnalysisOptions(sensor_delay_s="halt", contact_model="toe")


def _free_air(rng, white_var: float, walk_var: float) -> list[np.ndarray]:
    """An approach of 80 and a departure of 120 samples: a sloped line, white noise and a walk."""
    return [3.0 + 0.02 * np.arange(n) + rng.normal(size=n) * np.sqrt(white_var)
            + np.cumsum(rng.normal(size=n)) * np.sqrt(walk_var) for n in (80, 120)]


@pytest.mark.parametrize("walk_var", [0.0, 0.05])
def test_wander_estimate_recovers_white_noise_and_walk(walk_var):
    # 40 seeds each, white 0.5 g^2: white 0.49 mean (0.05..0.83 per seed); walk 0.004 mean
    # (0..0.022) when there is none, 0.050 (0.008..0.154) for 0.05, where 3 of 40 seeds give no
    # estimate (the white share fitted <= 0).
    estimates = [wander_from_free_air(_free_air(np.random.default_rng(seed), 0.5, walk_var)) for seed in range(40)]
    found = [w for w in estimates if w is not None]
    assert len(found) >= 35
    assert 0.42 < np.mean([w.white_var_g2 for w in found]) < 0.56
    walk = np.mean([w.walk_var_g2 for w in found])
    assert walk < 0.009 if walk_var == 0.0 else 0.035 < walk < 0.065


def test_too_little_free_air_gives_no_estimate():
    assert wander_from_free_air([np.zeros(20), np.arange(10.0)]) is None  # lags of 4, 8, 12 need 36 samples


def test_weighing_the_walk_tightens_cable_drift_taps(tmp_path, monkeypatch):
    # Independent generator, cable drift (thermal walk 1-4 g/sqrt(s)), 12 taps on each of seeds
    # 11-16: rms error 0.54-0.93 um per seed with the walk weighed, 0.64-1.15 without; pooled
    # 0.78 against 0.89 (ratio 0.88; per seed 0.81-0.99).
    labels = {seed: generate_set(tmp_path / str(seed), seed=seed, taps_per_scenario=12, scenarios=["cable_drift"])
              for seed in range(11, 17)}

    def rms_error_um() -> float:
        errors = [(result.z_mm - label["z_contact"]) * 1000.0
                  for seed, batch in labels.items() for label in batch
                  if (result := analyze_tap(read_tap_file(tmp_path / str(seed) / label["file"])[0], TOE)).valid]
        assert len(errors) >= 60
        return float(np.sqrt(np.mean(np.square(errors))))

    # The walk's share alone: the drift held to the approach's in both runs (without the walk the
    # departure's slope is judged against white noise only, and taken more often: 0.80 um either way).
    monkeypatch.setattr(analysis, "toe_drift_g_um",
                        lambda dec, ps, motion, *walk: analysis.free_air_slope_g_um(dec, motion))
    weighed = rms_error_um()
    estimate = analysis.free_air_wanders  # the toe fit without the walk; the thread check keeps its own
    monkeypatch.setattr(analysis, "free_air_wanders", lambda *tap: (None, estimate(*tap)[1]))
    assert weighed < 0.93 * rms_error_um()


def test_walk_weighted_residuals_equal_dense_generalised_least_squares():
    # The recursion (differences, bidiagonal factor, pressed and free parts as sums) against the
    # textbook form: whiten with the Cholesky factor of the full covariance, project out the baseline.
    from tapcell.tap.toe import SUBSAMPLES, Wander, _rss_whitened, _Whitened, toe_shape

    rng = np.random.default_rng(3)
    x_lo = np.arange(-40.0, 50.0)  # a pullback at 1 um per sample, contact near 0
    window_um = x_lo[:, None] + (np.arange(SUBSAMPLES) + 0.5)[None] / SUBSAMPLES
    x_mid = x_lo + 0.5
    y = 4.0 * toe_shape(0.3 - window_um, 5.0, 0.5).mean(axis=1) + rng.normal(size=len(x_lo)) * 0.8
    wander = Wander(white_var_g2=0.6, walk_var_g2=0.05)
    contacts = np.linspace(-3.0, 10.0, 27)
    widths = np.full_like(contacts, 4.5)
    data = _Whitened.prepare(window_um, x_mid, y, wander, contacts[0], contacts[-1], 16.0)
    rss, stiffness = (values[0] for values in _rss_whitened(contacts, widths, (0.5,), data))

    order = np.arange(len(y), dtype=float)
    whiten = np.linalg.inv(np.linalg.cholesky(0.6 * np.eye(len(y)) + 0.05 * np.minimum.outer(order, order)))
    baseline = np.linalg.qr(whiten @ np.ones((len(y), 1)))[0]
    y_w = whiten @ y
    y_w -= baseline @ (baseline.T @ y_w)
    for c, w, r, k in zip(contacts, widths, rss, stiffness):
        h = whiten @ toe_shape(c - window_um, w, 0.5).mean(axis=1)
        h -= baseline @ (baseline.T @ h)
        k_dense = (h @ y_w) / (h @ h)
        assert k == pytest.approx(k_dense, rel=1e-9)
        assert r == pytest.approx(y_w @ y_w - k_dense * (h @ y_w), rel=1e-9)


def test_wanders_of_each_pooling_equal_their_own_estimates():
    # wanders_from_variograms pools the first variogram alone, the first two, ... in one pass: each
    # the same floats as its own wander_from_variograms.
    rng = np.random.default_rng(11)
    estimated = 0
    for walk_var in (0.0, 0.0, 0.05, 0.05, 0.5):
        variograms = [free_air_variogram(force_g) for force_g in _free_air(rng, 0.5, walk_var)]
        first, both = wanders_from_variograms(variograms)
        assert first == wander_from_variograms(variograms[:1])
        assert both == wander_from_variograms(variograms)
        estimated += first is not None and first != both
    assert estimated >= 3
    short = free_air_variogram(np.zeros(5))  # too short for a variogram: no rows
    assert wanders_from_variograms([short, variograms[1]]) == [None, wander_from_variograms(variograms[1:])]


def _crossed(rng, pull_g: float, walk_var: float) -> list[tuple]:
    """An approach of 300 samples 10 um apart in height and a departure of 200 samples 1 um apart,
    white noise of 1 g^2, a walk in time, and a pull that follows the height along a sine (2 mm a
    period: a bowden tube bending); as `walk_beside_height_pull` takes them, and the forces."""
    segments = []
    for samples, step_um, top_um in ((300, 10.0, 3000.0), (200, 1.0, 0.0)):
        height_um = top_um + (-step_um if top_um else step_um) * np.arange(samples)
        force_g = (pull_g * np.sin(np.pi * height_um / 1000.0) + rng.normal(size=samples)
                   + np.cumsum(rng.normal(size=samples)) * np.sqrt(walk_var))
        segments.append((free_air_variogram(force_g), samples, step_um))
    return segments


@pytest.mark.parametrize("walk_var", [0.0, 0.05])
def test_a_pull_curved_in_height_is_not_taken_for_a_walk(walk_var):
    # 40 seeds each. A 3 g pull that follows the height: pooled as a walk the estimate is 0.094-0.13
    # per sample (mean 0.108 with no walk, 0.148 over a walk of 0.05) and the white half of it;
    # told apart, the walk is 0.004 (0-0.020) with none and 0.054 (0-0.128) for 0.05, the same as
    # without the pull (0.0008 and 0.043), the white 0.96-1.02.
    for pull_g in (0.0, 3.0):
        found = [walk_beside_height_pull(_crossed(np.random.default_rng(seed), pull_g, walk_var)) for seed in range(40)]
        assert all(w is not None for w in found)
        walk = np.mean([w.walk_var_g2 for w in found])
        assert walk < 0.008 if walk_var == 0.0 else 0.03 < walk < 0.07
        assert 0.9 < np.mean([w.white_var_g2 for w in found]) < 1.08
    pooled = [wander_from_variograms([v for v, *_ in _crossed(np.random.default_rng(seed), 3.0, 0.0)])
              for seed in range(40)]
    assert min(w.walk_var_g2 for w in pooled) > 0.09  # the walk the toe fit took before


def test_the_toe_fits_walk_is_read_from_samples_taken_while_the_nozzle_rose():
    # The samples after the pullback stand at one height: a 6 g step of the baseline there is no
    # walk of the samples the toe fit weighs (with them in, the walk read 0.075 g^2 a sample here,
    # 0.006 without).
    from types import SimpleNamespace

    rng = np.random.default_rng(5)
    force_g = np.concatenate((0.02 * np.arange(300.0), np.zeros(300))) + rng.normal(size=600)
    dec = SimpleNamespace(start=0, stop=600, bounds=(300, 320, 340, 360))
    stepped = force_g + np.where(np.arange(600) >= 500, 6.0, 0.0)
    found = analysis.free_air_wanders(force_g, dec, (10.0, 1.0), 500)
    assert analysis.free_air_wanders(stepped, dec, (10.0, 1.0), 500) == found
    assert found[0].walk_var_g2 < 0.01
    assert analysis.free_air_wanders(stepped, dec, (10.0, 1.0), 600)[0].walk_var_g2 > 0.05


@pytest.mark.parametrize("scenario", ["clean_hx717", "latency", "hx711_10", "clean_ads1220_2000"])
def test_the_samples_read_while_rising_end_at_the_pullbacks_end(scenario):
    # The adhesion checks' samples: the pullback's read by the end of the pullback plus the delay.
    # At the split's own delay they end at the split's stop (`SplitTap.rising_stop`, which the free-air
    # walk's departure ends at too); at any other ("auto" reads the window at 0) by a search of their
    # own. Both against the definition, on taps with no delay, a pipeline's, 10 and 2000 sps.
    from tapcell.taplab.generate import SCENARIOS, make_tap
    from tapcell.tap.readers import tap_from_object

    ends = set()
    for k in range(3):
        rng = np.random.default_rng([1, list(SCENARIOS).index(scenario) + 1, k])
        tap = tap_from_object(make_tap(SCENARIOS[scenario].draw(rng), rng)[0])
        split, *_ = analysis.split_tap(tap, AnalysisOptions())
        motion, timing = split.motion, split.timing
        window = analysis.model_window(split.time_s, split.force_g, motion, timing, timing.delay_s, split.dec)
        samples = analysis.pullback_samples(window, motion, timing, timing.delay_s)
        pullback_time_s = window.time_s[len(window.time_s) - len(samples[2]):]
        for delay_s in (timing.delay_s, timing.delay_s + 0.6 * timing.sample_period_s, 0.0):
            rising = analysis.read_while_rising(samples, split, window, delay_s)
            kept = int(np.count_nonzero(pullback_time_s <= motion.pullback_end_s + delay_s))
            assert 0 < kept < len(samples[2])  # the pullback ends with samples on either side
            for part, whole in zip(rising, samples):
                assert np.array_equal(part, whole[:kept])
            ends.add(kept)
    assert len(ends) > 3


def test_the_walk_beside_the_pull_is_the_nonnegative_least_squares():
    # The closed form (Cramer's rule on the scaled normal equations, then the fits with a column
    # dropped) against scipy's NNLS on the same rows: 300 draws, walk and pull each present, absent
    # or pulled negative by the noise; equal to 1e-9 relative wherever NNLS keeps the white positive.
    from scipy.optimize import nnls

    from tapcell.tap.toe import _white_walk_pull

    rng = np.random.default_rng(2)
    compared = 0
    for _ in range(300):
        rows = rng.integers(6, 24)
        columns = np.column_stack((rng.uniform(1.0, 2.5, rows), rng.uniform(0.0, 40.0, rows),
                                   rng.uniform(0.0, 1e6, rows) ** 2))
        truth = np.array([1.0, rng.choice([0.0, 0.02, 0.2]), rng.choice([0.0, 1e-12, 1e-10])])
        measured = columns @ truth + rng.normal(size=rows) * rng.choice([0.01, 0.3])
        scale = np.sqrt((columns * columns).sum(axis=0))
        expected = nnls(columns / scale, measured)[0] / scale
        sums = columns.T @ columns
        found = _white_walk_pull(sums[0, 0], sums[0, 1], sums[0, 2], sums[1, 1], sums[1, 2], sums[2, 2],
                                 *(columns.T @ measured), float(measured @ measured))
        if not expected[0] > 0.0:
            continue
        compared += 1
        assert found == pytest.approx((expected[0], expected[1]), rel=1e-9, abs=1e-12)
    assert compared >= 250
