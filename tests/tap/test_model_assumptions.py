"""z_sigma_um holds what the model's assumptions move (issue 21), and the analysis takes no option
that changes nothing."""

import math
from pathlib import Path

import pytest

import tapcell.taplab
from tapcell.tap import AnalysisOptions, analyze_tap, read_tap_file
from tapcell.tap.cli import options_from_settings
from tapcell.tap.toe import TOE_WIDTHS_UM, WIDTH_PRIOR, _width_prior
from tapcell.tap.uncertainty import FILM_WEIGHT, SHAPE_WEIGHT, SQUEEZE_WEIGHT, z_sigma_um

REAL_TAP = Path(tapcell.taplab.__file__).with_name("real") / "voron24_workbench.json"


def test_the_real_capture_reports_what_the_toe_shape_moves():
    analysis = analyze_tap(read_tap_file(str(REAL_TAP))[0])
    assert analysis.valid
    # A Hertzian toe fits it best (0.11 um alone), a parabolic toe reads it 2.8 um higher: half that
    # range (1.42 um) is the shape part; contact on the way down lies 1.9 um above break contact on
    # the way up beyond the fits' noise and the approach's sample grid (the squeeze part), and the
    # toe lifts Z by more than that (the film part, 1.9 um). Weighed, they are the sigma (5.93 um).
    parts = analysis.z_sigma_parts
    assert parts.noise_um < 0.2 and parts.shape_um == pytest.approx(1.42, abs=0.05)
    assert parts.squeeze_um == pytest.approx(1.9, abs=0.1) and parts.film_um == pytest.approx(1.9, abs=0.1)
    assert analysis.z_sigma_um == pytest.approx(z_sigma_um(parts), rel=1e-12)
    weighed_um = math.sqrt((SHAPE_WEIGHT * parts.shape_um) ** 2 + (SQUEEZE_WEIGHT * parts.squeeze_um) ** 2
                           + (FILM_WEIGHT * parts.film_um) ** 2)
    assert weighed_um < analysis.z_sigma_um < weighed_um + 0.3
    # The capture's own analysis (0.041963 mm) and the sharp model, which assumes no toe at all and
    # reads it 2.7 um below the capture, both lie within the sigma.
    recorded_mm = 0.04196257319307305
    assert abs(analysis.z_mm - recorded_mm) * 1000.0 < analysis.z_sigma_um
    sharp = analyze_tap(read_tap_file(str(REAL_TAP))[0], AnalysisOptions(contact_model="sharp"))
    assert (sharp.z_mm - recorded_mm) * 1000.0 == pytest.approx(-2.66, abs=0.1)
    assert abs(sharp.z_mm - recorded_mm) * 1000.0 < analysis.z_sigma_um


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
