"""A soft stage the toe took in at its widest (tapcell.tap.stage.shows_absorbed_stage): too faint to
reject, its first touch goes into z_sigma_um (the analysis's `unnamed_stage_um`)."""

from __future__ import annotations

import pytest

from bench.tap_sweep import Case, _sprung_stage, case_taps
from tapcell.tap import stage
from tapcell.tap.analysis import analyze_tap
from tapcell.tap.readers import read_tap_file, tap_from_object

CONTACT_UM = 40.0


def _fit(over_hinge_chi2: float, rise_um: float) -> stage.TwoStageFit:
    return stage.TwoStageFit(over_hinge_chi2, CONTACT_UM + rise_um, 3.0, 20.0, 0.1, False, over_hinge_chi2)


def test_the_rule_asks_for_the_widest_toe_the_evidence_and_the_rise():
    evidence, rise = stage.ABSORBED_STAGE_MIN_EVIDENCE, stage.ABSORBED_STAGE_MIN_RISE_UM
    assert stage.shows_absorbed_stage(_fit(evidence, rise), CONTACT_UM, True)
    assert not stage.shows_absorbed_stage(_fit(evidence, rise), CONTACT_UM, False)  # a narrower toe
    assert not stage.shows_absorbed_stage(_fit(evidence - 0.1, rise), CONTACT_UM, True)
    assert not stage.shows_absorbed_stage(_fit(evidence, rise - 0.1), CONTACT_UM, True)
    assert not stage.shows_absorbed_stage(_fit(evidence, -2.0 * rise), CONTACT_UM, True)  # below the contact
    assert not stage.shows_absorbed_stage(None, CONTACT_UM, True)


@pytest.fixture(scope="module")
def sprung_taps(reference_dir):
    """The reference clean HX717 taps with the sweep's approximate sprung stage of 25 um at a tenth
    of the bed's stiffness (the truth: the first touch, 25 um above the solid contact)."""
    case = Case("stage25", "sprung stage 25 um", "either", reference=("clean_hx717", 1),
                transform=_sprung_stage(25.0, 0.1), truth_up_um=25.0)
    plain = Case("plain", "the same taps", "accept", reference=("clean_hx717", 1))
    return case_taps(case, 1, 80, reference_dir), case_taps(plain, 1, 80, reference_dir)


@pytest.mark.parametrize("index", [24, 40, 46, 71, 76, 78])
def test_a_stage_the_toe_took_in_widens_sigma_to_cover_the_first_touch(sprung_taps, index):
    # Seed 1: 66 of 80 rejected as TAP_TWO_STAGE_CONTACT; of the 14 accepted these six read 18.8-20.9 um
    # low with z_sigma_um 1.7-3.5 before (e/sigma 5.3-12.5); now 12.6-21.4 (e/sigma 0.94-1.54).
    tap, truth_mm = sprung_taps[0][index]
    result = analyze_tap(tap_from_object(tap))
    assert result.valid and result.contact_onset_um == 16.0
    error_um = (result.z_mm - truth_mm) * 1000.0
    assert error_um < -15.0  # still the solid contact: the stage is measured in sigma, not in Z
    assert result.unnamed_stage_um >= stage.ABSORBED_STAGE_MIN_RISE_UM
    assert result.z_sigma_um >= result.unnamed_stage_um
    assert abs(error_um) / result.z_sigma_um < 1.6


def test_the_same_taps_without_the_stage_keep_their_sigma(sprung_taps):
    # No clean tap of either benchmark set (3,560 with the sessions) meets the rule; these 80 neither.
    results = [analyze_tap(tap_from_object(tap)) for tap, _ in sprung_taps[1]]
    assert all(r.valid for r in results)
    assert all(r.unnamed_stage_um < stage.ABSORBED_STAGE_MIN_RISE_UM for r in results)
    assert max(r.z_sigma_um for r in results) < 5.0


def test_a_toe_short_of_the_widest_keeps_its_sigma(reference_dir):
    # The reference clean ADS1220 2000 sps tap 16: a 10 um toe, and a two-stage fit that meets the
    # rule's evidence and rise. Under every toe the fit runs under (8 um and up) the rule would give
    # this clean tap a stage part, the one clean tap of 3,560 (and 3 more soft-sheet session taps),
    # for 1-4 fewer far-off taps in 5 of 16 sprung cases (clean HX717, 80 each): it keeps to the widest toe.
    result = analyze_tap(read_tap_file(reference_dir / "clean_ads1220_2000_0016.json")[0])
    assert result.valid and result.contact_onset_um < 16.0
    assert result.unnamed_stage_um == 0.0
    assert result.z_sigma_um < 2.0  # 1.24 um
