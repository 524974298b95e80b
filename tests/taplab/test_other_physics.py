"""Physics neither generator had modelled before issue 21, now in taplab: a two-stage mount, a
10 sps HX711, gantry ringing. The analysis measures them, or rejects with the cause's code; it
never accepts a tap 20 um off."""

import json

import numpy as np
import pytest

from tapcell.tap import analyze_tap, read_tap_file
from tapcell.taplab.generate import generate_set


@pytest.fixture(scope="module")
def taps(tmp_path_factory):
    out = tmp_path_factory.mktemp("other-physics")
    labels = generate_set(out, seed=5, taps_per_scenario=10, scenarios=["two_stage", "hx711_10", "ringing"])
    by_scenario = {}
    for label in labels:
        analysis = analyze_tap(read_tap_file(str(out / label["file"]))[0])
        by_scenario.setdefault(label["scenario"], []).append((analysis, label["z_contact"]))
    return by_scenario


def test_a_two_stage_mount_is_rejected_as_such_or_measured(taps):
    rows = taps["two_stage"]
    # Measured on 40 taps (seed 1): 32 rejected as TAP_TWO_STAGE_CONTACT, the rest valid -5.0 +- 2.3 um;
    # before, 4 of 40 were accepted 20-28 um low.
    named = [a for a, _ in rows if a.error == "TAP_TWO_STAGE_CONTACT"]
    assert len(named) >= 6
    assert all("two-stage mount" in a.message for a in named)
    valid_errors = [(a.z_mm - truth) * 1000.0 for a, truth in rows if a.valid]
    assert all(abs(e) < 12.0 for e in valid_errors), valid_errors


@pytest.mark.parametrize("scenario", ["hx711_10", "ringing"])
def test_slow_sensors_and_ringing_are_analysed(taps, scenario):
    rows = taps[scenario]
    errors = np.array([(a.z_mm - truth) * 1000.0 for a, truth in rows if a.valid])
    # Measured on 40 taps each (seed 1): 98 % / 100 % valid, -0.05 +- 0.50 / -0.37 +- 0.72 um.
    assert len(errors) >= 9, [a.error for a, _ in rows]
    assert abs(errors.mean()) < 1.0 and errors.std() < 1.5


def test_the_two_stage_tap_records_its_stage_in_the_labels(tmp_path):
    labels = generate_set(tmp_path, seed=1, taps_per_scenario=1, scenarios=["two_stage"])
    contact = labels[0]["spec"]["contact"]
    assert 8.0 <= contact["stage_um"] <= 30.0
    assert 0.1 * contact["stiffness_g_um"] <= contact["stage_stiffness_g_um"] <= 0.3 * contact["stiffness_g_um"]
    tap = json.loads((tmp_path / labels[0]["file"]).read_text())
    assert "stage_um" not in json.dumps(tap)  # the files stay blinded
