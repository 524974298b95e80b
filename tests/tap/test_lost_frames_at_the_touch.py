"""Frames lost in transport around the approach's touch (`analysis.approach_interval_s`): the way
down knows its contact only to within the gap they left. A burst of 3 over a reference HX717 tap's
3-4 sample compression (10 mm/s, 31 um a sample) put the down contact 33-70 um above break contact:
TAP_CONTACT_MISMATCH on 6 of 40 clean taps (`bench tap_sweep`'s ref_burst3h; Kalico, which reads
the pullback alone, 0), and the accepted ones' squeeze part blew z_sigma_um up to 45-62 um. Where
the burst took every compression sample, the five lines took the dwell's first samples for a
compression: TAP_CHRONOLOGY on 3 more; now the compression is the chord across the gap
(`analysis.frames_lost_at_the_halt`)."""

from __future__ import annotations

import numpy as np
import pytest

from bench.tap_sweep import analyse_in_process
from tapcell.tap import analysis


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
