"""Sub-sample trigger timing (`tapcell.extras.load_cell_probe.trigger_crossing`) on ideal contact ramps:
the estimated crossing of the threshold does not move with where in a conversion the contact fell."""

from __future__ import annotations

import numpy as np
import pytest

from tapcell.extras.load_cell_probe.safety import stop_timing
from tapcell.extras.load_cell_probe.trigger_crossing import (
    data_ready_times_s,
    replay_filtered_g,
    threshold_crossing,
    window_middle_times_s,
)
from tapcell.mcu.trigger import TriggerParams

HX717 = stop_timing("hx717", 320.0, "mcu", "mcu")
ADS1220 = stop_timing("ads1220", 660.0, "mcu", "mcu")
STIFFNESS_G_UM = 3.26  # the virtual printer's bed
PHASES = np.linspace(0.0, 1.0, 40, endpoint=False)


def contact_samples(timing, speed_mm_s: float, threshold_g: float, phase: float, rng, rate_error: float = 0.0):
    """Samples of an integrating ADC while the nozzle presses into the bed from contact on, up to the
    first at or past threshold_g: (read times, force), and the time the force crossed the threshold.
    The contact falls `phase` of a period into conversion 40; reads come 0..T/10 after data-ready."""
    period_s = timing.period_s * (1.0 + rate_error)
    ramp_g_s = STIFFNESS_G_UM * speed_mm_s * 1000.0
    contact_s = 1.0 + (40 + phase) * period_s
    start_s = 1.0 + np.arange(80) * period_s  # window k: [start, start + period]
    before = np.maximum(start_s - contact_s, 0.0)
    after = np.maximum(start_s + period_s - contact_s, 0.0)
    force_g = ramp_g_s * (after ** 2 - before ** 2) / (2.0 * period_s)
    read_s = start_s + period_s + timing.pipeline_s + rng.uniform(0.0, timing.read_delay_s, start_s.size)
    last = int(np.argmax(force_g >= threshold_g))
    return read_s[:last + 1], force_g[:last + 1], contact_s + threshold_g / ramp_g_s


@pytest.mark.parametrize("timing, speed_mm_s, threshold_g", [(HX717, 8.0, 75.0), (HX717, 5.0, 125.0),
                                                             (ADS1220, 8.0, 75.0)])
def test_the_crossing_does_not_move_with_the_sample_phase(timing, speed_mm_s, threshold_g):
    rng = np.random.default_rng(1)
    errors_um, trigger_errors_um = [], []
    for phase in PHASES:
        read_s, force_g, true_s = contact_samples(timing, speed_mm_s, threshold_g, phase, rng)
        crossing = threshold_crossing(read_s, force_g, threshold_g, timing)
        assert crossing.interpolated and 0.0 <= crossing.fraction <= 1.0
        assert crossing.trigger_time_s == read_s[-1]
        errors_um.append((crossing.time_s - true_s) * speed_mm_s * 1000.0)
        trigger_errors_um.append((read_s[-1] - true_s) * speed_mm_s * 1000.0)
    # The triggering sample's own time moves by a sample's travel with the phase (25 um at 8 mm/s
    # and 320 sps). The crossing moves by what the contact's kink and the read delays leave once
    # the grid is fitted, and sits on the true crossing: measured spread 0.98 / 0.62 / 0.47 um
    # (3.9 / 3.9 / 3.9 % of a sample's travel), largest error 0.53 / 0.34 / 0.26 um (2.1 %).
    travel_um = speed_mm_s * 1000.0 * timing.period_s
    assert np.ptp(trigger_errors_um) > 0.9 * travel_um
    assert np.ptp(errors_um) < 0.08 * travel_um
    assert np.max(np.abs(errors_um)) < 0.04 * travel_um


def test_a_slow_chip_clock_and_a_refused_frame_keep_the_grid():
    """The grid is fitted to the chip's real period (1.5 % fast here, as the slow-adc scenario's
    HX711) and a missing sample leaves a gap of whole periods, not a shifted grid."""
    rng = np.random.default_rng(2)
    timing = stop_timing("hx711", 80.0, "mcu", "mcu")
    period_s = timing.period_s / 1.015
    ready_s = 3.0 + np.arange(64) * period_s
    read_s = ready_s + rng.uniform(0.0, timing.read_delay_s, ready_s.size)
    keep = np.ones(ready_s.size, dtype=bool)
    keep[30] = False
    fitted_s = data_ready_times_s(read_s[keep], timing.period_s)
    # measured: within 0.005 periods of the true data-ready instants (the reads spread 0.1 period)
    assert np.max(np.abs(fitted_s - ready_s[keep])) < 0.02 * timing.period_s


def test_without_samples_to_interpolate_the_trigger_window_middle_is_the_answer():
    middle_s = float(window_middle_times_s(2.0, HX717))
    # read time less half the longest read delay, no pipeline (HX717) and half a period
    assert middle_s == pytest.approx(2.0 - 0.05 / 320.0 - 0.5 / 320.0, abs=1e-12)
    alone = threshold_crossing(np.array([2.0]), np.array([90.0]), 75.0, HX717)
    assert (alone.time_s, alone.fraction, alone.interpolated) == (pytest.approx(middle_s), 1.0, False)
    # The force fell between the two samples (noise on a trigger that fired at once): no line to follow.
    falling = threshold_crossing(np.array([2.0, 2.0 + 1 / 320.0]), np.array([80.0, 76.0]), 75.0, HX717)
    assert not falling.interpolated and falling.time_s == pytest.approx(middle_s + 1 / 320.0)


def test_the_crossing_is_on_the_line_between_the_two_samples():
    """Two samples a period apart at 25 g and 125 g: a 75 g threshold is crossed half-way between
    their window middles; a pull (negative force) is crossed on its own side."""
    t_s = 2.0 + np.arange(20) / 320.0  # reads exactly on the grid
    force_g = np.zeros(20)
    force_g[-2:] = (25.0, 125.0)
    crossing = threshold_crossing(t_s, force_g, 75.0, HX717)
    middles = t_s[-2:] - 0.5 / 320.0  # the fitted grid sits on these reads: no read delay left
    assert crossing.fraction == pytest.approx(0.5)
    assert crossing.time_s == pytest.approx(middles.mean(), abs=1e-9)
    pull = threshold_crossing(t_s, -force_g, 75.0, HX717)
    assert pull.time_s == pytest.approx(crossing.time_s, abs=1e-12)


def test_replay_gives_the_firmware_filtered_force_up_to_its_trigger():
    params = TriggerParams(counts_per_gram=110.0, reference_tare_counts=-38000, trigger_force_g=75.0,
                           sample_rate_sps=320.0)
    t_s = 1.0 + np.arange(1, 12) / 320.0
    grams = np.array([0, 0, 1, -1, 0, 10, 40, 70, 80, 120, 160], dtype=float)
    counts = np.round(-38000 + 110.0 * grams)
    replay = replay_filtered_g(params, -38000, 1.0, t_s, counts, float(t_s[8]))
    assert replay is not None
    times_s, filtered_g = replay
    np.testing.assert_array_equal(times_s, t_s[:9])
    np.testing.assert_allclose(filtered_g, grams[:9], atol=0.01)
    # A trigger time the replay does not trigger on (a sample the host lacks): nothing to interpolate.
    assert replay_filtered_g(params, -38000, 1.0, t_s, counts, float(t_s[7])) is None
    assert replay_filtered_g(params, -38000, 1.0, np.delete(t_s, 8), np.delete(counts, 8), float(t_s[8])) is None
