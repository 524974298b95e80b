"""z_sigma_um holds what the model's assumptions move (issue 21), and the analysis takes no option
that changes nothing."""

import math
from pathlib import Path

import pytest

import tapcell.taplab
from tapcell.tap import AnalysisOptions, analyze_tap, read_tap_file
from tapcell.tap.cli import options_from_settings
from tapcell.tap.toe import TOE_WIDTHS_UM, WIDTH_PRIOR, _width_prior

REAL_TAP = Path(tapcell.taplab.__file__).with_name("real") / "voron24_workbench.json"


def test_the_real_capture_reports_what_the_toe_shape_moves():
    analysis = analyze_tap(read_tap_file(str(REAL_TAP))[0])
    assert analysis.valid
    # A Hertzian toe fits it best (0.11 um alone), a parabolic toe reads it 2.8 um higher: half that
    # range is in the sigma (1.42 um), and the capture's own analysis (0.041963 mm) lies 1.0 sigma off.
    assert 1.2 < analysis.z_sigma_um < 1.7
    recorded_mm = 0.04196257319307305
    assert abs(analysis.z_mm - recorded_mm) * 1000.0 < 1.5 * analysis.z_sigma_um
    # The sharp model, which assumes no toe at all, reads it 2.7 um below the capture.
    sharp = analyze_tap(read_tap_file(str(REAL_TAP))[0], AnalysisOptions(contact_model="sharp"))
    assert (sharp.z_mm - recorded_mm) * 1000.0 == pytest.approx(-2.66, abs=0.1)


def test_the_width_prior_falls_off_with_the_width():
    assert WIDTH_PRIOR.sum() == pytest.approx(1.0)
    uniform = _width_prior(TOE_WIDTHS_UM, None)
    # The widest toe keeps exp(-16/4) of its uniform share relative to the narrowest.
    ratio = (WIDTH_PRIOR[-1] / uniform[-1]) / (WIDTH_PRIOR[0] / uniform[0])
    assert ratio == pytest.approx(math.exp(-4.0), rel=1e-9)


@pytest.mark.parametrize("setting", ["pullback_distance_mm=5", "pullback_speed_mm_s=1"])
def test_options_that_changed_nothing_are_refused(setting):
    with pytest.raises(ValueError, match="unknown option"):
        options_from_settings([setting])
