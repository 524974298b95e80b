"""TAP_PULLBACK_TOO_SHORT: the nozzle never left the bed during the pullback. It read as
TAP_BREAK_CONTACT_TOO_EARLY ("shorten pullback_distance": the opposite of the fix) or as a
chronology/shape error. Taps from tapcell.tap.synth (its own contact physics)."""

import pytest

from tapcell.tap import analyze_tap
from tapcell.tap.synth import synth_tap
from tapcell.tap.validate import STILL_PRESSING_SHARE, TapInvalid, check_left_the_bed


@pytest.mark.parametrize("pullback_mm", [0.005, 0.01, 0.015])
def test_a_pullback_shorter_than_the_springback_is_too_short(pullback_mm):
    # 4.6 g/um: the 75 g trigger plus the halt's overshoot press ~20 um; these pullbacks lift less.
    analysis = analyze_tap(synth_tap(pullback_distance_mm=pullback_mm, noise_g=0.5))
    assert analysis.error == "TAP_PULLBACK_TOO_SHORT"
    assert analysis.message.startswith("the nozzle still pressed the bed with ")
    assert "it never broke contact; lengthen pullback_distance" in analysis.message


def test_a_long_enough_pullback_passes_the_check():
    analysis = analyze_tap(synth_tap(pullback_distance_mm=0.1, noise_g=0.5))
    assert analysis.valid, analysis.message


def test_the_share_still_pressing():
    check_left_the_bed(pressed_g=150.0, remaining_g=150.0 * STILL_PRESSING_SHARE)  # at the limit: left
    check_left_the_bed(pressed_g=150.0, remaining_g=-20.0)  # ooze pulls the other way: left
    with pytest.raises(TapInvalid) as info:
        check_left_the_bed(pressed_g=150.0, remaining_g=12.0)
    assert info.value.code == "TAP_PULLBACK_TOO_SHORT"
    assert info.value.message.startswith("the nozzle still pressed the bed with 12g (8% of the 150g compression)")
