"""An approach too fast for its sensor (issue 21, item 3: reject only for a cause the tap shows).

Reference HX711 taps (80 sps, probed at 1.1-2.0 mm/s) averaged to 10 sps (the sweep's `ref_slow10`):
106-199 µm of approach a sample, so the nozzle goes from contact to the halt in 0.2-0.5 of a sample
and no sample is read while it presses. Half of them were rejected as TAP_CONTACT_MISMATCH (the way
down's contact 231-512 µm above the halt), TAP_CHRONOLOGY or TAP_SHAPE_INVALID: "clean the nozzle"
for a probing speed 7-8 x the guide's (an 80 sps HX711 probes at 2 mm/s at most, 25 µm a sample).
Lines out of order or misshapen there are now TAP_DATA_INSUFFICIENT, "probe slower"; a compression
the approach outran (less than a sample from break contact's height to the halt) places no contact
on the way down and no lag at the halt (`compression_places_the_halt`), so the contact mismatches
are measured. A tap within twice the guide's speed keeps the code of what it shows.
"""

from __future__ import annotations

import pytest

from bench.tap_sweep import CASES, analyse_in_process, case_taps
from tapcell.tap import validate
from tapcell.tap.analysis import compression_places_the_halt, split_tap
from tapcell.tap.model import TAP_DATA_INSUFFICIENT, AnalysisOptions
from tapcell.tap.readers import tap_from_object
from tapcell.tap.validate import TapInvalid

CASE = {case.name: case for case in CASES}


@pytest.fixture(scope="module")
def slow10(reference_dir):
    return [(analyse_in_process(tap), z_mm) for tap, z_mm in case_taps(CASE["ref_slow10"], 1, 20, reference_dir)]


def test_a_clean_tap_probed_too_fast_for_10_sps_is_rejected_for_its_speed(slow10):
    """Taps 8, 9, 16 (were TAP_CHRONOLOGY), 17 and 18 (TAP_SHAPE_INVALID): 0.49, 0.45, 0.50, 0.48
    and 0.46 samples from contact (83, 55, 85, 85, 62 µm above the halt) at 170, 122, 171, 176 and
    133 µm a sample."""
    for k, holds, contact_um, step_um in ((8, "0.49", 83, 170), (9, "0.45", 55, 122), (16, "0.50", 85, 171),
                                          (17, "0.48", 85, 176), (18, "0.46", 62, 133)):
        answer = slow10[k][0]
        assert answer["error"] == TAP_DATA_INSUFFICIENT, (k, answer["error"], answer["message"])
        assert answer["message"].startswith(f"the compression holds {holds} samples"), (k, answer["message"])
        assert f"({contact_um} µm above the halt" in answer["message"], k
        assert f"({step_um} µm a sample" in answer["message"], k
        assert "probe slower (PROBE_SPEED=" in answer["message"] and "faster sample_rate" in answer["message"]


def test_a_contact_no_sample_placed_is_not_a_contact_mismatch(slow10):
    """Taps 1, 2, 4, 5 and 10 were TAP_CONTACT_MISMATCH: a down contact 231-512 µm above the halt
    placed by no sample (0.21-0.47 samples from contact to the halt), not a film. Now measured:
    +0.67, +1.52, -0.02, +0.50, +0.67 µm at z_sigma 2.40-2.44 µm."""
    for k, error_um in ((1, 0.67), (2, 1.52), (4, -0.02), (5, 0.50), (10, 0.67)):
        answer, z_mm = slow10[k]
        assert answer["valid"], (k, answer["message"])
        assert (answer["z"] - z_mm) * 1000.0 == pytest.approx(error_um, abs=0.05), k
        assert answer["z_sigma_um"] == pytest.approx(2.42, abs=0.05), k


def test_the_case_keeps_its_measured_taps_and_rejects_only_for_the_speed(slow10):
    """5 of 20 rejected (10 before), every one for the speed; the 15 measured taps' errors
    -0.42..+2.03 µm at z_sigma 2.39-2.57 µm: within 0.83 of their sigma."""
    rejected = [answer["error"] for answer, _ in slow10 if not answer["valid"]]
    assert rejected == [TAP_DATA_INSUFFICIENT] * 5
    errors = [(answer["z"] - z_mm) * 1000.0 / answer["z_sigma_um"] for answer, z_mm in slow10 if answer["valid"]]
    assert len(errors) == 15
    assert max(abs(e) for e in errors) < 0.85


def test_no_lag_is_read_off_a_halt_the_approach_outran(reference_dir):
    """Reference clean_hx717 averaged to 80 sps (`ref_hx717x4`). Tap 5: 66 µm a sample, break
    contact 60 µm above the halt (0.91 samples), yet P1 to P2 spans 2.9 periods. Before: a lag of
    9.0 ms read off the halt, Z 3.14 µm low, z_sigma_um 53.3 (a squeeze of 36 µm from a down contact
    no sample placed). Now no lag, -0.28 µm at 1.29. Tap 8 (23 µm a sample, 2.2 samples) keeps its lag."""
    taps = case_taps(CASE["ref_hx717x4"], 1, 9, reference_dir)
    splits = [split_tap(tap_from_object(tap), AnalysisOptions())[0] for tap, _ in taps]
    assert [compression_places_the_halt(s.dec, s.motion, s.timing) for s in (splits[5], splits[8])] == [False, True]
    answer = analyse_in_process(taps[5][0])
    assert answer["valid"] and answer["sensor_delay_s"] == 0.0
    assert (answer["z"] - taps[5][1]) * 1000.0 == pytest.approx(-0.28, abs=0.05)
    assert answer["z_sigma_um"] == pytest.approx(1.29, abs=0.05)
    answer = analyse_in_process(taps[8][0])
    assert answer["sensor_delay_s"] > 0.0 and answer["z_sigma_um"] < 1.0


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
