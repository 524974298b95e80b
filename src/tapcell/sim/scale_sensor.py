"""An extra load cell with no contact physics (a spool scale, a bed corner cell), on the
virtual printer's clock: known weights, white and 1/f noise, a zero offset to calibrate."""

from __future__ import annotations

import numpy as np

from tapcell.host.backend import SampleBatch
from tapcell.sim.mcu import SampleChunk, VirtualMCU
from tapcell.sim.params import make_params
from tapcell.sim.sensor import IndexedNoise, chip_timing, counts_from_force, pink_block_maker


class ScaleSensor:
    def __init__(self, printer, name: str, chip: str, sample_rate_sps: float, seed: int):
        self.name = name
        self._printer = printer
        self.params = make_params({"chip": chip, "sample_rate_sps": float(sample_rate_sps)})
        streams = np.random.SeedSequence(seed).spawn(5)
        rng = [np.random.Generator(np.random.PCG64(s)) for s in streams]
        p = self.params
        self._timing = chip_timing(p)
        self._white = IndexedNoise(rng[0], lambda g, n: g.standard_normal(n) * p.white_noise_counts)
        self._pink = IndexedNoise(rng[1], pink_block_maker(p.pink_noise_counts, p.sample_rate_sps))
        self._mcu = VirtualMCU(self._timing.period_s, p.read_jitter_s, 0.0, 0.0, rng[2], rng[3])
        # each extra cell has its own sensitivity and offset, so calibration has something to find
        self.counts_per_gram = float(rng[4].uniform(80.0, 400.0))
        self.zero_offset_counts = float(rng[4].uniform(-80000.0, 80000.0))
        self._weights: list[tuple[float, float]] = []   # (from_s, grams) steps
        self._next_k = 0

    @property
    def sensor_info(self) -> dict:
        p = self.params
        return {"chip": p.chip, "sample_rate_sps": p.sample_rate_sps, "gain": p.gain, "counts_bits": 24,
                "counts_min": -(1 << 23), "counts_max": (1 << 23) - 1}

    def place_weight(self, grams: float, add: bool = False) -> float:
        """Like VirtualPrinter.place_weight: replaces the weight (or adds to it); returns the total."""
        now_s = self._printer.now_s
        total = float(grams) + (self._load_at(now_s) if add else 0.0)
        self._weights.append((now_s, total))
        return total

    def remove_weight(self) -> None:
        self._weights.append((self._printer.now_s, 0.0))

    def take_samples(self) -> SampleBatch:
        self.advance_to(self._printer.now_s)
        return self._mcu.take(self._printer.now_s)

    def _load_at(self, t_s: float) -> float:
        return float(self._loads_at(np.array([t_s]))[0])

    def _loads_at(self, t_s: np.ndarray) -> np.ndarray:
        """The load in force at each time: the last weight change at or before it (0 before any)."""
        if not self._weights:
            return np.zeros(t_s.shape)
        starts = np.array([w[0] for w in self._weights])
        loads = np.array([0.0] + [w[1] for w in self._weights])
        return loads[np.searchsorted(starts, t_s, side="right")]

    def advance_to(self, t_s: float) -> None:
        k_end = self._timing.first_index_after(t_s + self._timing.pipeline_s)
        if k_end <= self._next_k:
            return
        k0, k1 = self._next_k, k_end
        t_ready = self._timing.ready_times(k0, k1)
        force = self._loads_at(t_ready - self._timing.period_s / 2)
        counts = counts_from_force(force, self.counts_per_gram, self.zero_offset_counts,
                                   self._white.values(k0, k1) + self._pink.values(k0, k1))
        self._mcu.deliver(SampleChunk(t_ready + self._mcu.read_delays(k0, k1), counts, force, 0, 0))
        self._next_k = k1
