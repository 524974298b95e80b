"""The load-cell ADC of the independent tap generator: what a force history becomes as samples.

* Each conversion averages the input over its window: one period for the HX71x (a boxcar),
  three periods for the ADS1220's sinc3 filter (a quadratic spline kernel, group delay 1.5 periods).
* The converter runs on its own oscillator (a few per cent off nominal); a sample is stamped when
  it is read, `latency` periods after its conversion ended, with a little timestamp jitter.
* Electrical noise at the output: white and 1/f. Mains hum (with harmonics), cable drift and the
  thermal random walk are inputs and pass through the conversion window like the force.
* Corrupted frames: a few samples replaced by garbage (a bit flip high in the word, or a channel
  reading all ones), as long leads do.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SUBSAMPLES = 16  # fine-grid steps per conversion period


@dataclass(frozen=True)
class Adc:
    kind: str  # "hx711", "hx717", "ads1220"
    nominal_sps: float
    clock_error: float  # actual rate = nominal * (1 + clock_error)
    latency_periods: float  # read (and stamped) this long after the conversion ended
    jitter_s: float  # 1 sigma of the timestamp jitter
    white_g: float  # white noise at the output, 1 sigma
    pink_g: float  # 1/f noise at the output, rms over the tap
    counts_per_gram: float

    @property
    def period_s(self) -> float:
        return 1.0 / (self.nominal_sps * (1.0 + self.clock_error))

    @property
    def window_periods(self) -> int:
        return 3 if self.kind == "ads1220" else 1


def conversion_kernel(adc: Adc) -> np.ndarray:
    """Weights over the fine grid, newest last, summing to 1."""
    box = np.full(SUBSAMPLES, 1.0 / SUBSAMPLES)
    kernel = box
    for _ in range(adc.window_periods - 1):
        kernel = np.convolve(kernel, box)
    return kernel / kernel.sum()


def convert(fine_input_g: np.ndarray, adc: Adc) -> np.ndarray:
    """Samples from an input on the fine grid (SUBSAMPLES per period, conversion ends on the grid).

    Sample i is the window ending at fine index (i + window) * SUBSAMPLES - 1: the fine grid starts
    one full window before the first conversion ends.
    """
    kernel = conversion_kernel(adc)
    averaged = np.convolve(fine_input_g, kernel, mode="valid")  # entry j: window ending at fine index j + len - 1
    first = SUBSAMPLES * adc.window_periods - len(kernel)
    return averaged[first::SUBSAMPLES]


def pink_noise(count: int, rms_g: float, rng: np.random.Generator) -> np.ndarray:
    """1/f noise (power ~ 1/f) over `count` samples, scaled to the given rms."""
    if rms_g <= 0 or count < 4:
        return np.zeros(count)
    spectrum = rng.normal(size=count // 2 + 1) + 1j * rng.normal(size=count // 2 + 1)
    f = np.arange(count // 2 + 1, dtype=float)
    f[0] = 1.0
    spectrum /= np.sqrt(f)
    spectrum[0] = 0.0
    noise = np.fft.irfft(spectrum, n=count)
    return noise * (rms_g / max(float(noise.std()), 1e-12))


def corrupt_frames(force_g: np.ndarray, count: int, adc: Adc, rng: np.random.Generator) -> list[int]:
    """Replace `count` samples by garbage in place; returns their indices."""
    indices = sorted(int(i) for i in rng.choice(np.arange(2, len(force_g) - 2), size=count, replace=False))
    for i in indices:
        if rng.random() < 0.5:
            bit = int(rng.integers(14, 23))
            force_g[i] += float(rng.choice((-1.0, 1.0))) * (1 << bit) / adc.counts_per_gram
        else:  # a channel reading all ones: -1 counts against a tare of some 10^5 counts
            force_g[i] = -float(rng.uniform(5e4, 5e5)) / adc.counts_per_gram
    return indices
