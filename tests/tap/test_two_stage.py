"""The two-stage departure fit (tapcell.tap.stage.two_stage_fit) and its rejection in the analysis."""

import numpy as np
import pytest

from tapcell.tap import stage
from tapcell.tap.analysis import analyze_tap
from tapcell.tap.readers import read_tap_file
from tapcell.tap.toe import toe_shape
from tapcell.taplab.generate import generate_set

HEIGHTS_UM = np.arange(20.0, 120.0, 1.0)  # µm above the halt, one sample a µm
NOISE_G = 0.3


def departure(seed: int, soft_g_um: float, hinge_um: float = 52.0, top_um: float = 62.0,
              stiff_g_um: float = 4.0, drift_g_um: float = 0.0) -> np.ndarray:
    """A level, a stiff stage letting go at hinge_um, a soft one at top_um, white noise."""
    rng = np.random.default_rng(seed)
    return (0.5 + stiff_g_um * np.maximum(hinge_um - HEIGHTS_UM, 0.0) + soft_g_um * np.maximum(top_um - HEIGHTS_UM, 0.0)
            + drift_g_um * HEIGHTS_UM + rng.normal(0.0, NOISE_G, HEIGHTS_UM.size))


@pytest.mark.parametrize("seed", range(10))
def test_a_soft_stage_of_ten_percent_is_found_and_its_first_touch_read(seed):
    # 10 um of a stage 10 % of the contact's stiffness; the toe model's contact found near the hinge.
    fit = stage.two_stage_fit(HEIGHTS_UM, departure(seed, soft_g_um=0.4), 53.0, NOISE_G ** 2, 1.0)
    # Measured over 30 seeds: evidence 140-277 noise variances, top 62.05 +- 0.36 um (61.27-62.71).
    assert fit.evidence_chi2 > 5.0 * stage.TWO_STAGE_MIN_EVIDENCE
    assert abs(fit.top_um - 62.0) < 1.0
    assert 0.08 < fit.soft_share < 0.12 and 8.0 <= fit.span_um <= 12.0
    assert stage.shows_two_stage(fit, 53.0)


@pytest.mark.parametrize("width_um,power", [(8.0, 1.0), (12.0, 1.0), (16.0, 0.5)])
def test_a_wide_one_stage_toe_is_not_two_stages(width_um, power):
    # A soft sheet's toe: the one-stage toe explains it better (measured: evidence -16 or less, 30 seeds).
    for seed in range(5):
        rng = np.random.default_rng(seed)
        force_g = 0.5 + 4.0 * toe_shape(60.0 - HEIGHTS_UM, width_um, power) + rng.normal(0.0, NOISE_G, HEIGHTS_UM.size)
        fit = stage.two_stage_fit(HEIGHTS_UM, force_g, 55.0, NOISE_G ** 2, 1.0)
        assert fit is None or fit.evidence_chi2 < 0.0
        assert not stage.shows_two_stage(fit, 55.0)


def test_a_drift_is_no_stage():
    # A cable pulling 0.02 g/um over the whole departure: a line, fitted by both models alike.
    for seed in range(5):
        fit = stage.two_stage_fit(HEIGHTS_UM, departure(seed, soft_g_um=0.0, drift_g_um=0.02), 52.0, NOISE_G ** 2, 1.0)
        assert not stage.shows_two_stage(fit, 52.0)


def test_a_stage_shorter_than_two_samples_is_not_fitted():
    # 20 um a sample (10 sps at 0.2 mm/s): a 10 um stage is one sample's smear of the hinge.
    sparse = HEIGHTS_UM[::20]
    force_g = departure(0, soft_g_um=0.4)[::20]
    assert stage.two_stage_fit(sparse, force_g, 53.0, NOISE_G ** 2, 20.0) is None


def test_the_fit_runs_only_under_a_wide_toe():
    x_lo, x_hi = HEIGHTS_UM - 0.5, HEIGHTS_UM + 0.5
    force_g = departure(0, soft_g_um=0.4)
    wide = stage.two_stage_departure(x_lo, x_hi, force_g, 0.0, 53.0, 10.0, NOISE_G, 0.0)
    assert wide is not None and stage.shows_two_stage(wide, 53.0)
    assert stage.two_stage_departure(x_lo, x_hi, force_g, 0.0, 53.0, 6.0, NOISE_G, 0.0) is None


@pytest.fixture(scope="module")
def taplab_taps(tmp_path_factory):
    out = tmp_path_factory.mktemp("two-stage")
    labels = generate_set(out, seed=5, taps_per_scenario=10, scenarios=["two_stage", "clean_hx717", "soft_sheet"])
    return {label["file"]: (analyze_tap(read_tap_file(str(out / label["file"]))[0]), label) for label in labels}


def test_a_stage_the_wide_toe_absorbed_is_named(taplab_taps):
    # taplab seed 5: a 10.7 um stage (14 % of the contact); main read it valid 5.95 um low (sigma 2.4).
    rows = [(a, label) for a, label in taplab_taps.values() if label["scenario"] == "two_stage"]
    absorbed = [(a, label) for a, label in rows if 10.0 < label["spec"]["contact"]["stage_um"] < 11.0]
    assert len(absorbed) == 1
    analysis, _ = absorbed[0]
    assert analysis.error == "TAP_TWO_STAGE_CONTACT"
    assert "two stages" in analysis.message and "two-stage mount" in analysis.message
    # The rest: 9 of 10 named (main 8); the one left a 9.2 um stage read 2.9 um low.
    assert sum(a.error == "TAP_TWO_STAGE_CONTACT" for a, _ in rows) >= 9


def test_clean_and_soft_sheet_taps_are_not_two_stages(taplab_taps):
    rows = [a for a, label in taplab_taps.values() if label["scenario"] != "two_stage"]
    assert len(rows) == 20 and all(a.valid for a in rows), [a.error for a in rows]
