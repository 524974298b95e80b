"""Z, decomposition and validation of the tap analysis on synthetic taps of known truth."""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest

from tapcell.tap import AnalysisOptions, analyze_tap
from tapcell.tap.analysis import repair_spikes
from tapcell.tap.segments import prefix_sums, segment_line, segment_sse
from tapcell.tap.synth import synth_tap
from tapcell.tap.validate import TapInvalid, check_points, split_checks_pass

EXACT = dict(noise_g=0.0, relaxation_fraction=0.0)
SHARP = AnalysisOptions(contact_model="sharp")


@pytest.mark.parametrize("polarity", [1, -1])
@pytest.mark.parametrize("sps", [320.0, 660.0, 2000.0])
@pytest.mark.parametrize(("options", "method"), [(AnalysisOptions(), "toe"), (SHARP, "contact_model")])
def test_noise_free_z_is_exact(polarity, sps, options, method):
    tap = synth_tap(polarity=polarity, sample_rate_sps=sps, z_contact_mm=0.1234, **EXACT)
    result = analyze_tap(tap, options)
    assert result.valid, result.message
    assert result.z_method == method
    assert abs(result.z_mm - 0.1234) * 1000 < 0.01  # measured: toe 0.001-0.004 µm, sharp < 0.001
    assert result.polarity == polarity


def test_a_negative_tap_reports_its_points_lines_and_angles_in_its_own_polarity():
    # The same tap with its force negated: analysed in positive polarity, reported in its own, so its
    # points' forces, lines and angles are the positive tap's negated (exactly: x -1 changes no bit but
    # the sign), its times and Z the same.
    tap = synth_tap(sample_rate_sps=320.0, z_contact_mm=0.1234, noise_g=0.3, seed=5)
    flipped = dataclasses.replace(tap, force_g=-np.asarray(tap.force_g))
    up, down = analyze_tap(tap), analyze_tap(flipped)
    assert up.valid and down.valid and (up.polarity, down.polarity) == (1, -1)
    assert down.points == [(t, -f) for t, f in up.points]
    assert down.lines == [(-slope, -intercept) for slope, intercept in up.lines]
    assert down.angles_deg == [-a for a in up.angles_deg]
    assert down.z_mm == up.z_mm and down.compression_force_g == up.compression_force_g


def test_noise_free_soft_sheet_is_exact_with_the_toe_or_a_calibrated_onset_and_biased_sharp():
    tap = synth_tap(contact_onset_um=6.0, **EXACT)
    calibrated = analyze_tap(tap, AnalysisOptions(contact_onset_um=6.0))
    toe = analyze_tap(tap)
    sharp = analyze_tap(tap, SHARP)
    # A calibrated onset selects the sharp model with that onset.
    assert calibrated.z_method == "contact_model" and abs(calibrated.z_mm) * 1000 < 0.01
    # The toe model (default) finds the 6 µm toe itself (a width on its grid: measured +0.004 µm).
    assert toe.z_method == "toe" and abs(toe.z_mm) * 1000 < 0.01
    assert toe.contact_onset_um == 6.0
    # A sharp-contact reading of a soft onset lands about onset/2 low.
    assert -3.1 < sharp.z_mm * 1000 < -2.7
    assert -3.1 < sharp.z_line_mm * 1000 < -2.7


def test_fitted_onset_recovers_width_on_noise_free_tap():
    tap = synth_tap(contact_onset_um=6.0, **EXACT)
    result = analyze_tap(tap, AnalysisOptions(fit_contact_onset=True))
    assert result.contact_onset_um == pytest.approx(6.0, abs=0.01)
    assert abs(result.z_mm) * 1000 < 0.01


@pytest.mark.parametrize("options", [AnalysisOptions(), SHARP])
def test_known_sensor_delay_is_removed_and_an_ignored_delay_biases_up(options):
    tap = synth_tap(sensor_delay_s=0.003, **EXACT)  # meta carries the delay
    known = analyze_tap(tap, options)
    assert known.sensor_delay_s == 0.003 and abs(known.z_mm) * 1000 < 0.01
    tap.meta.pop("sensor_delay_s")
    # Undeclared, the lag is read off the halt (P2 - halt = delay + half the conversion window).
    from_halt = analyze_tap(tap, options)
    assert from_halt.sensor_delay_s == pytest.approx(0.003, abs=2e-5)  # measured 2.9987 ms
    assert abs(from_halt.z_mm) * 1000 < 0.02
    biased = analyze_tap(tap, dataclasses.replace(options, sensor_delay_s=0.0))
    # 3 ms at 0.66 mm/s pullback = +1.98 µm
    assert biased.z_mm * 1000 == pytest.approx(1.98, abs=0.02)


def test_sensor_delay_estimated_from_the_tap():
    tap = synth_tap(sensor_delay_s=0.003, approach_speed_mm_s=2.0, noise_g=0.0)
    tap.meta.pop("sensor_delay_s")
    result = analyze_tap(tap, AnalysisOptions(sensor_delay_s="auto", contact_model="sharp"))
    assert result.sensor_delay_estimate_s == pytest.approx(0.003, abs=0.0003)
    assert abs(result.z_mm) * 1000 < 0.25


def test_points_lines_and_stiffness_of_a_clean_tap():
    tap = synth_tap(**EXACT)
    result = analyze_tap(tap)
    times = [t for t, _ in result.points]
    assert times == sorted(times)
    assert result.compression_force_g == pytest.approx(4.6 * 25.227, rel=0.02)
    assert result.stiffness_decompression_g_um == pytest.approx(4.6, rel=1e-3)
    assert result.stiffness_compression_g_um == pytest.approx(4.6, rel=0.02)
    assert result.lines[3][0] == pytest.approx(-4.6 * 660, rel=0.02)  # g/s at 0.66 mm/s
    json = result.to_json()
    assert len(json["points"]) == 6 and len(json["lines"]) == 5
    assert json["z"] == pytest.approx(result.z_mm, abs=1e-9)


@pytest.mark.parametrize(("options", "bias_um"), [(SHARP, (-0.12, 0.12)), (AnalysisOptions(), (0.9, 1.6))])
def test_noisy_clean_taps_are_unbiased_and_sigma_is_honest(options, bias_um):
    """The sharp model is unbiased on a contact with no toe. The toe model (default) reads it high:
    its prior spans toes of 0-16 µm and a hinge is the narrowest, so the noise lets wider toes in
    (measured over 4 × 25 seeds: +1.22 ... +1.30 µm, sd 0.48-0.63 µm, sd/σ 0.60-0.76)."""
    errors, sigmas = [], []
    for seed in range(25):
        tap = synth_tap(seed=seed, noise_g=2.0)
        result = analyze_tap(tap, options)
        assert result.valid, result.message
        errors.append(result.z_mm * 1000)
        sigmas.append(result.z_sigma_um)
    assert bias_um[0] < np.mean(errors) < bias_um[1]
    assert 0.5 < np.std(errors) / np.mean(sigmas) < 1.6


@pytest.mark.parametrize("nominal_rate_sps", [1e300, 1e-300, 3.2])
def test_a_nominal_sample_rate_the_times_contradict_is_not_used(nominal_rate_sps):
    """The file's sample_rate is nominal; the times are what was sampled. One far off them (a file
    claiming 1e300 sps made every lag and step zero or infinite: a traceback) gives the Z the tap
    gives without it."""
    tap = synth_tap(seed=4)
    honest = analyze_tap(dataclasses.replace(tap, sample_rate_sps=None))
    lying = analyze_tap(dataclasses.replace(tap, sample_rate_sps=nominal_rate_sps))
    assert lying.valid and lying.z_mm == honest.z_mm


def test_corrupted_frames_are_repaired_and_do_not_move_z():
    clean = analyze_tap(synth_tap(seed=4))
    corrupted = analyze_tap(synth_tap(seed=4, corrupted_frames=4))
    assert corrupted.valid and corrupted.outliers == 4
    assert abs(corrupted.z_mm - clean.z_mm) * 1000 < 0.05


def test_repair_spikes_keeps_edges():
    force = np.array([0.0, 0.1, -0.1, 0.0, 100.0, 300.0, 300.2, 299.9, 5000.0, 300.1, 300.0, 299.8])
    repaired, count = repair_spikes(force, 8.0)
    assert count == 1
    assert repaired[8] == pytest.approx(300.0)
    assert repaired[4] == 100.0  # a steep edge is not a spike


def test_segments_match_numpy_polyfit_far_from_the_time_origin():
    rng = np.random.default_rng(0)
    t = 1.0e5 + np.arange(400) / 660.0
    f = np.where(np.arange(400) < 200, 3.0 + 20.0 * (t - t[0]), -50.0) + rng.normal(0, 1, 400)
    ps = prefix_sums(t, f)
    slope, intercept = segment_line(ps, 10, 150)
    ref_slope, ref_intercept = np.polyfit(t[10:150] - 1e5, f[10:150], 1)
    assert slope == pytest.approx(ref_slope, rel=1e-6)
    assert intercept + slope * 1e5 == pytest.approx(ref_intercept, abs=1e-4)
    sse = segment_sse(ps, np.array([10]), np.array([150]))[0]
    residual = f[10:150] - np.polyval([ref_slope, ref_intercept], t[10:150] - 1e5)
    assert sse == pytest.approx(float(residual @ residual), rel=1e-6)


def test_z_trace_without_moves_gives_the_same_z():
    tap = synth_tap(seed=2)
    with_moves = analyze_tap(tap)
    tap.moves = []
    from_z = analyze_tap(tap)
    assert from_z.valid, from_z.message
    assert abs(from_z.z_mm - with_moves.z_mm) * 1000 < 0.001  # measured 3e-11 µm: the same motion


# --- validation codes -------------------------------------------------------------------

def _code(tap, **options):
    return analyze_tap(tap, AnalysisOptions(**options)).error


def test_too_few_and_too_many_moves():
    tap = synth_tap()
    few = dataclasses.replace(tap, moves=tap.moves[-4:])
    many = dataclasses.replace(tap, moves=[dataclasses.replace(tap.moves[0], print_time=tap.moves[0].print_time - 1)] + tap.moves)
    assert _code(few) == "TOO_FEW_PROBING_MOVES"
    assert _code(many) == "TOO_MANY_PROBING_MOVES"
    assert _code(dataclasses.replace(tap, moves=tap.moves[1:])) is None  # 5 moves are fine


def test_coasting_move_acceleration():
    tap = synth_tap()
    tap.moves[-5] = dataclasses.replace(tap.moves[-5], accel=-200.0)
    assert _code(tap) == "COASTING_MOVE_ACCELERATION"


def _slowing_into(tap, end_z_mm: float):
    """The tap with its probing move slowing down at 500 mm/s² from 5 mm/s to stop at `end_z_mm`
    (it starts 5²/(2·500) = 25 µm above that end)."""
    slowing = dataclasses.replace(tap.moves[-5], start_v=5.0, accel=-500.0, start_z=end_z_mm + 0.025)
    return dataclasses.replace(tap, moves=[*tap.moves[:-5], slowing, *tap.moves[-4:]])


def test_coasting_message_fits_the_printers_position_min():
    """Issue 20's leftover: the advice follows where the probing move ended (its [stepper_z]
    position_min): at Z=0 it asks for a negative position_min; at -2 it does not ask for -5 again."""
    at_zero = analyze_tap(_slowing_into(synth_tap(), 0.0))
    assert at_zero.error == "COASTING_MOVE_ACCELERATION"
    assert "about to stop at its end, Z 0.000 (the lowest Z a probe may reach: [stepper_z] position_min)" in at_zero.message
    assert "give [stepper_z] a negative position_min (the guide's example: position_min: -5)" in at_zero.message
    already = analyze_tap(_slowing_into(synth_tap(), -2.0))
    assert already.error == "COASTING_MOVE_ACCELERATION"
    assert "Z -2.000" in already.message and "2.000 mm below Z=0 already" in already.message
    assert "home Z again (G28 Z)" in already.message and "-5" not in already.message
    speeding = synth_tap()
    speeding.moves[-5] = dataclasses.replace(speeding.moves[-5], accel=200.0)
    message = analyze_tap(speeding).message
    assert "accelerating (200 mm/s²)" in message and "2.050 mm below where it started" in message  # 2.025 down to -0.025
    assert "position_min" not in message and "sample_retract_dist" in message


def test_pullback_too_short_and_break_contact_too_late():
    # Break contact ~25 µm above the halt: a 20 µm pullback never breaks contact, in a 28 µm one
    # it falls in the last sixth (after 23.3 µm), in a 30 µm one just inside (before 25 µm).
    assert _code(synth_tap(pullback_distance_mm=0.02)) == "TAP_PULLBACK_TOO_SHORT"
    too_late = analyze_tap(synth_tap(pullback_distance_mm=0.028))
    assert too_late.error == "TAP_BREAK_CONTACT_TOO_LATE"
    assert "in the last sixth of the pullback" in too_late.message and "increase pullback_distance" in too_late.message
    assert _code(synth_tap(pullback_distance_mm=0.03)) is None


def test_break_contact_too_early():
    assert _code(synth_tap(), sensor_delay_s=0.05) == "TAP_BREAK_CONTACT_TOO_EARLY"
    # The spec: break contact in the middle two thirds. At ~25 µm a 0.2 mm pullback breaks in
    # its first sixth (33 µm): the pullback is longer than it needs to be.
    early = analyze_tap(synth_tap(pullback_distance_mm=0.2))
    assert early.error == "TAP_BREAK_CONTACT_TOO_EARLY"
    assert "in the first sixth of the pullback" in early.message and "shorten pullback_distance" in early.message
    assert _code(synth_tap(pullback_distance_mm=0.14)) is None  # 25/140: 18 %, inside


def test_chronology_and_shape():
    tap = synth_tap()
    noise_only = dataclasses.replace(tap, force_g=np.random.default_rng(1).normal(0, 1, len(tap.time_s)))
    assert _code(noise_only) == "TAP_CHRONOLOGY"
    reversed_tap = dataclasses.replace(tap, force_g=tap.force_g[::-1].copy())
    assert _code(reversed_tap) == "TAP_SHAPE_INVALID"


def test_invalid_tap_keeps_its_lines_for_plots():
    result = analyze_tap(synth_tap(pullback_distance_mm=0.028))
    assert not result.valid and len(result.lines) == 5 and len(result.points) == 6


def test_contact_search_finds_the_global_minimum_of_the_profile_residual():
    from tapcell.tap.contact import profile_rss, search_contact

    rng = np.random.default_rng(3)
    x_lo = np.arange(60, dtype=float)  # µm, 1 µm windows (integration = one sample)
    x_min, span = x_lo, np.ones(60)
    truth_um, stiffness = 20.37, 4.6
    mean = np.clip(truth_um - x_min, 0.0, 1.0) * (truth_um - x_min - 0.5 * np.clip(truth_um - x_min, 0.0, 1.0))
    force = 3.0 + stiffness * mean + rng.normal(0.0, 1.0, 60)
    found = search_contact(force, x_min, span, 16.0, 24.0, 0.0, 1.0)
    fine = np.linspace(16.0, 24.0, 80001)
    brute = fine[np.argmin(profile_rss(force, x_min, span, 16.0, 24.0, 0.0, fine))]
    assert found == pytest.approx(brute, abs=0.002)
    assert abs(found - truth_um) < 0.3


def test_limits_of_the_benchmark_unknown_stiffness_costs_spread():
    from tapcell.tap.synth import NUISANCE_FIELDS, SynthTap, contact_sigma_limit_um

    spec = SynthTap(seed=0)
    tap = synth_tap(spec)
    only_contact = contact_sigma_limit_um(spec, tap)
    with_nuisance = contact_sigma_limit_um(spec, tap, NUISANCE_FIELDS)
    # Knowing the stiffness lets hundreds of dwell samples pin the height; fitting it does not.
    assert 0.010 < only_contact < 0.020
    assert 0.06 < with_nuisance < 0.09


def test_plot_draws_five_lines_six_named_points_and_z():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from tapcell.tap.plot import POINT_NAMES, draw_tap

    tap = synth_tap(seed=4)
    analysis = analyze_tap(tap)
    figure, axes = plt.subplots()
    draw_tap(axes, tap, analysis, "t")
    texts = [text.get_text() for text in axes.texts]
    assert texts[:6] == [f"P{k}" for k in range(6)]  # short labels at the points, named in a key
    assert "\n".join(f"P{k} {name}" for k, name in enumerate(POINT_NAMES)) in texts
    assert f"Z = {analysis.z_mm:.4f} mm ± {analysis.z_sigma_um:.2f} µm" in texts
    fitted = [line for line in axes.lines if line.get_color() == "red" and len(line.get_xdata()) == 2]
    assert len(fitted) == 5
    t0 = float(tap.time_s[0])
    for k, line in enumerate(fitted):  # each line runs from point k to point k+1
        assert line.get_xdata()[0] + t0 == pytest.approx(analysis.points[k][0])
        assert line.get_xdata()[1] + t0 == pytest.approx(analysis.points[k + 1][0])
    plt.close(figure)


def test_the_splits_own_check_passes_exactly_what_check_points_passes():
    # check_split leaves the points' order and the angles to the split's own check when it passed
    # them (SplitTap.points_pass): the two agree on every sign of every angle (zeros of both signs,
    # NaN) and on points in and out of time order.
    in_order = [(float(t), 0.0) for t in range(6)]
    swapped = [*in_order[:2], in_order[3], in_order[2], *in_order[4:]]
    outcomes = set()
    for points in (in_order, swapped):
        for angles in itertools.product((-2.0, -0.0, 0.0, 3.0, math.nan), repeat=4):
            try:
                check_points(points, list(angles))
                passes = True
            except TapInvalid:
                passes = False
            assert split_checks_pass(points, list(angles)) == passes, (points, angles)
            outcomes.add(passes)
    assert outcomes == {True, False}
