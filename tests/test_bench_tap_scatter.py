"""bench tap_scatter re-draws a taplab scenario's taps with one thing changed (issue 21, i21-sigma5)."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the bench package beside tests/

from bench.tap_scatter import VARIANTS, options_for, score_variant, truth_chi2  # noqa: E402
from tapcell.tap.model import TapAnalysis  # noqa: E402
from tapcell.tap.toe import ToeGridResult  # noqa: E402
from tapcell.taplab.generate import SCENARIOS  # noqa: E402


def _spec():
    return SCENARIOS["mains_hum"].draw(np.random.default_rng([7, 7, 0]))


def test_each_variant_changes_only_what_it_names():
    drawn = _spec()
    white = VARIANTS["white noise"](drawn)
    assert white.adc.pink_g == 0.0 and white.walk_g_per_sqrt_s == 0.0 and white.hum_g == (0.0, 0.0, 0.0)
    assert white.drift_g_per_mm == 0.0 and white.adc.white_g == drawn.adc.white_g and white.contact == drawn.contact
    hertz, parabolic = VARIANTS["Hertzian toes"](drawn), VARIANTS["parabolic toes"](drawn)
    assert (hertz.contact.onset_power, hertz.contact.onset_blend) == (0.5, 0.0)
    assert (parabolic.contact.onset_power, parabolic.contact.onset_blend) == (1.0, 0.0)
    assert hertz.contact.onset_um == drawn.contact.onset_um and hertz.adc == drawn.adc
    assert VARIANTS["narrow toes"](drawn).contact.onset_um == 2.0
    assert VARIANTS["wide toes"](drawn).contact.onset_um == 6.0
    assert VARIANTS["delay given"](drawn) == drawn
    assert options_for("delay given", drawn).sensor_delay_s == pytest.approx(
        drawn.adc.latency_periods * drawn.adc.period_s)
    assert options_for("as drawn", drawn).sensor_delay_s is None


def test_the_truth_is_scored_against_the_toe_fits_best_toe():
    """Two toes over contacts 0..4 µm: the best (residual 10 at 2 µm) and one 3 variances worse at
    the truth's 3 µm, variance 2: Δχ² at truth is (16 - 10) / 2 = 3; a truth off the grid has none."""
    contacts = np.arange(0.0, 4.01, 1.0)
    rss = np.array([[30.0, 20.0, 10.0, 20.0, 30.0], [40.0, 30.0, 20.0, 16.0, 30.0]])
    analysis = TapAnalysis(valid=True, z_method="toe", toe_grid=ToeGridResult(contacts, rss, 2.0, np.ones(2)),
                           toe_z_origin_mm=0.1)
    assert truth_chi2(analysis, 0.103) == pytest.approx(3.0)
    assert truth_chi2(analysis, 0.1025) == pytest.approx((15.0 - 10.0) / 2.0)  # halfway: the first toe, interpolated
    assert truth_chi2(analysis, 0.2) is None
    assert truth_chi2(TapAnalysis(valid=True, z_method="contact_model"), 0.103) is None


def test_a_few_taps_are_scored(tmp_path):
    row = score_variant("Hertzian toes", "clean_hx717", 3, 7, tmp_path)
    assert row["taps"] == 3 and abs(row["bias"]) < 2.0 and 0.0 < row["sigma"] < 3.0 and row["chi2"] >= 0.0
