"""A tap is rejected only for a cause it shows, with that cause's code (issue 21).

A cable or bowden that pulls one way while Z moves down and another while it moves up shifts the
whole pullback's force by a constant: the nozzle still leaves the bed inside the pullback, and the
contact model, which fits its own baseline, reads the same Z. Such a tap was rejected as
TAP_PULLBACK_TOO_SHORT (shifted up) or TAP_ADHESION (shifted down). A strand of ooze that pulls
on the nozzle as it leaves, and a pullback that ends with the nozzle still pressing, keep their
codes. Taps from tapcell.tap.synth (its own contact physics).
"""

import dataclasses

import pytest

from tapcell.tap import analyze_tap
from tapcell.tap.synth import synth_tap
from tapcell.tap.validate import STILL_PRESSING_SCATTERS, TapInvalid, check_left_the_bed

TRIGGER_G = 75.0


def _shifted_on_the_way_up(tap, shift_g: float):
    """The tap with every sample from the pullback's start on moved by shift_g (a cable reversing)."""
    pullback_start_s = tap.moves[-3].print_time
    force = tap.force_g.copy()
    force[tap.time_s >= pullback_start_s] += shift_g
    return dataclasses.replace(tap, force_g=force)


@pytest.mark.parametrize("seed", [0, 3])
@pytest.mark.parametrize("share", [0.2, 0.1, -0.1, -0.2])
def test_a_cable_pulling_another_way_on_the_way_up_is_measured(seed, share):
    # Before issue 21: +0.2 read TAP_PULLBACK_TOO_SHORT ("it never broke contact"), -0.1 and -0.2
    # TAP_ADHESION, though the nozzle left the bed a third of the way up.
    tap = synth_tap(seed=seed, noise_g=0.7, sample_rate_sps=320, pullback_distance_mm=0.2)
    plain = analyze_tap(tap)
    shifted = analyze_tap(_shifted_on_the_way_up(tap, share * TRIGGER_G))
    assert plain.valid and shifted.valid, shifted.message
    # The toe fits its own baseline: the shift moves Z by nothing (measured: < 1e-6 um).
    assert shifted.z_mm == pytest.approx(plain.z_mm, abs=1e-5 / 1000)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_strand_pulling_the_nozzle_is_still_adhesion(seed):
    # 20 g peaking 40 um above contact: the toe would read it as contact, +8.6..+9.8 um.
    analysis = analyze_tap(synth_tap(seed=seed, noise_g=0.7, sample_rate_sps=320, pull_force_g=20.0,
                                     pull_length_um=40.0))
    assert analysis.error == "TAP_ADHESION"


def test_a_shift_the_pullback_is_too_short_to_judge_stays_adhesion():
    # A 0.1 mm pullback ends ~70 um above contact: a strand that peaks 40 um up has not let go
    # there, so a constant departure offset cannot be told from it (seed 4: 7.5 g down).
    tap = synth_tap(seed=4, noise_g=0.7, sample_rate_sps=320, pullback_distance_mm=0.1)
    assert analyze_tap(tap).valid
    assert analyze_tap(_shifted_on_the_way_up(tap, -0.1 * TRIGGER_G)).error == "TAP_ADHESION"


def test_still_pressing_must_stand_clear_of_the_departures_scatter():
    # 8 % of the compression remaining is pressing on a quiet departure...
    with pytest.raises(TapInvalid) as info:
        check_left_the_bed(pressed_g=150.0, remaining_g=12.0, scatter_g=1.0)
    assert info.value.code == "TAP_PULLBACK_TOO_SHORT"
    # ... and a swing of the hum on a departure scattering 4 g (12 g < 4 x 4 g): not a cause.
    check_left_the_bed(pressed_g=150.0, remaining_g=12.0, scatter_g=4.0)
    assert STILL_PRESSING_SCATTERS == 4.0
