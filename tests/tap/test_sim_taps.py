"""The classifier on virtual-printer taps: clean ones accepted, fouled ones rejected; the misfit floor."""

from __future__ import annotations

import math

import pytest

from tapcell.tap import AnalysisOptions, analyze_tap
from tapcell.tap.analysis import step_staircase_sigma_um
from tapcell.sim.taps import SimTapSpec, record_sim_tap


def test_step_staircase_sigma_matches_the_sawtooth_average():
    sawtooth = 2.5 / math.sqrt(12)
    assert step_staircase_sigma_um(2.5, 0.0) == pytest.approx(sawtooth)
    assert step_staircase_sigma_um(2.5, 1.0) == pytest.approx(0.6 * sawtooth)  # (1 - 1/2.5)
    assert step_staircase_sigma_um(2.5, 2.5) == pytest.approx(0.0, abs=1e-12)
    # 4 µm = one whole step + 1.5 µm: (1.5/4)(1 - 1.5/2.5) of the sawtooth (numerically 0.1082 µm)
    assert step_staircase_sigma_um(2.5, 4.0) == pytest.approx(0.10825, abs=1e-4)
    assert step_staircase_sigma_um(0.0, 1.0) == 0.0


@pytest.mark.parametrize("speed_mm_s", [2.0, 5.0, 10.0])
def test_clean_virtual_taps_are_accepted_and_accurate(speed_mm_s):
    for seed in range(4):
        tap = record_sim_tap(SimTapSpec(speed_mm_s=speed_mm_s, seed=seed, pullback_distance_mm=0.1))
        result = analyze_tap(tap)
        sharp = analyze_tap(tap, AnalysisOptions(contact_model="sharp"))
        assert tap.truth["label"] == "clean"
        assert result.valid, result.message
        assert result.quality > 80.0
        # The toe model over 20 seeds: +0.55 ± 0.42 / +0.12 ± 0.31 / +0.17 ± 0.31 µm at 2 / 5 / 10 mm/s
        # (every tap within -0.40 ... +1.47).
        assert -1.3 < (result.z_mm - tap.truth["z_contact"]) * 1000 < 2.2
        # The sharp model reads the sim's 2 µm smooth-PEI onset onset/2 low, and the halt lag a little
        # lower (10 seeds: -1.24 ± 0.10 / -1.54 ± 0.14 / -1.64 ± 0.14 µm).
        assert -2.2 < (sharp.z_mm - tap.truth["z_contact"]) * 1000 < -0.9
        # Step staircase at 3.26 g/µm, 2.5 µm steps, 1 µm windows: 3.26 × 0.6 × 0.7217 = 1.41 g.
        assert result.step_sigma_g == pytest.approx(1.41, abs=0.02)


def test_stiffness_is_scored_only_when_the_compression_was_sampled():
    slow = analyze_tap(record_sim_tap(SimTapSpec(speed_mm_s=2.0, pullback_distance_mm=0.1)))
    fast = analyze_tap(record_sim_tap(SimTapSpec(speed_mm_s=10.0, pullback_distance_mm=0.1)))
    # 2 mm/s at 320 sps: 6.25 µm per sample, 4 samples pressed; 10 mm/s: 31 µm, one.
    assert slow.compression_samples == 4 and "stiffness" in slow.quality_components
    assert slow.stiffness_compression_g_um == pytest.approx(3.26, rel=0.1)
    assert fast.compression_samples == 1 and fast.stiffness_compression_g_um is None
    assert "stiffness" not in fast.quality_components


def test_default_pullback_breaks_contact_too_early_at_2mm_s_on_a_stiff_bed():
    # 31 µm up a 0.2 mm pullback: 15 %, inside the first sixth (the spec's middle two thirds).
    result = analyze_tap(record_sim_tap(SimTapSpec(speed_mm_s=2.0, pullback_distance_mm=0.2)))
    assert result.error == "TAP_BREAK_CONTACT_TOO_EARLY"
    assert analyze_tap(record_sim_tap(SimTapSpec(speed_mm_s=5.0, pullback_distance_mm=0.2))).valid


@pytest.mark.parametrize("film_um", [60.0, 20.0])
def test_fouled_virtual_taps_are_rejected(film_um):
    for speed_mm_s in (2.0, 5.0, 10.0):
        tap = record_sim_tap(SimTapSpec(scenario="oozy", speed_mm_s=speed_mm_s, pullback_distance_mm=0.1,
                                        overrides={"ooze_film_um": film_um}))
        assert tap.truth["label"] == "fouled"
        assert not analyze_tap(tap).valid
