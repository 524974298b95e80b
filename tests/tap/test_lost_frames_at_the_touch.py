"""Frames lost in transport around the approach's touch (`analysis.approach_interval_s`): the way
down knows its contact only to within the gap they left. A burst of 3 over a reference HX717 tap's
3-4 sample compression (10 mm/s, 31 um a sample) put the down contact 33-70 um above break contact:
TAP_CONTACT_MISMATCH on 6 of 40 clean taps (`bench tap_sweep`'s ref_burst3h; Kalico, which reads
the pullback alone, 0), and the accepted ones' squeeze part blew z_sigma_um up to 45-62 um. Where
the burst took every compression sample, the five lines took the dwell's first samples for a
compression: TAP_CHRONOLOGY on 3 more; now the compression is the chord across the gap
(`analysis.frames_lost_at_the_halt`)."""

from __future__ import annotations

from unittest.mock import ANY

import numpy as np
import pytest

from bench.tap_sweep import Case, _burst_dropped, analyse_in_process, case_taps
from tapcell.tap import AnalysisOptions, analysis, analyze_tap
from tapcell.tap.readers import tap_from_object


def test_the_interval_is_a_period_unless_frames_were_lost_around_the_touch():
    period_s, speed_mm_s = 0.003125, 10.0
    time_s = np.arange(200) * period_s
    halt_s = time_s[150] + 0.001
    touch_um = 3.5 * period_s * speed_mm_s * 1000.0  # 3.5 samples above the halt
    assert analysis.approach_interval_s(time_s, halt_s, touch_um, speed_mm_s, period_s) == period_s
    jittered = time_s + np.random.default_rng(1).uniform(-0.2, 0.2, len(time_s)) * period_s
    assert analysis.approach_interval_s(jittered, halt_s, touch_um, speed_mm_s, period_s) == period_s
    lost = np.delete(time_s, [147, 148, 149])  # the three samples before the halt
    assert analysis.approach_interval_s(lost, halt_s, touch_um, speed_mm_s, period_s) == pytest.approx(4 * period_s)
    far = np.delete(time_s, [100, 101, 102])  # lost long before the touch: not its concern
    assert analysis.approach_interval_s(far, halt_s, touch_um, speed_mm_s, period_s) == period_s


@pytest.mark.parametrize("k", [0, 7, 14, 4, 27, 31])
def test_a_clean_tap_that_lost_its_compression_frames_is_measured(sweep_tap, k):
    # Taps 0 and 7 were TAP_CONTACT_MISMATCH (down 56 and 49 um above up, 37 and 42 allowed);
    # tap 14 was accepted with a z_sigma_um of 45 um (its error 0.01 um); taps 4, 27 and 31 were
    # TAP_CHRONOLOGY (now -0.10, -0.35 and -0.68 um off at 0.61, 0.54 and 0.46 um).
    tap, z_mm = sweep_tap("ref_burst3h", 1, k)
    answer = analyse_in_process(tap)
    assert answer["valid"], answer["message"]
    assert answer["z_sigma_um"] < 2.0
    assert abs(answer["z"] - z_mm) * 1000.0 < 3.0 * answer["z_sigma_um"]


def test_with_the_nominal_period_the_same_taps_are_rejected(sweep_tap, monkeypatch):
    """The mechanism: the gap ignored."""
    monkeypatch.setattr(analysis, "approach_interval_s", lambda time_s, halt_s, down_um, speed, period_s: period_s)
    answer = analyse_in_process(sweep_tap("ref_burst3h", 1, 0)[0])
    assert answer["error"] == "TAP_CONTACT_MISMATCH"


@pytest.mark.parametrize("k", [4, 27, 31])
def test_without_the_chord_the_split_falls_out_of_time_order(sweep_tap, monkeypatch, k):
    """The mechanism: no compression across the gap."""
    monkeypatch.setattr(analysis, "frames_lost_at_the_halt", lambda time_s, halt_s, period_s: False)
    assert analyse_in_process(sweep_tap("ref_burst3h", 1, k)[0])["error"] == "TAP_CHRONOLOGY"


def test_frames_lost_at_the_halt_is_a_gap_before_the_first_sample_after_it():
    period_s = 0.003125
    time_s = np.arange(200) * period_s
    halt_s = time_s[150] - 0.001
    assert not analysis.frames_lost_at_the_halt(time_s, halt_s, period_s)
    assert analysis.frames_lost_at_the_halt(np.delete(time_s, [148, 149]), halt_s, period_s)
    assert not analysis.frames_lost_at_the_halt(np.delete(time_s, [145, 146]), halt_s, period_s)  # samples follow


# Frames lost up to the halt where the first split passed its checks (sixteenth session): its
# compression read wholly after the halt, from the dwell's first samples, and met the approach far
# before the touch (`analysis.split_across_the_gap_if_flatter`); or one pressed sample was left and
# the compression's fit found no contact, 0.02 g/um (`analysis.COMPRESSION_STIFFNESS_SHARE_MIN`).
# Measured on the reference taps, 80 a scenario, the 2-5 samples before the halt lost: 59
# TAP_CONTACT_MISMATCH of 2,400 taps before, 2 rejected after (soft sheets, LOW_TAP_QUALITY).


@pytest.mark.parametrize("name, k", [("ref_burst3h", 55), ("ref_burst3h", 78), ("ref_660burst3h", 57),
                                     ("ref_660burst3h", 65)])
def test_a_compression_read_after_the_halt_gives_way_to_the_chord(measured_within, sweep_tap, monkeypatch, name, k):
    measured_within(name, 1, k, 3.0)
    monkeypatch.setattr(analysis, "split_across_the_gap_if_flatter", lambda *args: args[-1])  # the first split kept
    assert analyse_in_process(sweep_tap(name, 1, k)[0])["error"] == "TAP_CONTACT_MISMATCH"


def test_a_compression_fit_that_found_no_contact_is_not_judged(measured_within, sweep_tap, monkeypatch):
    """Reference HX717 tap 42, 3 lost: its compression fit read 0.02 g/um against the pullback's 1.9."""
    measured_within("ref_burst3h", 1, 42, 3.0)
    monkeypatch.setattr(analysis, "COMPRESSION_STIFFNESS_SHARE_MIN", 0.0)
    assert analyse_in_process(sweep_tap("ref_burst3h", 1, 42)[0])["error"] == "TAP_CONTACT_MISMATCH"


def test_a_compression_that_kept_samples_before_the_gap_stays(reference_dir, monkeypatch):
    """A 2000 sps reference tap (29) with the one frame before the halt lost: its compression holds
    38 samples before the gap and is flatter than the chord from the last of them (0.42 of it); the
    chord would put the contact at that sample, deep in the compression (LOW_TAP_QUALITY)."""
    case = Case("x", "", "accept", reference=("clean_ads1220_2000", 1), transform=_burst_dropped(1, "halt"))
    tap, z_mm = case_taps(case, 1, 30, reference_dir)[29]
    answer = analyse_in_process(tap)
    monkeypatch.setattr(analysis, "split_across_the_gap_if_flatter", lambda *args: args[-1])
    assert analyse_in_process(tap) == {**answer, "elapsed_ms": ANY, "cpu_ms": ANY}
    assert answer["valid"] and abs(answer["z"] - z_mm) * 1000.0 < 3.0 * answer["z_sigma_um"]


@pytest.mark.parametrize("scenario", ["clean_hx717", "clean_ads1220_660", "hx711_slow"])
def test_no_clean_tap_is_rejected_for_three_frames_lost_at_the_halt(reference_dir, scenario):
    """80 taps a scenario, the 3 samples before the halt lost: 4, 2 and 9 TAP_CONTACT_MISMATCH before."""
    case = Case("x", "", "accept", reference=(scenario, 1), transform=_burst_dropped(3, "halt"))
    answers = [analyse_in_process(tap) for tap, _ in case_taps(case, 1, 80, reference_dir)]
    assert len(answers) == 80
    assert [a["error"] for a in answers if not a["valid"]] == []


@pytest.mark.parametrize("k", [4, 17, 28])
def test_a_lagged_compression_read_after_the_halt_stays(reference_dir, monkeypatch, k):
    """The reference latency taps (each reading handed over 1-2 samples late) with the 4 samples
    before the halt lost: the compression is read wholly after the halt, and it is steeper than the
    chord (2.5, 2.8 and 2.8 times): the rise itself, late. The chord in its place read the 80 taps
    +0.61 ± 0.76 um, against +0.25 ± 0.60 as they are."""
    case = Case("x", "", "accept", reference=("latency", 1), transform=_burst_dropped(4, "halt"))
    tap, z_mm = case_taps(case, 1, k + 1, reference_dir)[k]
    answer = analyse_in_process(tap)
    assert answer["valid"] and abs(answer["z"] - z_mm) * 1000.0 < 3.0 * answer["z_sigma_um"]
    monkeypatch.setattr(analysis, "split_across_the_gap_if_flatter", lambda *args: args[-1])
    assert analyse_in_process(tap) == {**answer, "elapsed_ms": ANY, "cpu_ms": ANY}


def test_without_a_contact_down_the_line_point_is_not_judged_either(reference_dir, monkeypatch):
    """A reference ADS1220 660 tap (5) with the 4 samples before the halt lost: its compression fit
    found no contact, and the line point P1, from the same lone pressed sample, lay 463 um above the
    halt (break contact: 49 um)."""
    case = Case("x", "", "accept", reference=("clean_ads1220_660", 1), transform=_burst_dropped(4, "halt"))
    tap, z_mm = case_taps(case, 1, 6, reference_dir)[5]
    answer = analyse_in_process(tap)
    assert answer["valid"] and abs(answer["z"] - z_mm) * 1000.0 < 3.0 * answer["z_sigma_um"]
    judged = analysis.check_contact_heights
    monkeypatch.setattr(analysis, "check_contact_heights",
                        lambda window, pullback, compression, motion, timing, placed:
                        judged(window, pullback, compression, motion, timing, True))
    assert analyse_in_process(tap)["error"] == "TAP_CONTACT_MISMATCH"


def test_a_compression_fit_with_no_contact_gives_no_delay(sweep_tap):
    """With `sensor_delay_s=auto` the delay comes from the way down's contact against the way up's:
    the 0.02 g/um fit of reference HX717 tap 42 (3 lost) made it -37 ms and put Z 12 um high."""
    tap, z_mm = sweep_tap("ref_burst3h", 1, 42)
    answer = analyze_tap(tap_from_object(tap), AnalysisOptions().with_overrides({"sensor_delay_s": "auto"}))
    assert answer.valid and answer.sensor_delay_s == 0.0
    assert abs(answer.z_mm - z_mm) * 1000.0 < 3.0 * answer.z_sigma_um


def test_no_compression_stiffness_is_scored_with_the_deepest_part_lost(reference_dir):
    """A reference noisy-mains tap (44) with the 2 samples before the halt lost: the two pressed
    samples left are the compression's shallowest, its fit 1.45 g/um against the pullback's 6.06
    (the whole tap: 5.40), the classifier's stiffness mismatch 197 % (LOW_TAP_QUALITY)."""
    case = Case("x", "", "accept", reference=("noisy_mains", 1), transform=_burst_dropped(2, "halt"))
    tap, z_mm = case_taps(case, 1, 45, reference_dir)[44]
    answer = analyse_in_process(tap)
    assert answer["valid"] and abs(answer["z"] - z_mm) * 1000.0 < 3.0 * answer["z_sigma_um"]
    assert answer["stiffness_compression_g_um"] is None and "stiffness" not in answer["quality_components"]


def test_no_film_is_read_off_a_contact_down_in_a_gap(reference_dir):
    """A reference bowden tap (1) with the 3 samples before the halt lost: its down contact, somewhere
    in the gap, lay 56 um above the up one (51 % of the way to a mismatch), and with the cable's
    level 15.5 g below the approach's the pressed-film rule read a film (TAP_ADHESION)."""
    case = Case("x", "", "accept", reference=("bowden_drift", 1), transform=_burst_dropped(3, "halt"))
    tap, z_mm = case_taps(case, 1, 2, reference_dir)[1]
    answer = analyse_in_process(tap)
    assert answer["valid"] and abs(answer["z"] - z_mm) * 1000.0 < 3.0 * answer["z_sigma_um"]
