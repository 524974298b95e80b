"""The floor of the contact height (tapcell.taplab.bound) on cases with a known answer."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from tapcell.taplab import bound
from tapcell.taplab.generate import SCENARIOS, RecordedMotion, draw_tap, make_tap, noise_free_samples, noise_record_length
from tapcell.taplab.sensor import SUBSAMPLES, convert, pink_noise


def _fisher_of_line(times: np.ndarray, noise_g: float, duplicate_slope: bool) -> np.ndarray:
    """J over NAMES for y = a + b t + white noise: `a` in the z_contact slot, b in stiffness's (and onset's)."""
    G = np.zeros((len(times), len(bound.NAMES)))
    G[:, 0] = 1.0
    G[:, 1] = times
    if duplicate_slope:
        G[:, 2] = times  # a second parameter moving the samples exactly like the first: degenerate
    return G.T @ G / noise_g ** 2


@pytest.mark.parametrize("duplicate_slope", [False, True])
def test_crb_of_a_straight_line_intercept_is_the_textbook_one(duplicate_slope):
    times = np.linspace(-1.0, 3.0, 41)
    noise_g = 0.7
    n = len(times)
    textbook = noise_g * np.sqrt(np.sum(times ** 2) / (n * np.sum(times ** 2) - np.sum(times) ** 2))
    J = _fisher_of_line(times, noise_g, duplicate_slope)
    unknown = ("z_contact_um", "stiffness_g_um", "onset_um") if duplicate_slope else ("z_contact_um", "stiffness_g_um")
    floor = bound.crb(J, unknown)
    assert floor.sigma_um == pytest.approx(textbook, rel=1e-9)
    assert floor.degenerate is duplicate_slope
    # With the slope known the intercept is a mean of n samples.
    assert bound.crb(J, ("z_contact_um",)).sigma_um == pytest.approx(noise_g / np.sqrt(n), rel=1e-9)


def test_walk_covariance_is_the_converted_walks():
    """Against brute force: the generator's own conversion applied to every fine step of the walk."""
    for sensor in ("hx717", "ads1220_660"):
        spec = draw_tap(np.random.default_rng(3), sensor, walk_g_per_sqrt_s=0.8)
        count = 12
        fine = (count + spec.adc.window_periods + 1) * SUBSAMPLES
        # sample values per unit step of the walk at each fine index: convert the step responses
        response = np.column_stack([convert((np.arange(fine) >= m).astype(float), spec.adc)[:count]
                                    for m in range(fine)])
        dt_s = spec.adc.period_s / SUBSAMPLES
        brute = spec.walk_g_per_sqrt_s ** 2 * dt_s * response @ response.T
        assert bound.walk_covariance(spec, count) == pytest.approx(brute, rel=1e-9)


def test_pink_covariance_matches_the_generators_noise():
    spec = draw_tap(np.random.default_rng(4), "hx717")
    _, record = noise_record_length(spec)
    rng = np.random.default_rng(5)
    draws = np.array([pink_noise(record, spec.adc.pink_g, rng)[:60] for _ in range(3000)])
    empirical = draws.T @ draws / len(draws)
    model = bound.pink_covariance(spec, 60)
    # correlation at lags 1, 10, 50: measured 0.00-0.04 below the model over six seeds of 3000 draws
    # (sampling, and the generator rescaling every draw to its rms, which the model leaves out)
    for lag in (1, 10, 50):
        measured = np.mean(np.diag(empirical, lag)) / np.mean(np.diag(empirical))
        assert measured == pytest.approx(model[0, lag] / model[0, 0], abs=0.06)
    assert model[0, 0] == pytest.approx(spec.adc.pink_g ** 2)


def _hx711_tap(k: int = 0):
    rng = np.random.default_rng([1, list(SCENARIOS).index("hx711_80") + 1, k])
    spec = SCENARIOS["hx711_80"].draw(rng)
    tap, _ = make_tap(spec, rng)
    return spec, RecordedMotion.of_tap(tap)


def test_bound_does_not_depend_on_the_finite_difference_step():
    spec, motion = _hx711_tap()
    floors = []
    for scale in (0.5, 2.0):
        J = bound.fisher(bound.sensitivities(spec, motion, step_scale=scale), spec, coloured=False)
        floors.append([bound.crb(J, unknown).sigma_um for unknown in bound.UNKNOWN_SETS.values()])
    assert floors[0] == pytest.approx(floors[1], rel=0.01)
    # the coloured Fisher information is the whitened samples' (the twins' distances use the whitener)
    G = bound.sensitivities(spec, motion)
    whitened = bound.whitener(spec, G.shape[0], coloured=True) @ G
    assert bound.fisher(G, spec, coloured=True) == pytest.approx(whitened.T @ whitened, rel=1e-6)
    # knowing more never loosens the floor
    assert floors[0] == sorted(floors[0], reverse=True)


def test_nothing_in_an_oozy_tap_depends_on_the_residual_film_alone():
    """The mild-ooze floor: move the bed down and the film (at the touch and after squeezing) up by
    the same amount, and every noise-free sample stays the same."""
    rng = np.random.default_rng([1, list(SCENARIOS).index("mild_ooze") + 1, 2])
    spec = SCENARIOS["mild_ooze"].draw(rng)
    tap, _ = make_tap(spec, rng)
    motion = RecordedMotion.of_tap(tap)
    lift_um = 1.5
    lifted_film = replace(spec, z_contact_mm=spec.z_contact_mm - lift_um / 1000, approach_mm=spec.approach_mm + lift_um / 1000,
                          ooze=replace(spec.ooze, film_um=spec.ooze.film_um + lift_um,
                                       film_residual_um=spec.ooze.film_residual_um + lift_um))
    bed_only = replace(lifted_film, ooze=spec.ooze)
    same = noise_free_samples(spec, motion)
    assert np.abs(noise_free_samples(lifted_film, motion) - same).max() < 1e-9
    assert np.abs(noise_free_samples(bed_only, motion) - same).max() > 1.0  # the bed alone shows


def test_pair_floor_is_the_bayes_error_of_two_gaussian_taps():
    """Against a direct simulation: one sample, N(0, 1) or N(d, 1), z 0 or `shift`, the posterior mean as the estimate."""
    rng = np.random.default_rng(6)
    shift = 1.5
    for distance in (0.0, 1.0, 2.5):
        z = rng.integers(0, 2, size=200_000)
        y = rng.normal(size=z.size) + distance * z
        posterior_1 = 1.0 / (1.0 + np.exp(-(distance * y - 0.5 * distance ** 2)))
        simulated = np.sqrt(np.mean((shift * posterior_1 - shift * z) ** 2))
        assert bound.pair_floor_um(shift, distance) == pytest.approx(simulated, rel=0.01)
    assert bound.pair_floor_um(shift, 0.0) == pytest.approx(shift / 2)


def test_a_twin_stays_in_the_ranges_and_is_no_farther_than_the_tap_itself_moved():
    spec, motion = _hx711_tap()
    ranges = bound.prior_ranges(SCENARIOS["hx711_80"], draws=300)
    twin = bound.nearest_twin(spec, motion, 1.0, ranges, iterations=3)
    for name, value in twin.parameters.items():
        assert ranges[name][0][0] <= value <= ranges[name][-1][1]
    # the tap itself with only z moved is the search's start (its parameters are inside the ranges here)
    moved = bound.PARAMETERS[0].shift(spec, 1.0)
    hum = bound.sensitivities(moved, motion)[:, len(bound.PARAMETERS):]
    difference = bound._samples(moved, motion) - bound._samples(spec, motion)
    difference -= hum @ np.linalg.lstsq(hum, difference, rcond=None)[0]
    start = np.linalg.norm(difference) / spec.adc.white_g
    assert 0.0 < twin.distance < start
    assert twin.floor_um == pytest.approx(bound.pair_floor_um(1.0, twin.distance))


def test_prior_information_of_a_smoothed_uniform_has_the_gaussian_limit():
    """Smoothed far more than its width, a uniform is a Gaussian of variance s² + L²/12: information 1/variance."""
    assert bound.smoothed_uniform_information([(0.0, 1.0, 1.0)], 3.0) == pytest.approx(1.0 / (9.0 + 1.0 / 12.0), rel=0.01)
    # and a narrow smoothing puts the information at the edges: ~ 2 c / (s L), more for less smoothing
    assert bound.smoothed_uniform_information([(0.0, 1.0, 1.0)], 0.01) > bound.smoothed_uniform_information(
        [(0.0, 1.0, 1.0)], 0.05) > 12.0
