"""The independent generator's physics (tapcell.taplab): properties the issue asks of it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tapcell.taplab.generate import LABELS_FILE, SCENARIOS, draw_tap, generate_set, make_tap
from tapcell.taplab.physics import Contact, elastic_force_g, loading_force_g, relaxed_share
from tapcell.taplab.sensor import Adc, convert, conversion_kernel

CONTACT = Contact(stiffness_g_um=4.0, onset_um=6.0, onset_power=0.5, onset_blend=0.3, unload_ratio=0.92,
                  relax_fraction=(0.03,), relax_tau_s=(0.1,))


def test_onset_is_c1_into_the_linear_region():
    w = CONTACT.onset_um
    x = np.array([w - 1e-6, w, w + 1e-6])
    f = loading_force_g(x, CONTACT)
    slopes = np.diff(f) / 1e-6
    assert slopes == pytest.approx([4.0, 4.0], rel=1e-4)  # stiffness continuous at the onset's end
    assert loading_force_g(np.array([0.0, -3.0]), CONTACT).tolist() == [0.0, 0.0]
    small = loading_force_g(np.array([1e-4, 2e-4]), CONTACT)
    assert small[1] / small[0] == pytest.approx(2 ** 1.5, rel=0.05)  # Hertz-like near the touch (power 0.5)


@pytest.mark.parametrize("ratio", [0.9, 1.05])
def test_hysteresis_reaches_zero_exactly_at_the_surface(ratio):
    contact = Contact(**{**CONTACT.__dict__, "unload_ratio": ratio})
    down = np.linspace(-5, 40, 451)
    path = np.concatenate((down, down[::-1]))
    force = elastic_force_g(path, contact)
    unloading = force[len(down):]
    assert force[len(down) - 1] == unloading[0]  # continuous at the turn
    assert unloading[down[::-1] <= 0.0].max() == 0.0  # zero at and above the surface
    assert unloading[np.isclose(down[::-1], 0.1)][0] > 0.0
    slope_top = (unloading[0] - unloading[1]) / 0.1
    assert slope_top == pytest.approx(ratio * contact.stiffness_g_um, rel=0.01)


def test_relaxation_continues_from_the_touch_with_its_time_constant():
    t = np.array([0.0, 0.1, 1.0])
    share = relaxed_share(t + 1.0, 1.0, CONTACT)
    assert share[0] == 0.0
    assert share[1] == pytest.approx(0.03 * (1 - np.exp(-1.0)))
    assert share[2] == pytest.approx(0.03, rel=1e-4)


def test_sinc3_window_spans_three_periods_and_a_boxcar_one():
    hx = Adc("hx717", 320.0, 0.0, 0.0, 0.0, 0.0, 0.0, 400.0)
    ads = Adc("ads1220", 660.0, 0.0, 0.0, 0.0, 0.0, 0.0, 400.0)
    for adc, centroid in ((hx, 0.5), (ads, 1.5)):
        kernel = conversion_kernel(adc)
        fine = np.arange(len(kernel)) + 0.5
        assert kernel.sum() == pytest.approx(1.0)
        # group delay (periods) counted back from the window's newest end
        assert (len(kernel) - kernel @ fine) / 16 == pytest.approx(centroid, abs=1 / 16)
    ramp = np.arange(16 * 40, dtype=float)  # a ramp of 1 per fine step: output = window centroid
    samples = convert(ramp, hx)
    assert np.diff(samples) == pytest.approx(16.0)


def test_a_tap_is_deterministic_and_truth_is_kept_apart(tmp_path):
    first = generate_set(tmp_path / "a", seed=5, taps_per_scenario=1, scenarios=["clean_hx717", "mild_ooze"])
    again = generate_set(tmp_path / "b", seed=5, taps_per_scenario=1, scenarios=["mild_ooze", "clean_hx717"])
    by_scenario = {label["scenario"]: label for label in again}
    for label in first:
        twin = by_scenario[label["scenario"]]
        assert (tmp_path / "a" / label["file"]).read_text() == (tmp_path / "b" / twin["file"]).read_text()
        tap = json.loads((tmp_path / "a" / label["file"]).read_text())
        assert "truth" not in tap and set(tap["meta"]) == {"source"}  # blinded
        assert len(tap["moves"]) == 5
    labels = [json.loads(line) for line in (tmp_path / "a" / LABELS_FILE).read_text().splitlines()]
    assert {label["scenario"] for label in labels} == {"clean_hx717", "mild_ooze"}


def test_film_ooze_leaves_contact_high_and_a_short_pullback_never_leaves():
    rng = np.random.default_rng(3)
    spec = SCENARIOS["mild_ooze"].draw(rng)
    _, truth = make_tap(spec, rng)
    assert 0.0 < truth["film_left_um"] <= spec.ooze.film_um
    rng = np.random.default_rng(4)
    spec = draw_tap(rng, pullback_over_travel=0.8)
    _, truth = make_tap(spec, rng)
    assert not truth["broke_contact"]
