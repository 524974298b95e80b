"""bench toe_shape: what one tap can tell about its contact's toe, and taplab's truth (issue 21)."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the bench package beside tests/

from bench.toe_shape import (HERTZ, PARABOLA, TOE_VARIANTS, identifiability, onset_of,  # noqa: E402  (after the path)
                             taplab_taps, toe_force_over_k)
from tapcell.tap import analyze_tap  # noqa: E402


def test_a_reference_like_toe_shows_neither_its_shape_nor_itself_to_one_tap():
    # A Hertzian toe lifting the linear region 0.95 um (the reference taps' clean median) at 0.51 um
    # of noise per sample: a parabolic toe fits it as well to 0.007 noise variances and reads
    # contact 0.50 um higher; even a hinge fits it to 0.22 variances (0.92 um low).
    shape_chi2, shape_contact = identifiability(0.95, HERTZ, PARABOLA, 1.0, 1.0, 0.51, phases=2)
    assert shape_chi2 < 0.015 and shape_contact == pytest.approx(0.50, abs=0.05)
    hinge_chi2, hinge_contact = identifiability(0.95, HERTZ, None, 1.0, 1.0, 0.51, phases=2)
    assert hinge_chi2 == pytest.approx(0.22, abs=0.03) and hinge_contact == pytest.approx(-0.92, abs=0.03)


def test_the_approach_tells_nothing_the_pullback_does_not():
    # taplab's toe (parabolic, lift 1.7 um, 0.21 um noise): the pullback tells it from a hinge by
    # 2.2 noise variances, 15 um samples of the approach by none, whatever the shape reads.
    pullback = identifiability(1.7, PARABOLA, None, 1.0, 1.0, 0.21, phases=2)[0]
    approach = identifiability(1.7, PARABOLA, None, 15.0, 15.0, 0.21, phases=2)[0]
    assert pullback == pytest.approx(2.24, abs=0.15)
    assert approach < 0.01


def test_the_onset_is_read_against_the_truth():
    # A parabolic toe lifting 1.5 um, stiffness 4 g/um, on a baseline with drift, 0.1 g of noise.
    depth = np.arange(-60.0, 30.0, 1.0)
    rng = np.random.default_rng(3)
    force = 12.0 + 0.05 * depth + 4.0 * toe_force_over_k(depth, 1.5, PARABOLA) + rng.normal(0.0, 0.1, depth.size)
    onset = onset_of(depth, force)
    assert onset.lift_um == pytest.approx(1.5, abs=0.05)
    assert onset.noise_um == pytest.approx(0.1 / 4.0, rel=0.3)
    assert onset.force_over_k_um[depth == 2.0][0] == pytest.approx(toe_force_over_k(2.0, 1.5, PARABOLA)[0], abs=0.1)


def test_taplab_reads_its_truth_where_the_analysis_reads_contact():
    # Noise-free, no toe, no unloading loop or relaxation: the force returns to zero at taplab's
    # truth, and the analysis reads it there (the 40 taps of the set: -0.03 +- 0.05 um, 0.18 at most).
    edit = TOE_VARIANTS["none, no loop or relaxation, noise-free"]
    errors_um = []
    for tap, truth_mm in taplab_taps("clean_hx717", 8, edit=edit):
        analysis = analyze_tap(tap)
        assert analysis.valid
        errors_um.append((analysis.z_mm - truth_mm) * 1000.0)
    assert max(map(abs, errors_um)) < 0.2
    assert abs(np.mean(errors_um)) < 0.1
