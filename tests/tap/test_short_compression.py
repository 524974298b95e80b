"""A compression shorter than one conversion window and one period (issue 21's sweep): no sample's
window lies wholly between the touch and the halt, so P2 lands anywhere in a window. The lag read
off it moved a reference tap averaged to 10 sps 15 µm low at z_sigma 0.7; the compression's fit put
contact on the way down hundreds of µm above the halt (TAP_CONTACT_MISMATCH on clean taps, or a
squeeze allowance of 20-800 µm in z_sigma_um). Now: no lag from the halt (0, as for an implausible
one, with the window in z_sigma_um), no contact-mismatch judged, no squeeze allowance from it."""

from __future__ import annotations

import math

import pytest

from bench.tap_sweep import CASES, analyse_in_process, case_taps
from tapcell.tap.analysis import compression_end_s, compression_places_the_halt, split_tap
from tapcell.tap.model import AnalysisOptions
from tapcell.tap.readers import tap_from_object

CASE = {case.name: case for case in CASES}


def _pressing_periods(tap: dict) -> float:
    split = split_tap(tap_from_object(tap), AnalysisOptions())[0]
    points, timing = split.dec.points, split.timing
    return (points[2][0] - points[1][0]) / timing.sample_period_s


def _error_um(answer: dict, z_mm: float) -> float:
    return (answer["z"] - z_mm) * 1000.0


def test_a_few_samples_of_compression_is_measured_with_its_own_sigma():
    """taplab's tap at 80 sps, 5 mm/s on a 10 g/µm bed (the sweep's `fewcontact`, seed 1): P1 to P2
    spans 1.40-1.76 periods on taps 0 and 2-5 (2.11 on tap 1). Before: z_sigma_um 59.6, 36.2,
    19.8 µm on taps 0, 2 and 3 (0.4-0.9 µm off; the squeeze allowance read from a compression fit
    on one sample) and a lag of 4.8-5.8 ms read off the halt. Now a delay of 0 and z_sigma 0.34-1.35 µm;
    errors -0.47..+0.33 µm. Tap 1 presses long enough and keeps its lag and Z."""
    taps = case_taps(CASE["fewcontact"], seed=1, count=6, reference_dir=None)
    for k, (tap, z_mm) in enumerate(taps):
        answer = analyse_in_process(tap)
        assert answer["valid"], (k, answer["message"])
        assert abs(_error_um(answer, z_mm)) < 0.6, k
        assert answer["z_sigma_um"] < 1.5, (k, answer["z_sigma_um"])
        short = _pressing_periods(tap) < 2.0  # one period + a window of one period
        assert short == (k != 1)
        assert (answer["sensor_delay_s"] == 0.0) == short, k
    answer = analyse_in_process(taps[1][0])
    assert answer["sensor_delay_s"] == pytest.approx(0.0036, abs=1e-4)
    assert _error_um(answer, taps[1][1]) == pytest.approx(-0.217, abs=0.01)


def test_the_predicate_counts_one_window_and_one_period():
    """taplab 80 sps, integration one period: 1.40 periods from P1 to P2 is short, 2.11 is not."""
    taps = case_taps(CASE["fewcontact"], seed=1, count=2, reference_dir=None)
    splits = [split_tap(tap_from_object(tap), AnalysisOptions())[0] for tap, _ in taps]
    assert [compression_places_the_halt(s.dec, s.motion, s.timing) for s in splits] == [False, True]
    assert splits[0].timing.integration_s == pytest.approx(splits[0].timing.sample_period_s)


def test_a_clean_tap_averaged_to_80_sps_is_not_a_contact_mismatch(reference_dir):
    """Reference clean_hx717 tap 14 averaged in blocks of 4 (the sweep's `ref_hx717x4`): 1.46
    periods from P1 to P2. Before: TAP_CONTACT_MISMATCH, "contact on the way down (753.8 um above
    the halt)". Now measured +1.18 µm off, z_sigma 1.26 µm."""
    (tap, z_mm) = case_taps(CASE["ref_hx717x4"], 1, 15, reference_dir)[14]
    assert _pressing_periods(tap) == pytest.approx(1.457, abs=0.01)
    answer = analyse_in_process(tap)
    assert answer["valid"], answer["message"]
    assert _error_um(answer, z_mm) == pytest.approx(1.18, abs=0.1)
    assert answer["z_sigma_um"] == pytest.approx(1.26, abs=0.1)


def test_a_tap_averaged_to_10_sps_reads_no_lag_off_its_halt(reference_dir):
    """Reference clean_hx717 averaged in blocks of 32 (`ref_hx717x32`, 10 sps, 32 µm of pullback a
    sample). Tap 12: before, a lag of 46 ms read off a 1.24-period compression put it 15.1 µm low
    at z_sigma 0.71 (21 σ). Now no lag: its Z, kept with the rejection, -0.40 µm. The tap is
    rejected for its pullback's step (`validate.PULLBACK_MAX_STEP_UM`), as every tap of the case is:
    before that rule its accepted taps lay within 1.1 σ, at z_sigma_um 9.2 (the conversion window's
    100 ms / √12 at 0.32 mm/s)."""
    taps = case_taps(CASE["ref_hx717x32"], 1, 20, reference_dir)
    answer = analyse_in_process(taps[12][0])
    assert answer["sensor_delay_s"] == 0.0
    assert _error_um(answer, taps[12][1]) == pytest.approx(-0.40, abs=0.1)
    assert answer["error"] == "TAP_DATA_INSUFFICIENT"
    assert answer["message"].startswith("the pullback moves 32.0 µm a sample")


def test_a_tap_averaged_to_10_sps_carries_its_conversion_window_in_its_sigma(reference_dir):
    """Reference HX711 80 sps averaged in blocks of 8 (`ref_slow10`, 10 sps, 8 µm of pullback a
    sample): no lag from the halt, and z_sigma_um at least the conversion window's 100 ms / √12 at
    0.08 mm/s (2.31 µm). Taps 0-7 measured -0.12 to +1.74 µm, z_sigma_um 2.39-2.57."""
    window_um = 0.08 * 1000.0 * 0.1 / math.sqrt(12.0)
    for k, (tap, z_mm) in enumerate(case_taps(CASE["ref_slow10"], 1, 8, reference_dir)):
        answer = analyse_in_process(tap)
        assert answer["valid"] and answer["sensor_delay_s"] == 0.0, k
        assert answer["z_sigma_um"] >= window_um, k
        assert abs(_error_um(answer, z_mm)) < answer["z_sigma_um"], k


def test_a_long_compression_still_reads_its_lag_and_judges_the_contacts(reference_dir):
    """The reference clean HX717 tap 0 (unaveraged: 2.5+ periods pressed) keeps its lag from the halt."""
    (tap, z_mm), = case_taps(CASE["ref_ramp5"], 1, 1, reference_dir)
    assert _pressing_periods(tap) > 2.0
    answer = analyse_in_process(tap)
    assert answer["valid"] and answer["sensor_delay_s"] > 0.0


def test_heavy_ooze_pressing_a_film_is_still_a_contact_mismatch():
    """taplab heavy ooze (seed 1, taps 0 and 7): the approach presses a film from 279 and 50 µm
    above the halt, 16.6 and 2.31 periods from P1 to P2: judged, and rejected as before."""
    from bench.tap_seeds import seed_tap

    for k, periods in ((0, 16.63), (7, 2.31)):
        tap, _ = seed_tap(1, "heavy_ooze", k)
        assert _pressing_periods(tap) == pytest.approx(periods, abs=0.01)
        answer = analyse_in_process(tap)
        assert answer["error"] == "TAP_CONTACT_MISMATCH", (k, answer["message"])


def test_a_one_sample_compression_ends_no_later_than_the_dwells_first_sample():
    """taplab at 20 g/µm and 5 mm/s (the sweep's `k20`, seed 3, tap 37): one sample (87.5 g) between
    free air and the dwell's 259 g. The split's compression line runs through a free-air sample and
    that one, a third as steep as the real one, and meets the dwell 6.1 ms after the halt, past the
    dwell's first sample (3.0 ms, already at 259.2 g). The lag read off P2, 4.5 ms, put the down
    contact 22 µm high at 5 mm/s, 28.0 µm above break contact (22.1 allowed): TAP_CONTACT_MISMATCH.
    Read off the dwell's first sample, 1.5 ms."""
    tap, z_mm = case_taps(CASE["k20"], seed=3, count=38, reference_dir=None)[37]
    split = split_tap(tap_from_object(tap), AnalysisOptions())[0]
    contact, peak = split.dec.bounds[:2]
    first_dwell_s = float(split.time_s[split.dec.start + peak])
    assert peak - contact == 2 and split.dec.points[2][0] - first_dwell_s > 0.003
    assert compression_end_s(split) == first_dwell_s
    answer = analyse_in_process(tap)
    assert answer["valid"], answer["message"]
    assert answer["sensor_delay_s"] == pytest.approx(0.00147, abs=5e-5)
    assert abs(_error_um(answer, z_mm)) < 1.0

