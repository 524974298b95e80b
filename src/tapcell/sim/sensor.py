"""The load-cell ADC: conversion timing, integration, noise, hum and counts.

The chip converts back to back on its own oscillator: conversion k integrates the cell
signal over one period and is ready (DRDY) at t0 + (k+1)·T, plus a chip pipeline delay.
Noise is generated per sample *index* in fixed blocks, so the same seed gives the same
noise however the simulation is chunked (and re-running a chunk after a halt is exact).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from tapcell.sim.params import CHIP_PIPELINE_PERIODS, SimParams

COUNTS_MIN = -(1 << 23)
COUNTS_MAX = (1 << 23) - 1
PHYSICS_STEP_MAX_S = 0.5e-3   # finest grid spacing the contact physics needs at probing speeds


@dataclass(frozen=True)
class ChipTiming:
    period_s: float          # real conversion period (nominal rate corrected by the oscillator error)
    substeps: int            # physics grid points per conversion window
    pipeline_s: float        # window end to data ready
    first_ready_s: float     # DRDY of conversion 0

    @property
    def grid_dt_s(self) -> float:
        return self.period_s / self.substeps

    def ready_times(self, k0: int, k1: int) -> np.ndarray:
        return self.first_ready_s + np.arange(k0, k1) * self.period_s

    def first_index_after(self, t_s: float) -> int:
        """First conversion whose data-ready time is after t_s."""
        return max(0, math.floor((t_s - self.first_ready_s) / self.period_s) + 1)

    def window_start_s(self, k: int) -> float:
        """When the integration window of conversion k opens."""
        return self.first_ready_s - self.pipeline_s - self.period_s + k * self.period_s

    def grid_times(self, k0: int, k1: int) -> np.ndarray:
        """Midpoints of the physics grid covering the windows of conversions k0..k1-1."""
        j = np.arange(k0 * self.substeps, k1 * self.substeps)
        return self.window_start_s(0) + (j + 0.5) * self.grid_dt_s


def chip_timing(params: SimParams, t0_s: float = 0.0) -> ChipTiming:
    period = 1.0 / (params.sample_rate_sps * (1.0 + params.chip_rate_error))
    substeps = max(4, math.ceil(period / PHYSICS_STEP_MAX_S))
    pipeline = CHIP_PIPELINE_PERIODS[params.chip] * period
    return ChipTiming(period, substeps, pipeline, t0_s + period + pipeline)


class IndexedNoise:
    """Per-sample-index random values generated in blocks from one Generator."""

    BLOCK = 4096

    def __init__(self, rng: np.random.Generator, make_block):
        self._rng = rng
        self._make_block = make_block      # (rng, n) -> array; may keep filter state between blocks
        self._blocks: dict[int, np.ndarray] = {}
        self._next_block = 0

    def values(self, k0: int, k1: int) -> np.ndarray:
        first, last = k0 // self.BLOCK, (k1 - 1) // self.BLOCK
        while self._next_block <= last:
            self._blocks[self._next_block] = self._make_block(self._rng, self.BLOCK)
            self._next_block += 1
            self._blocks.pop(self._next_block - 4, None)   # keep a few recent blocks only
        if k1 <= k0:
            return np.zeros(0)
        joined = np.concatenate([self._blocks[b] for b in range(first, last + 1)])
        offset = first * self.BLOCK
        return joined[k0 - offset:k1 - offset]


def pink_block_maker(rms: float, sample_rate_sps: float):
    """1/f-like noise: equal-power first-order lowpass processes with corner times a decade apart."""
    taus_s = (0.03, 0.3, 3.0, 30.0)
    poles = [math.exp(-1.0 / (tau * sample_rate_sps)) for tau in taus_s]
    # each process: x[n] = p x[n-1] + sqrt(1-p²) w[n] has unit variance
    states = [np.zeros(1) for _ in poles]
    each_rms = rms / math.sqrt(len(poles))

    def make(rng: np.random.Generator, n: int) -> np.ndarray:
        total = np.zeros(n)
        for i, p in enumerate(poles):
            w = rng.standard_normal(n) * math.sqrt(1.0 - p * p)
            y, states[i] = lfilter([1.0], [1.0, -p], w, zi=states[i])
            total += y
        return total * each_rms

    return make


def window_average_sine(amplitude: float, freq_hz: float, t_end_s: np.ndarray, window_s: float,
                        phase: float = 0.0) -> np.ndarray:
    """Mean of amplitude·sin(2πf t + phase) over [t_end - window, t_end]: what an integrating ADC sees."""
    w = 2.0 * math.pi * freq_hz
    a = t_end_s - window_s
    return amplitude * (np.cos(w * a + phase) - np.cos(w * t_end_s + phase)) / (w * window_s)


def counts_from_force(force_g: np.ndarray, counts_per_gram: float, zero_offset_counts: float,
                      electrical_counts: np.ndarray) -> np.ndarray:
    """Ideal 24-bit conversion: offset + sensitivity·force + noise, rounded and saturated."""
    raw = zero_offset_counts + counts_per_gram * force_g + electrical_counts
    return np.clip(np.rint(raw), COUNTS_MIN, COUNTS_MAX).astype(np.int32)
