"""bench/tap_sweep.py: taplab's physics swept far outside its scenarios (issue 21), and what it found."""

from __future__ import annotations

import numpy as np
import pytest

from bench import tap_sweep
from bench.tap_sweep import CASES, analyse_in_process, case_taps, findings, reference_taps, sweep

CASE = {case.name: case for case in CASES}


def _errors_um(name: str, count: int) -> list[float | None]:
    out = []
    for tap, z_mm in case_taps(CASE[name], seed=1, count=count, reference_dir=None):
        answer = analyse_in_process(tap)
        out.append((answer["z"] - z_mm) * 1000.0 if answer["valid"] else None)
    return out


def test_one_parameter_differs_between_cases():
    """Every case draws the same base tap: the one parameter swept is all that changes."""
    (base, _), = case_taps(CASE["base"], 1, 1, None)
    (slow, _), = case_taps(CASE["pull0.5"], 1, 1, None)
    assert base["probe"]["speed"] == slow["probe"]["speed"] == 5.0
    assert base["probe"]["trigger_force"] == slow["probe"]["trigger_force"]
    assert base["probe"]["pullback_speed"] == pytest.approx(0.32)
    assert slow["probe"]["pullback_speed"] == 0.5
    (fast, _), = case_taps(CASE["sps4000"], 1, 1, None)
    assert fast["sample_rate"] == 4000.0 and fast["probe"]["pullback_speed"] == pytest.approx(4.0)


def test_four_samples_of_adc_latency_are_measured_not_dropped():
    """The lag read off the halt was capped at 4 sample periods and fell back to 0 beyond: a
    4-sample pipeline (4.5 periods with the window) read +2.5..+4.3 µm with z_sigma 0.5-0.9
    (rms e/σ 8.8). The cap now adds the split's allowance for an unknown delay (20 ms)."""
    errors = _errors_um("lat4", 6)
    assert all(e is not None for e in errors)
    assert abs(float(np.mean(errors))) < 1.0, errors  # measured -0.28 ± 0.59 over 20; +3.71 before
    assert max(abs(e) for e in errors) < 2.0, errors


def test_a_crash_is_counted_and_found_first(monkeypatch):
    def broken(_tap):
        raise ZeroDivisionError("boom")

    monkeypatch.setattr(tap_sweep, "analyze_tap", broken)
    results = sweep([CASE["base"]], seed=1, count=2, reference_dir=None, kalico=None, scratch=None)
    assert results[0].ours.codes["TRACEBACK"] == 2
    found = findings(results)
    assert found[0].startswith("(1) base: base-000.json: ZeroDivisionError: boom")
    assert any(line.startswith("(3) base: 100 %") for line in found)


def test_the_sweep_scores_like_the_benchmark():
    """bias, silent failures and rms(e/σ) come from taplab.benchmark.score on the case's truth."""
    results = sweep([CASE["base"], CASE["endbreak1.1"]], seed=1, count=4, reference_dir=None, kalico=None,
                    scratch=None)
    base, late = results
    errors = _errors_um("base", 4)
    assert base.ours.taps == 4 and base.ours.valid == 4
    assert base.ours.bias_um == pytest.approx(float(np.mean(errors)), abs=1e-6)
    assert base.worst_um == pytest.approx(max(abs(e) for e in errors), abs=1e-6)
    assert base.ours.silent == 0 and base.kalico is None
    # a pullback ending at 1.08-1.18x the overtravel: the spec's last sixth, rejected as such
    assert late.ours.codes["TAP_BREAK_CONTACT_TOO_LATE"] >= 2
    assert not any("endbreak1.1" in line for line in findings(results))  # rejecting it is honest ("either")


def test_reference_taps_averaged_into_a_slower_sensor(reference_dir):
    (tap, z_mm), = case_taps(CASE["ref_hx717x4"], 1, 1, reference_dir)
    assert tap["sample_rate"] == 80.0 and len(tap["z"]) == len(tap["time"])
    assert "truth" not in tap and "meta" not in tap
    answer = analyse_in_process(tap)
    assert answer["valid"] and abs(answer["z"] - z_mm) * 1000.0 < 3.0


def test_a_pullback_of_a_few_samples_is_not_called_too_short():
    """10 mm/s at 320 sps: 31 µm a sample, 7 samples over a pullback 2.2-3.5x the overtravel. The
    nozzle left the bed, but the rules counting samples from the pullback's end said it never did,
    "increase pullback_distance" (5 of 20). Now: too few samples, slow pullback_speed; and where
    the pullback holds them but the decompression holds one sample wholly pressed, the same fix
    (14 of the other 15, tests/tap/test_fast_pullback.py)."""
    codes, messages = [], []
    for tap, _ in case_taps(CASE["pull10"], seed=1, count=12, reference_dir=None):
        answer = analyse_in_process(tap)
        if not answer["valid"]:
            codes.append(answer["error"])
            messages.append(answer["message"])
    assert codes and set(codes) == {"TAP_DATA_INSUFFICIENT"}, codes
    assert all("slow pullback_speed" in m and "31.2 µm a sample" in m for m in messages), messages


def test_a_pullback_starting_at_the_halt_says_there_is_no_dwell():
    """A dwell of 0 was "phase times out of order: halt X, pullback X..": the times are equal, not
    out of order. Still TAP_MOTION_INVALID (the five lines need a dwell), now naming it."""
    (tap, _), = case_taps(CASE["dwell0"], seed=1, count=1, reference_dir=None)
    answer = analyse_in_process(tap)
    assert answer["error"] == "TAP_MOTION_INVALID"
    assert answer["message"].startswith("the pullback starts at the halt (")
    assert "no dwell" in answer["message"]


# --- the reference taps transformed (another generator's taps: its toes, noise and timing kept) ---

@pytest.fixture(scope="module")
def reference_dir(tmp_path_factory):
    return reference_taps(None, tmp_path_factory.mktemp("reference")) or pytest.skip("no reference taps here")


def _original(reference_dir, scenario: str = "clean_hx717") -> dict:
    """The first reference tap of a scenario as the sweep reads it (truth and meta dropped)."""
    (tap, _), = case_taps(tap_sweep.Case("plain", "", "accept", reference=(scenario, 1)), 1, 1, reference_dir)
    return tap


def test_lost_frames_keep_every_other_sample_as_it_was(reference_dir):
    original = _original(reference_dir)
    rows = set(zip(original["time"], original["force"], original["z"]))
    (one_in_20, _), = case_taps(CASE["ref_drop20"], 1, 1, reference_dir)
    n = len(original["time"])
    assert len(one_in_20["time"]) == n - n // 20 == len(one_in_20["force"]) == len(one_in_20["z"])
    assert set(zip(one_in_20["time"], one_in_20["force"], one_in_20["z"])) <= rows
    (burst, _), = case_taps(CASE["ref_burst5"], 1, 1, reference_dir)
    t = np.asarray(original["time"])
    gone = np.flatnonzero(~np.isin(t, burst["time"]))
    assert len(gone) == 5 and np.all(np.diff(gone) == 1)
    events = original["events"]
    assert events["pullback_start_time"] <= t[gone[0]] and t[gone[-1]] <= events["pullback_end_time"]


def test_gain_polarity_offset_and_latency_are_exact(reference_dir):
    original = _original(reference_dir)
    force = np.asarray(original["force"])
    (flipped, _), = case_taps(CASE["ref_flip"], 1, 1, reference_dir)
    (gain5, _), = case_taps(CASE["ref_gain5"], 1, 1, reference_dir)
    (offset, _), = case_taps(CASE["ref_off-5k"], 1, 1, reference_dir)
    (later, _), = case_taps(CASE["ref_lat+1"], 1, 1, reference_dir)
    assert np.allclose(flipped["force"], -force, atol=1e-5)
    assert flipped["probe"]["trigger_force"] == original["probe"]["trigger_force"] > 0
    assert np.allclose(gain5["force"], 5.0 * force, atol=1e-5)
    assert gain5["probe"]["trigger_force"] == pytest.approx(5.0 * original["probe"]["trigger_force"])
    assert np.allclose(offset["force"], force - 5000.0, atol=1e-5)
    latency = _original(reference_dir, "latency")
    assert later["force"][1:] == latency["force"][:-1] and later["time"] == latency["time"]


def test_a_saturated_sensor_clips_the_force_flat_at_its_limit(reference_dir):
    """`_force_clipped(0.8)`: every force beyond 80 % of the peak held at that limit, the rest kept;
    the analysis refuses the tap for what it shows (TAP_SENSOR_SATURATED), not for its shape."""
    original = _original(reference_dir)
    force = np.asarray(original["force"])
    limit_g = 0.8 * np.max(np.abs(force))
    (clipped, _), = case_taps(CASE["ref_clip80"], 1, 1, reference_dir)
    out = np.asarray(clipped["force"])
    inside = np.abs(force) <= limit_g
    assert np.allclose(out[inside], force[inside], atol=1e-5)
    assert np.all(np.abs(out[~inside]) == round(limit_g, 5)) and np.count_nonzero(~inside) >= 8
    answer = analyse_in_process(clipped)
    assert not answer["valid"] and answer["error"] == "TAP_SENSOR_SATURATED"


def test_a_slower_tap_keeps_its_samples_per_micron(reference_dir):
    """`_slower(8)` on the 80 sps HX711: 10 sps, 8x slower moves, every sample's force and Z kept."""
    original = _original(reference_dir, "hx711_slow")
    (slow, _), = case_taps(CASE["ref_slow10t"], 1, 1, reference_dir)
    assert slow["sample_rate"] == 10.0 and slow["force"] == original["force"] and slow["z"] == original["z"]
    t0, t, ts = original["time"][0], np.asarray(original["time"]), np.asarray(slow["time"])
    assert np.allclose(ts - t0, 8.0 * (t - t0))
    assert slow["probe"]["pullback_speed"] == pytest.approx(original["probe"]["pullback_speed"] / 8.0)
    for before, after in zip(original["moves"], slow["moves"]):
        # the same distance: v t and a t² unchanged
        assert after["start_v"] * after["move_t"] == pytest.approx(before["start_v"] * before["move_t"])
        assert after["accel"] * after["move_t"] ** 2 == pytest.approx(before["accel"] * before["move_t"] ** 2)
    answer = analyse_in_process(slow)
    assert answer["valid"], answer["message"]


def test_jitter_hum_and_ringing_add_what_they_say(reference_dir):
    original = _original(reference_dir)
    force, t = np.asarray(original["force"]), np.asarray(original["time"])
    (jittered, _), = case_taps(CASE["ref_jitter5"], 1, 1, reference_dir)
    moved = np.asarray(jittered["time"]) - t
    own_s = float(np.std(np.diff(t) - np.median(np.diff(t)))) / np.sqrt(2.0)
    assert np.all(np.diff(jittered["time"]) > 0) and jittered["force"] == original["force"]
    assert np.std(moved) == pytest.approx(own_s * np.sqrt(24.0), rel=0.25)
    (hummed, _), = case_taps(CASE["ref_hum"], 1, 1, reference_dir)
    hum = np.asarray(hummed["force"]) - force
    assert 5.0 < np.max(np.abs(hum)) <= 9.0 + 1e-4
    (rung, z_mm), = case_taps(CASE["ref_ring"], 1, 1, reference_dir)
    ring = np.asarray(rung["force"]) - force
    in_contact = np.asarray(original["z"]) < z_mm
    assert np.all(ring[~in_contact] == 0.0) and np.max(np.abs(ring[in_contact])) > 1.0


# Reference cases with a clean tap the analysis still rejects on seed 1 (docs/tap-analysis.md,
# "Load-cell creep"): the reference's clean HX717 tap 7 scores 23.9 of the soft-stage check's 36 noise
# variances unperturbed, and a creep of 0.5-2 % of the load tips it over.
KNOWN_GAPS = {"ref_creep"}


def test_the_reference_transforms_find_nothing(reference_dir):
    """Every reference-tap case the sweep expects accepted, 15 taps each: no crash, no silent
    failure, no clean tap rejected, no accepted tap 5 µm and 4 σ off (20 taps each:
    docs/tap-analysis.md's table).
    Before: ref_hx717x4 tap 14 rejected as TAP_CONTACT_MISMATCH. Left out: the gaps the docs name
    (KNOWN_GAPS), which the sweep itself reports."""
    cases = [case for case in CASES if case.reference and case.expect == "accept" and case.name not in KNOWN_GAPS]
    assert len(cases) >= 17
    results = sweep(cases, seed=1, count=15, reference_dir=reference_dir, kalico=None, scratch=None)
    assert findings(results) == []


def test_a_sprung_stage_adds_its_force_above_the_contact_and_moves_the_truth_up(reference_dir):
    """`_sprung_stage(20, 0.1)`: a tenth of the bed's stiffness over the 20 µm above the solid
    contact, bottomed out below it; the first touch (the truth scored) 20 µm higher."""
    original = _original(reference_dir)
    force, z = np.asarray(original["force"]), np.asarray(original["z"])
    (staged, top_mm), = case_taps(CASE["ref_stage20"], 1, 1, reference_dir)
    (_, solid_mm), = case_taps(CASE["ref_clip80"], 1, 1, reference_dir)  # the same tap, its truth kept
    assert (top_mm - solid_mm) * 1000.0 == pytest.approx(20.0)
    added = np.asarray(staged["force"]) - force
    g_per_um = force[np.argmax(np.abs(force))] / ((solid_mm - z.min()) * 1000.0)
    above = z >= top_mm
    assert np.all(np.abs(added[above]) <= 1e-5)  # nothing before the first touch
    bottomed = z <= solid_mm
    assert np.allclose(added[bottomed], 0.1 * g_per_um * 20.0, atol=1e-5)  # the springs' whole travel
    between = ~above & ~bottomed
    assert np.count_nonzero(between) > 10
    assert np.allclose(added[between], 0.1 * g_per_um * (top_mm - z[between]) * 1000.0, atol=1e-5)


def test_an_accepted_tap_far_off_at_many_sigma_is_found(reference_dir):
    """The far-off finding reports what it measures: on the approximate 20 µm sprung stage (seed 1,
    20 taps) the three accepted taps read 19.7, 16.6 and 12.8 µm below the first touch at 16.7, 14.6
    and 3.5 σ; the first two pass both of `far_off`'s bars (5 µm, 4 σ), the third not the σ's."""
    results = sweep([CASE["ref_stage20"]], seed=1, count=20, reference_dir=reference_dir, kalico=None, scratch=None)
    assert findings(results) == ["(4) ref_stage20: 2 accepted tap(s) over 5 µm and 4 σ off, worst -19.7 µm at 16.7 σ"]


def test_a_curved_reading_a_step_and_crosstalk_add_what_they_say(reference_dir):
    """`_curved_reading(0.15)`: the load's square, at most 15 % of the peak load, nothing where no
    load; `_offset_step`: one step of 3-10 g at one instant; `_motion_crosstalk`: 1-3 g exactly
    while Z moves (the moves' speed), nothing in the dwell."""
    original = _original(reference_dir)
    force, t = np.asarray(original["force"]), np.asarray(original["time"])
    load = force - np.median(force[:20])
    peak_g = np.max(np.abs(load))
    (curved, _), = case_taps(CASE["ref_curved"], 1, 1, reference_dir)
    added = np.asarray(curved["force"]) - force
    share = added / (load * np.abs(load) / peak_g)
    heavy = np.abs(load) > 0.3 * peak_g
    assert np.count_nonzero(heavy) > 20 and 0.0 < np.max(np.abs(added)) <= 0.15 * peak_g + 1e-4
    assert np.allclose(share[heavy], share[heavy][0], atol=1e-4)  # one curvature, the load's square
    (stepped, _), = case_taps(CASE["ref_step"], 1, 1, reference_dir)
    step = np.asarray(stepped["force"]) - force
    changes = np.flatnonzero(np.abs(np.diff(step)) > 1e-3)
    assert len(changes) == 1 and 3.0 - 1e-4 <= abs(step[-1]) <= 10.0 + 1e-4 and np.all(step[:changes[0] + 1] == 0)
    (crossed, _), = case_taps(CASE["ref_xtalk"], 1, 1, reference_dir)
    offset = np.asarray(crossed["force"]) - force
    events = original["events"]
    held = (t > events["home_end_time"] + 1e-3) & (t < events["pullback_start_time"] - 1e-3)
    first_move_s = min(move["print_time"] for move in original["moves"] if move["z_r"] and move["start_v"] + abs(move["accel"]) > 0)
    approaching = (t > first_move_s + 0.01) & (t < events["home_end_time"] - 0.01)
    before = t < first_move_s
    assert np.count_nonzero(held) > 10 and np.all(np.abs(offset[held]) <= 1e-5)
    assert 1.0 - 1e-4 <= abs(offset[approaching][0]) <= 3.0 + 1e-4
    assert np.allclose(offset[approaching], offset[approaching][0], atol=1e-5)
    assert np.count_nonzero(approaching) > 10 and np.all(np.abs(offset[before]) <= 1e-5)


def test_a_microstep_error_moves_the_force_with_the_nozzle_and_the_truth_with_the_touch(reference_dir):
    """`_microstep_error((20, 40), 0.1)`: above the nozzle's first touch nothing changes; deep in the
    contact the force differs from the tap's by the bed's stiffness times the nozzle's stand-off,
    a sine of one full step; the truth scored is where the nozzle now touches, within the error's
    reach (at most 4 µm) of the bed's."""
    original = _original(reference_dir)
    force, z = np.asarray(original["force"]), np.asarray(original["z"])
    (_, bed_mm), = case_taps(CASE["ref_clip80"], 1, 1, reference_dir)  # the same tap, its truth kept
    (stepped, touch_mm), = case_taps(CASE["ref_ustep"], 1, 1, reference_dir)
    assert 0.0 < abs(touch_mm - bed_mm) * 1000.0 <= 4.0
    assert stepped["truth"] == {"z_contact": touch_mm}
    added = np.asarray(stepped["force"]) - force
    free = z > max(bed_mm, touch_mm) + 0.005
    assert np.all(np.abs(added[free]) <= 1e-5)
    deep = z < min(bed_mm, touch_mm) - 0.005
    g_per_um = force[np.argmax(np.abs(force))] / ((bed_mm - z.min()) * 1000.0)
    stand_off_um = -added[deep] / g_per_um
    assert np.count_nonzero(deep) > 20 and 0.5 < np.max(np.abs(stand_off_um)) <= 4.0 + 1e-3
    # the stand-off is a sine of one full step: fitted to the deep samples, it puts the nozzle's
    # true height (commanded + stand-off) at the scored touch on the bed
    fits = []
    for period_um in (20.0, 40.0):
        angle = 2.0 * np.pi * z[deep] * 1000.0 / period_um
        basis = np.column_stack([np.sin(angle), np.cos(angle)])
        coef, *_ = np.linalg.lstsq(basis, stand_off_um, rcond=None)
        fits.append((float(np.sum((basis @ coef - stand_off_um) ** 2)), period_um, coef))
    misfit, period_um, (a_sin, a_cos) = min(fits, key=lambda fit: fit[0])
    assert misfit < 1e-3 * len(stand_off_um)
    at_touch = 2.0 * np.pi * touch_mm * 1000.0 / period_um
    assert (touch_mm - bed_mm) * 1000.0 == pytest.approx(-(a_sin * np.sin(at_touch) + a_cos * np.cos(at_touch)), abs=0.01)


def test_hysteresis_uptime_and_a_declared_rate_change_only_what_they_say(reference_dir):
    original = _original(reference_dir)
    force = np.asarray(original["force"])
    (hyst, _), = case_taps(CASE["ref_hyst"], 1, 1, reference_dir)
    bump = np.asarray(hyst["force"]) - force
    peak_at = int(np.argmax(np.abs(force - np.median(force[:20]))))
    assert np.all(bump[:peak_at + 1] == 0.0) and 0.0 < np.max(np.abs(bump)) <= 0.03 * np.max(np.abs(force)) + 1e-3
    (later, _), = case_taps(CASE["ref_uptime"], 1, 1, reference_dir)
    shift_s = 30 * 86400.0
    assert np.allclose(np.asarray(later["time"]) - original["time"], shift_s, atol=1e-6)
    assert later["events"]["home_end_time"] - original["events"]["home_end_time"] == pytest.approx(shift_s)
    assert later["moves"][0]["print_time"] - original["moves"][0]["print_time"] == pytest.approx(shift_s)
    assert later["force"] == original["force"]
    slow = _original(reference_dir, "hx711_slow")
    (declared, _), = case_taps(CASE["ref_rate0.9"], 1, 1, reference_dir)
    assert declared["sample_rate"] == pytest.approx(0.9 * slow["sample_rate"]) and declared["time"] == slow["time"]
