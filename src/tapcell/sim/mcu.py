"""The virtual MCU: when samples are read, what reaches the host, and how the trigger stops Z.

The MCU polls data-ready ten times per sample period (so a sample is read up to T/10 after
it is ready) and its task adds a small random delay. A sample read more than one period
late is lost and counted as an overflow, like a real bulk-sensor buffer. Samples go to the
host in batches; during a probing move each one also goes through the firmware trigger.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass

import numpy as np

from tapcell.host.backend import SampleBatch
from tapcell.sim.motion import FORGET_BATCH, HISTORY_KEEP_S
from tapcell.sim.sensor import IndexedNoise


@dataclass
class TriggerEvent:
    """The firmware trigger fired (triggered=True) or reported an error, at MCU time time_s."""

    time_s: float
    triggered: bool
    error: object


@dataclass
class SampleChunk:
    """Samples of a run of conversions as they reach the MCU (bad, missing and late ones removed)."""

    t_s: np.ndarray
    counts: np.ndarray
    force_g: np.ndarray       # true, noise-free cell force of each kept sample (tests only)
    errors: int
    overflows: int


class SampleLog:
    """The delivered samples of the last HISTORY_KEEP_S, kept for tap files and truth: times,
    counts and the true cell force. Older chunks are dropped (the cost per tap stays flat)."""

    def __init__(self):
        self._parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self._part_ends: list[float] = []  # last sample time of each part (non-decreasing)

    def append(self, t_s, counts, force_g) -> None:
        if t_s.size:
            self._parts.append((t_s, counts, force_g))
            self._part_ends.append(float(t_s[-1]))
            old = bisect.bisect_left(self._part_ends, self._part_ends[-1] - HISTORY_KEEP_S)
            if old > FORGET_BATCH:
                del self._parts[:old], self._part_ends[:old]

    def between(self, t0_s: float, t1_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        first = bisect.bisect_left(self._part_ends, t0_s)
        parts = [p for p in self._parts[first:] if p[0][0] <= t1_s]
        if not parts:
            return np.zeros(0), np.zeros(0, dtype=np.int32), np.zeros(0)
        t, c, f = (np.concatenate(col) for col in zip(*parts))
        keep = (t >= t0_s) & (t <= t1_s)
        return t[keep], c[keep], f[keep]


class VirtualMCU:
    def __init__(self, period_s: float, read_jitter_s: float, stop_delay_s: float, multi_mcu_delay_s: float,
                 poll_rng: np.random.Generator, jitter_rng: np.random.Generator):
        self.period_s = period_s
        self.stop_latency_s = stop_delay_s + multi_mcu_delay_s
        self._poll = IndexedNoise(poll_rng, lambda rng, n: rng.uniform(0.0, period_s / 10.0, n))
        self._jitter = IndexedNoise(jitter_rng, lambda rng, n: rng.exponential(read_jitter_s, n)
                                    if read_jitter_s > 0 else np.zeros(n))
        self._out_t: list[np.ndarray] = []
        self._out_counts: list[np.ndarray] = []
        self.errors = 0
        self.overflows = 0
        self._taken_errors = 0
        self._taken_overflows = 0
        self.log = SampleLog()
        self.last_counts: int | None = None

    def read_delays(self, k0: int, k1: int) -> np.ndarray:
        """Data-ready detection (polling at T/10) plus task latency, per sample index."""
        return self._poll.values(k0, k1) + self._jitter.values(k0, k1)

    def deliver(self, chunk: SampleChunk) -> None:
        """Queue a chunk's good samples for the host; count its errors and overflows."""
        self.errors += chunk.errors
        self.overflows += chunk.overflows
        t, c = chunk.t_s, chunk.counts
        if t.size:
            self._out_t.append(t)
            self._out_counts.append(c)
            self.last_counts = int(c[-1])
        self.log.append(t, c, chunk.force_g)

    def pending(self, after_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Queued samples read after `after_s` (not yet visible to the host)."""
        t, c = self._queued()
        keep = t > after_s
        return t[keep], c[keep]

    def take(self, now_s: float) -> SampleBatch:
        t, c = self._queued()
        ready = t <= now_s
        self._out_t, self._out_counts = ([t[~ready]], [c[~ready]]) if np.any(~ready) else ([], [])
        batch = SampleBatch(t[ready], c[ready], self.errors - self._taken_errors,
                            self.overflows - self._taken_overflows)
        self._taken_errors, self._taken_overflows = self.errors, self.overflows
        return batch

    def _queued(self):
        if not self._out_t:
            return np.zeros(0), np.zeros(0, dtype=np.int32)
        return np.concatenate(self._out_t), np.concatenate(self._out_counts)


class TriggerFeeder:
    """Feeds samples to the firmware trigger in batches and ticks its sensor watchdog in gaps."""

    def __init__(self, trigger, period_s: float, start_s: float, no_error):
        self.trigger = trigger
        self.period_s = period_s
        self.last_sample_s = start_s
        self.last_tick_s = start_s
        self.no_error = no_error

    def feed(self, t_s: np.ndarray, counts: np.ndarray, until_s: float) -> TriggerEvent | None:
        """Feed samples in time order; between samples further apart than 1.5 periods the
        watchdog is checked every period, as the MCU's timer would."""
        bounds = np.concatenate([[self.last_sample_s], t_s, [until_s]])
        gaps = np.nonzero(np.diff(bounds) > 1.5 * self.period_s)[0]
        start = 0
        for gap in gaps:
            event = self._feed_run(t_s[start:gap], counts[start:gap])
            if event is not None:
                return event
            event = self._tick_watchdog(bounds[gap], bounds[gap + 1])
            if event is not None:
                return event
            start = gap
        return self._feed_run(t_s[start:], counts[start:])

    def _feed_run(self, t_s, counts) -> TriggerEvent | None:
        if t_s.size == 0:
            return None
        result = self.trigger.feed(np.ascontiguousarray(t_s, dtype=float),
                                   np.ascontiguousarray(counts, dtype=np.int32))
        if result.trigger_index is not None and result.trigger_index >= 0:
            return TriggerEvent(float(result.trigger_time_s), True, self.no_error)
        if result.error != self.no_error:
            has_index = result.error_index is not None and 0 <= result.error_index < t_s.size
            index = result.error_index if has_index else t_s.size - 1
            return TriggerEvent(float(t_s[index]), False, result.error)
        self.last_sample_s = self.last_tick_s = float(t_s[-1])
        return None

    def _tick_watchdog(self, from_s: float, to_s: float) -> TriggerEvent | None:
        tick = max(from_s, self.last_tick_s) + self.period_s
        while tick < to_s:
            error = self.trigger.check_watchdog(tick)
            if error != self.no_error:
                return TriggerEvent(tick, False, error)
            self.last_tick_s = tick
            tick += self.period_s
        return None
