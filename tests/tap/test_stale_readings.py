"""Stale readings (issue 21's sweep, `ref_stale3`): a sensor read before its next conversion hands
over the last value again at a new time. A reading equal to the one before it, after which the force
moves on by more than STALE_JUMP_NOISE noise sigmas, is dropped as a lost reading is."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from bench.tap_sweep import CASES, Case, analyse_in_process, case_taps
from tapcell.tap import analysis
from tapcell.tap.analysis import STALE_JUMP_NOISE, STALE_MAX_SHARE, noise_sigma_g, stale_readings
from tapcell.tap.synth import synth_tap

CASE = {case.name: case for case in CASES}

# (seed, tap) of `ref_stale3` rejected before: TAP_CONTACT_MISMATCH, TAP_CHRONOLOGY, LOW_TAP_QUALITY;
# measured then -0.98, +0.17 and -0.28 µm off (by hand).
STALE_TAPS = ((60, 3, "TAP_CONTACT_MISMATCH"), (53, 6, "TAP_CHRONOLOGY"), (54, 9, "LOW_TAP_QUALITY"))


def ramp_with_noise(seed: int = 0, samples: int = 200) -> np.ndarray:
    """Free air, a steep ramp of 20 g a sample over samples 100-109, free air again; 1 g of noise."""
    rng = np.random.default_rng(seed)
    force_g = np.concatenate([np.zeros(100), 20.0 * np.arange(1, 11), np.full(samples - 110, 200.0)])
    return force_g + rng.normal(0.0, 1.0, samples)


@pytest.mark.usefixtures("kernel_or_twin")
def test_a_reading_repeated_on_a_ramp_is_stale():
    force_g = ramp_with_noise()
    force_g[104] = force_g[103]
    assert stale_readings(force_g).tolist() == [104]


@pytest.mark.usefixtures("kernel_or_twin")
def test_a_run_of_repeats_on_a_ramp_is_stale_whole():
    force_g = ramp_with_noise()
    force_g[104:107] = force_g[103]
    assert stale_readings(force_g).tolist() == [104, 105, 106]


@pytest.mark.usefixtures("kernel_or_twin")
def test_a_reading_repeated_in_free_air_is_kept():
    """Whether it is stale or not, the force does not move on from it: nothing tells, nothing is lost."""
    force_g = ramp_with_noise()
    force_g[50] = force_g[49]
    assert stale_readings(force_g) is None


@pytest.mark.usefixtures("kernel_or_twin")
def test_the_jump_is_weighed_against_the_noise():
    force_g = ramp_with_noise()
    force_g[150] = force_g[149]
    noise_g = noise_sigma_g(force_g)
    force_g[151:] += force_g[150] + 0.9 * STALE_JUMP_NOISE * noise_g - force_g[151]  # moves on, under the limit
    assert stale_readings(force_g) is None
    force_g[151:] += 0.2 * STALE_JUMP_NOISE * noise_g  # now over it
    assert stale_readings(force_g).tolist() == [150]


@pytest.mark.usefixtures("kernel_or_twin")
def test_a_sensor_whose_steps_are_coarser_than_its_noise_tells_nothing():
    force_g = np.round(ramp_with_noise() / 2.0) * 2.0  # 2 g steps under 1 g of noise: a fifth repeat
    repeats = int(np.count_nonzero(force_g[1:] == force_g[:-1]))
    assert repeats > STALE_MAX_SHARE * len(force_g)
    force_g[104] = force_g[103]
    assert stale_readings(force_g) is None


@pytest.mark.parametrize("seed,k,_code", STALE_TAPS)
def test_a_clean_tap_with_stale_readings_is_measured(measured_within, seed, k, _code):
    answer = measured_within("ref_stale3", seed, k, 3.0)  # -0.98, +0.17, -0.28 um
    assert answer["stale_readings"] >= 1


@pytest.mark.parametrize("seed,k,code", STALE_TAPS)
def test_with_its_stale_readings_kept_the_tap_is_rejected(reference_dir, seed, k, code, monkeypatch):
    """The mechanism: the same taps with nothing dropped."""
    monkeypatch.setattr(analysis, "stale_readings", lambda force_g: None)
    answer = analyse_in_process(case_taps(CASE["ref_stale3"], seed, k + 1, reference_dir)[k][0])
    assert answer["error"] == code
    assert "stale_readings" not in answer


def test_a_clean_reference_tap_drops_nothing(reference_dir):
    clean = Case("clean", "reference HX717", "accept", reference=("clean_hx717", 1))
    for tap, _ in case_taps(clean, 1, 20, reference_dir):
        assert "stale_readings" not in analyse_in_process(tap)


def test_a_tap_without_a_repeated_reading_skips_the_look(monkeypatch):
    """The sample check's kernel says whether any reading equals the one before it; without one the
    analysis never calls `stale_readings` (a clean tap's 2 µs), and with one it does."""
    if analysis._C is None:
        pytest.skip("the compiled kernels are not built here")
    calls = []
    monkeypatch.setattr(analysis, "stale_readings", lambda force_g: calls.append(len(force_g)))
    tap = synth_tap(seed=3)
    force_g = np.asarray(tap.force_g, dtype=float)
    assert not np.any(force_g[1:] == force_g[:-1])
    analysis.analyze_tap(tap)
    assert calls == []
    force_g[40] = force_g[39]
    analysis.analyze_tap(dataclasses.replace(tap, force_g=force_g))
    assert calls == [len(force_g)]


def _repeated(force_g: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The force (`ramp_with_noise`) with a few runs of 1-3 readings repeated: one on its ramp, the others
    anywhere (in free air most), one at the very end sometimes."""
    force_g = force_g.copy()
    starts = [int(rng.integers(101, 108)), *rng.choice(np.arange(1, len(force_g) - 1), size=int(rng.integers(0, 5)))]
    for start in starts:
        force_g[start:start + int(rng.integers(1, 4))] = force_g[start - 1]
    if rng.random() < 0.3:
        force_g[-2:] = force_g[-3]
    return force_g


def test_the_kernel_finds_the_twins_readings(reference_dir):
    """The same indices from the kernel and the twin: on the reference taps that repeat a reading (more
    than half of them: a repeat in free air), and on ramps with runs repeated anywhere."""
    if analysis._C is None:
        pytest.skip("the compiled kernels are not built here")
    from tapcell.tap.readers import read_tap_file

    rng = np.random.default_rng(21)
    forces = [np.asarray(read_tap_file(path)[0].force_g, dtype=float)
              for path in sorted(reference_dir.glob("clean_hx717_00[0-3]*.json"))]
    forces += [_repeated(ramp_with_noise(seed), rng) for seed in range(200)]
    forces += [np.array([1.0, 1.0]), np.array([1.0, 1.0, 5.0]), np.array([2.0, 2.0, 2.0]), np.array([0.0, 3.0, 3.0])]
    kernel = analysis._C
    found = 0
    for force_g in forces:
        fast = analysis.stale_readings(force_g)
        analysis._C = None
        try:
            twin = analysis.stale_readings(force_g)
        finally:
            analysis._C = kernel
        assert (fast is None) == (twin is None)
        if fast is not None:
            assert fast.dtype == twin.dtype and fast.tolist() == twin.tolist()
            found += 1
    assert found == 200  # every ramp's run is stale, to both
