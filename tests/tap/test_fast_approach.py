"""An approach too fast for its sensor (issue 21, item 3: reject only for a cause the tap shows).

Reference HX711 taps (80 sps, probed at 1.1-2.0 mm/s) averaged to 10 sps (the sweep's `ref_slow10`):
106-199 µm of approach a sample, so the nozzle goes from contact to the halt in 0.2-0.5 of a sample
and no sample is read while it presses. Half of them were rejected as TAP_CONTACT_MISMATCH (the way
down's contact 231-512 µm above the halt), TAP_CHRONOLOGY or TAP_SHAPE_INVALID: "clean the nozzle"
for a probing speed 7-8 x the guide's (an 80 sps HX711 probes at 2 mm/s at most, 25 µm a sample).
Such a rejection is now TAP_DATA_INSUFFICIENT, "probe slower"; no tap changes validity, and a tap
within the guide's speed keeps the code of what it shows.
"""

from __future__ import annotations

import pytest

from bench.tap_sweep import CASES, analyse_in_process, case_taps, reference_taps
from tapcell.tap import validate
from tapcell.tap.model import TAP_DATA_INSUFFICIENT
from tapcell.tap.validate import TapInvalid

CASE = {case.name: case for case in CASES}


@pytest.fixture(scope="module")
def reference_dir(tmp_path_factory):
    return reference_taps(None, tmp_path_factory.mktemp("reference")) or pytest.skip("no reference taps here")


@pytest.fixture(scope="module")
def slow10(reference_dir):
    return [(analyse_in_process(tap), z_mm) for tap, z_mm in case_taps(CASE["ref_slow10"], 1, 20, reference_dir)]


def test_a_clean_tap_probed_too_fast_for_10_sps_is_rejected_for_its_speed(slow10):
    """Taps 1, 5 (were TAP_CONTACT_MISMATCH), 8 (TAP_CHRONOLOGY) and 17 (TAP_SHAPE_INVALID): 0.25,
    0.21, 0.49 and 0.48 samples from contact (37, 24, 83, 85 µm above the halt) at 145, 114, 170 and
    176 µm a sample."""
    for k, holds, contact_um, step_um in ((1, "0.25", 37, 145), (5, "0.21", 24, 114), (8, "0.49", 83, 170),
                                          (17, "0.48", 85, 176)):
        answer = slow10[k][0]
        assert answer["error"] == TAP_DATA_INSUFFICIENT, (k, answer["error"], answer["message"])
        assert answer["message"].startswith(f"the compression holds {holds} samples"), (k, answer["message"])
        assert f"({contact_um} µm above the halt" in answer["message"], k
        assert f"({step_um} µm a sample" in answer["message"], k
        assert "probe slower (PROBE_SPEED=" in answer["message"] and "faster sample_rate" in answer["message"]


def test_the_case_keeps_its_measured_taps_and_rejects_only_for_the_speed(slow10):
    """10 of 20 rejected, every one for the speed; the 10 measured taps as before the change (errors
    -0.42..+2.03 µm at z_sigma 2.38-2.57 µm: within 0.8 of their sigma)."""
    rejected = [answer["error"] for answer, _ in slow10 if not answer["valid"]]
    assert rejected == [TAP_DATA_INSUFFICIENT] * 10
    errors = [(answer["z"] - z_mm) * 1000.0 / answer["z_sigma_um"] for answer, z_mm in slow10 if answer["valid"]]
    assert len(errors) == 10
    assert max(abs(e) for e in errors) < 0.85


@pytest.mark.parametrize("contact_um, step_um, too_fast", [
    (37.0, 145.0, True),    # ref_slow10 tap 1: 0.25 of a sample
    (85.0, 84.0, False),    # a sample of compression
    (24.0, 51.0, True),     # just over twice the guide's 25 µm a sample
    (24.0, 50.0, False),    # twice the guide's step: the speed is not blamed
    (8.0, 31.25, False),    # a stiff bed at 10 mm/s and 320 sps (the reference set's fastest)
    (0.0, 341.0, False),    # a break line at the halt places no contact (ref_hx717x32 tap 2)
    (float("nan"), 341.0, False),
])
def test_the_rule_counts_the_compression_in_samples_against_the_guide(contact_um, step_um, too_fast):
    assert validate.compression_too_fast(contact_um, step_um) is too_fast
    if too_fast:
        with pytest.raises(TapInvalid) as raised:
            validate.check_compression_samples(contact_um, step_um, 1.45)
        assert raised.value.code == TAP_DATA_INSUFFICIENT
    else:
        validate.check_compression_samples(contact_um, step_um, 1.45)


def test_ooze_at_the_guide_speed_keeps_its_contact_mismatch():
    """taplab's heavy ooze (seed 1, 15.6 µm a sample; 0.5-3 samples of compression by the way up's
    contact): the film's contact mismatch is what the tap shows. 24 of 40 TAP_CONTACT_MISMATCH, as before."""
    from bench.tap_seeds import seed_tap

    codes = [analyse_in_process(seed_tap(1, "heavy_ooze", k)[0])["error"] for k in range(40)]
    assert codes.count("TAP_CONTACT_MISMATCH") == 24
    assert TAP_DATA_INSUFFICIENT not in codes and None not in codes
