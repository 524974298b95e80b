"""A saturated sensor is refused for what the tap shows: TAP_SENSOR_SATURATED (issue 21).

A load cell whose ADC saturates (a small cell, a high gain, a fast probe) records the force clipped
flat at its limit. Before, such a tap read a few µm off with a σ that did not say so (clipped at 60 %
of its peak: +2.8..+4 µm on the reference taps, e/σ 2.3-3.4) or was rejected under codes that named
other causes (at 40 %: LOW_COMPRESSION_FORCE, TAP_CHRONOLOGY, LOW_TAP_QUALITY). The rule
(analysis.saturated_run, the kernel's `sample_problem`): 8 samples or more in a row exactly at the
extreme force away from the first sample, where the rest of the tap repeats a value in at most one
step in four (a sensor with steps coarser than its noise repeats values anywhere).
"""

import dataclasses
from pathlib import Path

import numpy as np
import pytest

import tapcell.taplab
from tapcell.tap import analysis, analyze_tap, read_tap_file
from tapcell.tap.synth import synth_tap

REAL_TAP = Path(tapcell.taplab.__file__).with_name("real") / "voron24_workbench.json"


def _clipped(tap, share: float, sign: float = 1.0):
    """The tap as a sensor saturating at `share` of its peak |force| records it (polarity times sign)."""
    force = sign * tap.force_g
    limit_g = share * np.max(np.abs(force))
    return dataclasses.replace(tap, force_g=np.clip(force, -limit_g, limit_g))


@pytest.mark.parametrize("seed", [0, 3])
def test_a_clipped_tap_is_refused_as_saturated(seed):
    # synth_tap (320 sps, 0.7 g noise, ~156 g peak) clipped at 80 %: 102 samples held at the limit
    # from sample 131 (measured on seeds 0-3; at 90 %: 98-99, at 60 %: 110). Unclipped: valid.
    tap = synth_tap(seed=seed, noise_g=0.7, sample_rate_sps=320)
    assert analyze_tap(tap).valid
    clipped = _clipped(tap, 0.8)
    answer = analyze_tap(clipped)
    assert not answer.valid and answer.error == "TAP_SENSOR_SATURATED"
    limit_g = 0.8 * np.max(np.abs(tap.force_g))
    assert f"holds at {limit_g:.1f} g, the tap's highest, for 102 samples in a row" in answer.message
    assert "lower the probing speed" in answer.message and "larger load cell" in answer.message
    assert analysis.saturated_run(clipped.force_g) == (131, 102)


@pytest.mark.parametrize("sign, side", [(1.0, "lowest"), (-1.0, "highest")])
def test_the_real_tap_clipped_either_polarity(sign, side):
    # The Voron capture reads its tap negative (-205 g at its peak, 959 samples at 332 sps). Clipped
    # at 90 % it holds -184.9 g (or +184.9 g flipped) for 95 samples, 284 ms; at 95 % its peak's
    # noise leaves fewer than 8 equal samples and it stays valid.
    tap = read_tap_file(REAL_TAP)[0]
    answer = analyze_tap(_clipped(tap, 0.9, sign))
    assert not answer.valid and answer.error == "TAP_SENSOR_SATURATED"
    assert f"holds at {sign * -184.9:.1f} g, the tap's {side}, for 95 samples in a row (284 ms)" in answer.message
    assert analyze_tap(_clipped(tap, 0.95, sign)).valid


# The Z each rounding moves by (measured 0.11, 0.72 and 3.1 µm): its bound.
@pytest.mark.parametrize("step_g, held, moved_um", [(1.0, 1, 0.3), (10.0, 1, 1.0), (20.0, 12, 4.0)])
def test_a_coarse_sensor_repeating_its_extreme_is_not_saturated(step_g, held, moved_um):
    # The real tap in coarser grams: rounded to 20 g its peak holds 12 samples in a row at -200 g
    # (more than the 8 the rule needs), but 97 % of its other steps repeat a value too: a sensor whose
    # steps are coarser than its noise, measured as before (43.4 um clean, 40.3 um in 20 g steps).
    tap = read_tap_file(REAL_TAP)[0]
    rounded = dataclasses.replace(tap, force_g=np.round(tap.force_g / step_g) * step_g)
    f = rounded.force_g
    at_peak = np.concatenate(([0], f == f.min(), [0]))
    edges = np.flatnonzero(np.diff(at_peak))
    assert max(edges[1::2] - edges[::2]) == held
    answer = analyze_tap(rounded)
    assert answer.valid, answer.message
    assert answer.z_mm == pytest.approx(analyze_tap(tap).z_mm, abs=moved_um / 1000.0)
    assert analysis.saturated_run(f) == (0, 0)


def test_a_reading_frozen_to_the_end_is_not_called_saturated():
    # A sensor that stopped changing at the peak (sample 133 of 343) holds 210 samples at its
    # extreme, but the force never comes back from it: not a limit passed and left. The analysis
    # reads a nozzle still pressing and the live probe names the stuck sensor
    # (tests/test_hostile_inputs.py).
    tap = synth_tap(seed=0, noise_g=0.7, sample_rate_sps=320)
    force = tap.force_g.copy()
    peak = int(np.argmax(force))
    force[peak:] = force[peak]
    assert analysis.saturated_run(force) == (0, 0)
    assert analyze_tap(dataclasses.replace(tap, force_g=force)).error == "TAP_PULLBACK_TOO_SHORT"


def test_the_run_must_be_eight_samples_long():
    # Synth seed 1 clipped at 99 % of its peak holds exactly SATURATED_RUN samples at the limit;
    # one of them a hair below it leaves 7 in a row, which a clean tap may hold: measured.
    tap = synth_tap(seed=1, noise_g=0.7, sample_rate_sps=320)
    limit_g = 0.99 * np.max(np.abs(tap.force_g))
    force = np.clip(tap.force_g, -limit_g, limit_g)
    assert analysis.saturated_run(force) == (131, analysis.SATURATED_RUN)
    assert analyze_tap(dataclasses.replace(tap, force_g=force)).error == "TAP_SENSOR_SATURATED"
    force[131 + analysis.SATURATED_RUN - 1] = np.nextafter(limit_g, 0.0)
    assert analysis.saturated_run(force) == (0, 0)
    assert analyze_tap(dataclasses.replace(tap, force_g=force)).valid


def _held_at_100_g(repeats: int) -> np.ndarray:
    """60 distinct steps up, 10 samples held at 100 g, 70 distinct steps down: 129 steps off the
    extreme, `repeats` of them repeating the value before."""
    force = np.concatenate((np.linspace(0.0, 90.0, 60), np.full(10, 100.0), np.linspace(89.0, 0.5, 70)))
    for i in range(72, 72 + 2 * repeats, 2):
        force[i] = force[i - 1]
    return force


def test_the_rest_may_repeat_a_value_in_one_step_of_four():
    # 32 repeats of 129 steps: 4 x 32 <= 129, a run at a limit; 33: a sensor coarser than its noise.
    assert analysis.saturated_run(_held_at_100_g(32)) == (60, 10)
    assert analysis.saturated_run(_held_at_100_g(33)) == (0, 0)
    if analysis._C is not None:  # the kernel's twin of the same rule
        time_s = np.arange(140) / 320.0
        assert analysis._C.sample_problem(time_s, _held_at_100_g(32)) == analysis.SAMPLES_SATURATED
        assert analysis._C.sample_problem(time_s, _held_at_100_g(33)) == analysis.SAMPLES_REPEATING  # fine
