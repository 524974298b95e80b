"""A strong hum nobody asked to remove is most of the noise the adhesion check weighs a dip against,
and a film's dip passes under it. Where the check let a dip or pull pass that a quieter noise could
fail, and a mains line dominates the tap's noise, the tap is analysed again with the hum removed
(issue 21: a mild-ooze tap accepted 5-10 µm high is a far-off tap with a small sigma)."""

import numpy as np
import pytest

from bench.tap_sweep import Case, _mains_hum, case_taps
from tapcell.tap import AnalysisOptions, analysis, analyze_tap, hum
from tapcell.tap.readers import tap_from_object

# The reference's mild-ooze taps with 5/2/2 g more hum at 50 or 60 Hz (`_mains_hum`, seed 1). Without
# the second look these were accepted (error µm): 12 +7.4, 31 +6.8, 45 +6.6 (a dip of 2-3 noise
# sigmas, under the 4 that reject), 42 +9.1 (no dip; the departure pulled 10.7 g below free air).
HIDDEN_BY_HUM = [12, 31, 42, 45]


@pytest.fixture(scope="module")
def hummed_ooze(reference_dir):
    case = Case("x", "", "either", reference=("ooze_mild", 1), transform=_mains_hum((5.0, 2.0, 2.0)))
    return case_taps(case, 1, 80, reference_dir)


@pytest.mark.parametrize("k", HIDDEN_BY_HUM)
def test_a_film_a_hum_hid_is_found_with_the_hum_removed(hummed_ooze, k):
    tap = tap_from_object(hummed_ooze[k][0])
    answer = analyze_tap(tap)
    assert (answer.valid, answer.error) == (False, "TAP_ADHESION"), answer.message
    # the analysis that found it is `auto`'s: the hum it removed is the case's 5 g line
    assert answer.hum["frequencies_hz"][0] in (50.0, 60.0) and 4.0 < answer.hum["amplitudes_g"][0] < 6.0


@pytest.mark.parametrize("k", HIDDEN_BY_HUM)
def test_the_users_hum_answer_is_kept(hummed_ooze, k):
    # `none` is the user's answer: no second look, and the film passes under the hum as before.
    tap = tap_from_object(hummed_ooze[k][0])
    first = analyze_tap(tap, AnalysisOptions(mains_hz=()))
    assert first.valid and first.hum is None
    assert first.passed_film_g >= analysis.FILM_HUM_LOOK_MIN_NOISE * first.noise_sigma_g


def test_a_strong_hum_on_a_clean_tap_leaves_it_measured(reference_dir):
    # The same hum on the reference's clean ADS1220 660 sps taps (71 of 80 look again, the worst
    # then 2.8 sigma off): every tap is still valid, and one that looked again within 3 sigma of the
    # truth, with the hum removed.
    case = Case("x", "", "accept", reference=("clean_ads1220_660", 1), transform=_mains_hum((5.0, 2.0, 2.0)))
    looked = 0
    for tap_object, z_mm in case_taps(case, 1, 20, reference_dir):
        answer = analyze_tap(tap_from_object(tap_object))
        assert answer.valid, answer.message
        if answer.hum is not None:
            looked += 1
            assert abs(answer.z_mm - z_mm) * 1000.0 < 3.0 * answer.z_sigma_um
    assert looked >= 15


def _sampled(amplitude_g, frequency_hz, noise_g=0.5, rate_sps=320.0, seconds=2.0, seed=3):
    rng = np.random.default_rng(seed)
    time_s = np.arange(int(rate_sps * seconds)) / rate_sps + 100.0
    force_g = amplitude_g * np.sin(2 * np.pi * frequency_hz * time_s + 0.4) + rng.normal(0.0, noise_g, len(time_s))
    return time_s, force_g


@pytest.mark.parametrize("frequency_hz", [50.0, 60.0])
def test_a_hum_far_above_the_noise_dominates_it(frequency_hz):
    assert hum.dominant_mains_lines(*_sampled(5.0, frequency_hz)) == (frequency_hz,)


def test_the_screen_reads_the_taps_end():
    # a long record: the hum in its first part only, then in its last DOMINANCE_MAX_SAMPLES only
    time_s, hummed_g = _sampled(5.0, 50.0, seconds=40.0)
    quiet_g = _sampled(0.0, 50.0, seconds=40.0)[1]
    end = len(time_s) - hum.DOMINANCE_MAX_SAMPLES
    assert hum.dominant_mains_lines(time_s, np.concatenate([hummed_g[:end], quiet_g[end:]])) == ()
    assert hum.dominant_mains_lines(time_s, np.concatenate([quiet_g[:end], hummed_g[end:]])) == (50.0,)


@pytest.mark.parametrize("amplitude_g", [0.0, 0.15])
def test_noise_or_a_weak_hum_does_not(amplitude_g):
    # 0.15 g on 0.5 g of noise: the screen sees the line (chi2 over its bar), but not as the noise
    assert hum.dominant_mains_lines(*_sampled(amplitude_g, 50.0)) == ()


def _first_tap(reference_dir, scenario):
    """The reference scenario's tap 0, as it is."""
    return tap_from_object(case_taps(Case("x", "", "either", reference=(scenario, 1)), 1, 1, reference_dir)[0][0])


def _refusing(what):
    """A stand-in that fails the test when called."""
    def refuse(*_args):
        raise AssertionError(what)
    return refuse


def test_no_screen_where_the_check_let_nothing_deep_pass(reference_dir, monkeypatch):
    # The reference's clean HX717 tap 0 (no hum added): its passed dip or pull lies under one noise
    # sigma, so the analysis never runs the screen.
    tap = _first_tap(reference_dir, "clean_hx717")
    monkeypatch.setattr(hum, "dominant_mains_lines", _refusing("screened"))
    answer = analyze_tap(tap)
    assert answer.valid and answer.passed_film_g < analysis.FILM_HUM_LOOK_MIN_NOISE * answer.noise_sigma_g


def test_a_heavy_ooze_a_hum_let_through_is_rejected(reference_dir):
    # The reference's heavy-ooze tap 36 with 10/3/3 g more hum (seed 2): accepted 34.6 µm high (a
    # silent failure) when the film check was judged against the hum.
    case = Case("x", "", "either", reference=("ooze_heavy", 1), transform=_mains_hum((10.0, 3.0, 3.0)))
    tap = tap_from_object(case_taps(case, 2, 37, reference_dir)[36][0])
    assert analyze_tap(tap, AnalysisOptions(mains_hz=())).valid
    assert analyze_tap(tap).error == "TAP_ADHESION"


# The reference's clean ADS1220 2000 sps taps with 20/5/5 g more hum (seed 2): rejected, their force's
# shape bent by a hum that dominates their noise; with it removed they read 0.74 / 0.49 / 0.45 / 0.02
# µm off (0.4-1.7 sigma).
BENT_BY_HUM = {7: "TAP_ADHESION", 12: "LOW_TAP_QUALITY", 13: "TAP_ADHESION", 19: "LOW_TAP_QUALITY"}


@pytest.fixture(scope="module")
def hummed_2000(reference_dir):
    case = Case("x", "", "accept", reference=("clean_ads1220_2000", 1), transform=_mains_hum((20.0, 5.0, 5.0)))
    return case_taps(case, 2, 20, reference_dir)


@pytest.mark.parametrize("k", sorted(BENT_BY_HUM))
def test_a_shape_a_dominant_hum_bent_is_measured_with_the_hum_removed(hummed_2000, monkeypatch, k):
    tap_object, z_mm = hummed_2000[k]
    answer = analyze_tap(tap_from_object(tap_object))
    assert answer.valid, answer.message
    assert answer.hum is not None and abs(answer.z_mm - z_mm) * 1000.0 < 2.0 * answer.z_sigma_um
    # looked at again only for the shape codes a hum can cause
    monkeypatch.setattr(analysis, "HUM_MAY_CAUSE", analysis.HUM_MAY_CAUSE - {BENT_BY_HUM[k]})
    assert analyze_tap(tap_from_object(tap_object)).error == BENT_BY_HUM[k]


def test_a_rejection_without_a_dominant_hum_is_not_looked_at_again(reference_dir, monkeypatch):
    # The reference's heavy-ooze tap 0 (no hum added): TAP_ADHESION, and no line dominates its noise.
    tap = _first_tap(reference_dir, "ooze_heavy")
    monkeypatch.setattr(analysis, "_second_look_without_hum", _refusing("looked again"))
    assert analyze_tap(tap).error == "TAP_ADHESION"
