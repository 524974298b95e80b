"""z_sigma_um from the parts the tap shows (tapcell.tap.uncertainty, issue 21).

Numbers measured on tapcell.tap.synth taps, seeds 0-11 (660 sps, 4.6 g/µm, a sharp contact):
noise 0.5 g: noise part median 0.052 µm, sigma 0.23; noise 3 g: 0.302 µm, sigma 0.56. A 2 g strand
pulling over the first 30 µm of the departure (0.15 mm pullback): thread part 0.20-0.30 µm, sigma
median 0.68 against 0.23 for the same taps without it; a 1 g strand 0.00-0.17 µm, sigma 0.44.
taplab (seed 11, 10 taps a scenario): the accepted mild-ooze taps' squeeze part 0.44-7.19 µm, median
3.51 (1.44-5.68 on the five that read +2.7..+5.0 µm high), clean HX717's 0 on 8 of 10 taps, at most 0.99.
"""

import math

import numpy as np
import pytest

from tapcell.tap import analyze_tap, read_tap_file
from tapcell.tap.synth import synth_tap
from tapcell.taplab.generate import generate_set
from tapcell.tap.toe import TOE_WIDTHS_UM, WIDTH_PRIOR, marginal_contact_um
from tapcell.tap.uncertainty import (APPROACH_GRID_SHARE, SigmaWeights, ZSigmaParts, film_um, floor_um, misfit_um,
                                     squeeze_allowance_um, squeeze_um, staircase_um, thread_um, z_sigma_um)
from tapcell.tap.validate import CONSISTENCY_SIGMAS

SEEDS = range(8)


def _analyses(**changes):
    analyses = [analyze_tap(synth_tap(seed=seed, **changes)) for seed in SEEDS]
    assert all(a.valid for a in analyses), [a.error for a in analyses]
    return analyses


def test_the_parts_add_in_quadrature_each_weighed():
    parts = ZSigmaParts(noise_um=0.3, shape_um=0.4, thread_um=2.0, misfit_um=0.5, squeeze_um=1.5, film_um=0.8,
                        floor_um=0.25, staircase_um=0.12, delay_um=0.05)
    weights = SigmaWeights(noise=0.5, shape=2.75, misfit=0.0, thread=1.75, squeeze=2.0, film=1.5, floor=2.0)
    expected = math.sqrt(0.15 ** 2 + 1.1 ** 2 + 3.5 ** 2 + 3.0 ** 2 + 1.2 ** 2 + 0.5 ** 2 + 0.12 ** 2 + 0.05 ** 2)
    assert z_sigma_um(parts, weights) == pytest.approx(expected, rel=1e-12)
    # The analysis reports exactly the weighed sum of its own parts.
    analysis = analyze_tap(synth_tap(seed=1))
    assert analysis.z_sigma_um == pytest.approx(z_sigma_um(analysis.z_sigma_parts), rel=1e-12)


def test_sigma_grows_with_the_noise():
    quiet, noisy = _analyses(noise_g=0.5), _analyses(noise_g=3.0)
    quiet_noise = np.median([a.z_sigma_parts.noise_um for a in quiet])
    noisy_noise = np.median([a.z_sigma_parts.noise_um for a in noisy])
    # Six times the noise: the noise part grows in proportion (0.052 -> 0.302 µm, x5.8).
    assert 0.03 < quiet_noise < 0.08
    assert 4.5 < noisy_noise / quiet_noise < 7.5
    assert np.median([a.z_sigma_um for a in noisy]) > 1.8 * np.median([a.z_sigma_um for a in quiet])


def test_a_strand_letting_go_makes_the_sigma_larger():
    clean = _analyses(noise_g=0.5, pullback_distance_mm=0.15)
    pulled = _analyses(noise_g=0.5, pullback_distance_mm=0.15, pull_force_g=2.0, pull_length_um=30.0)
    assert max(a.z_sigma_parts.thread_um for a in clean) < 0.1
    threads = [a.z_sigma_parts.thread_um for a in pulled]
    assert 0.15 < min(threads) and max(threads) < 0.4  # 2 g over 4.6 g/µm, its median over the near reach
    # Measured 1.99x (the thread's part beside the rest); without the thread part ~1x.
    assert np.median([a.z_sigma_um for a in pulled]) > 1.6 * np.median([a.z_sigma_um for a in clean])


def test_the_shape_part_is_half_the_range_over_the_toe_shapes():
    analysis = analyze_tap(synth_tap(seed=3, contact_onset_um=6.0))
    grid = analysis.toe_grid
    widths = len(TOE_WIDTHS_UM)
    hertz, parabola = (marginal_contact_um(grid.contacts_um, grid.rss[k * widths:(k + 1) * widths], grid.noise_var,
                                           WIDTH_PRIOR)[0] for k in range(2))
    assert analysis.z_sigma_parts.shape_um == pytest.approx(0.5 * abs(hertz - parabola), rel=1e-12)
    assert analysis.z_sigma_parts.shape_um > 0.05
    # The noise part is the sharp fit's sigma over the same pullback.
    assert analysis.z_sigma_parts.noise_um == analysis.z_sharp_sigma_um


def test_thread_is_the_let_go_beyond_the_walk():
    # 4 g near, 1 g further up: 3 g let go over 3 g/µm = 1 µm; a walk of 5 g² between takes 4 of the 9.
    assert thread_um(4.0, 1.0, 0.0, 3.0) == pytest.approx(1.0)
    assert thread_um(4.0, 1.0, 5.0, 3.0) == pytest.approx(2.0 / 3.0)
    assert thread_um(4.0, 4.0, 0.0, 3.0) == 0.0  # a pull that stays is a baseline, not a thread
    assert thread_um(4.0, None, 0.0, 2.0) == pytest.approx(2.0)  # cannot tell: the whole pull
    assert thread_um(None, None, 0.0, 2.0) == 0.0


def test_misfit_is_what_the_noise_and_staircase_leave():
    # 5 g residual against 3 g noise and a 0 g staircase: 4 g, over 2 g/µm.
    assert misfit_um(5.0, 3.0, 0.0, 2.0) == pytest.approx(2.0)
    assert misfit_um(2.0, 3.0, 1.0, 2.0) == 0.0
    assert misfit_um(None, 3.0, 0.0, 2.0) == 0.0


def test_the_staircase_averages_over_the_steps_in_reach():
    # 2.5 µm steps: 30 µm of reach holds 12 of them.
    assert staircase_um(0.43, 2.5) == pytest.approx(0.43 / math.sqrt(12.0))
    assert staircase_um(0.43, 0.0) == 0.43


def test_squeeze_is_the_contact_mismatch_beyond_its_allowance():
    # Down 7 µm above the halt, up 3: 4 µm apart, 1.5 allowed.
    assert squeeze_um(7.0, 3.0, 1.5) == pytest.approx(2.5)
    assert squeeze_um(3.0, 7.0, 1.5) == 0.0  # down below up: a delay, not a film
    assert squeeze_um(None, 3.0, 1.5) == 0.0


def test_a_film_squeezed_on_taplab_mild_ooze_makes_the_sigma_larger(tmp_path):
    """Seed 11, 10 taps a scenario: the accepted mild-ooze taps that read over 2 um high (four,
    +2.2..+6.6 um) show a squeeze of 0.26-2.95 um and a film of 0.26-1.81, and their sigma is
    0.77-1.89 of their error (1.7-5.1 um). Clean HX717: no squeeze, no film, sigma under 2 um."""
    labels = generate_set(tmp_path, seed=11, taps_per_scenario=10, scenarios=["clean_hx717", "mild_ooze"])
    parts = {"clean_hx717": [], "mild_ooze": []}
    high = []  # the accepted taps that read over 2 µm high: (squeeze, film, sigma)
    for label in labels:
        analysis = analyze_tap(read_tap_file(tmp_path / label["file"])[0])
        if analysis.valid:
            p = analysis.z_sigma_parts
            parts[label["scenario"]].append((p.squeeze_um, p.film_um, analysis.z_sigma_um))
            error_um = (analysis.z_mm - label["z_contact"]) * 1000.0
            if error_um > 2.0:
                high.append((p.squeeze_um, p.film_um, analysis.z_sigma_um, error_um))
    assert len(parts["mild_ooze"]) >= 4 and np.median([s for s, _, _ in parts["mild_ooze"]]) > 1.0
    assert len(high) >= 3 and min(s for s, _, _, _ in high) > 0.1 and min(f for _, f, _, _ in high) > 0.1
    assert min(sigma / error for _, _, sigma, error in high) > 0.5  # each at least half its error
    assert max(s + f for s, f, _ in parts["clean_hx717"]) == 0.0
    assert max(sigma for _, _, sigma in parts["clean_hx717"]) < 2.0


def test_the_squeeze_allowance_holds_the_approach_grid():
    # Fits of 0.3 and 0.4 µm alone: 3 x 0.5 µm. A slow sensor's 25 µm a sample adds its grid share.
    assert squeeze_allowance_um(0.3, 0.4, 0.0) == pytest.approx(CONSISTENCY_SIGMAS * 0.5)
    grid_um = APPROACH_GRID_SHARE * 25.0
    assert squeeze_allowance_um(0.3, 0.4, 25.0) == pytest.approx(CONSISTENCY_SIGMAS * math.sqrt(0.25 + grid_um ** 2))


def test_the_film_is_at_most_the_squeeze_and_the_toe_lift():
    assert film_um(3.0, 1.2) == pytest.approx(1.2)
    assert film_um(0.5, -2.0) == pytest.approx(0.5)  # the lift's size, either way
    assert film_um(0.0, 4.0) == 0.0  # nothing squeezed: no film
    assert film_um(-1.0, 4.0) == 0.0


def test_the_floor_is_one_gram_over_the_stiffness():
    assert floor_um(4.0) == pytest.approx(0.25)
    assert floor_um(1.0) == pytest.approx(4.0 * floor_um(4.0))  # a bed 4x softer: 4x the height
    assert floor_um(0.0) == 0.0


def test_a_slow_approach_grid_is_not_read_as_a_squeezed_film(tmp_path):
    """taplab HX711 80 sps (25 µm of approach a sample, 1-3 samples in contact): the squeeze part
    was 2.5 µm rms without the grid's share (seed 1), while the errors were 0.75 µm rms."""
    labels = generate_set(tmp_path, seed=11, taps_per_scenario=10, scenarios=["hx711_80"])
    squeezes = []
    for label in labels:
        analysis = analyze_tap(read_tap_file(tmp_path / label["file"])[0])
        assert analysis.valid, analysis.message
        squeezes.append(analysis.z_sigma_parts.squeeze_um)
    assert math.sqrt(np.mean(np.square(squeezes))) < 1.0, squeezes
