"""Nozzle temperature (first-order heater), its thermal growth, and the cell's warming."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass
class NozzleThermal:
    ambient_c: float
    heater_tau_s: float
    expansion_um_per_c: float
    temp_at_ref_c: float
    ref_time_s: float = 0.0
    target_c: float | None = None

    def __post_init__(self):
        if self.target_c is None:
            self.target_c = self.temp_at_ref_c

    def temps_at(self, t_s) -> np.ndarray:
        """Temperature approaches the target exponentially from the last set point."""
        age = np.maximum(np.asarray(t_s, dtype=float) - self.ref_time_s, 0.0)
        return self.target_c + (self.temp_at_ref_c - self.target_c) * np.exp(-age / self.heater_tau_s)

    def set_target(self, now_s: float, target_c: float) -> None:
        self.temp_at_ref_c = float(self.temps_at(now_s))
        self.ref_time_s = now_s
        self.target_c = target_c

    def time_to_settle_s(self, now_s: float, within_c: float = 1.0) -> float:
        """How long until the temperature is within `within_c` of the target."""
        error = abs(float(self.temps_at(now_s)) - self.target_c)
        return 0.0 if error <= within_c else self.heater_tau_s * math.log(error / within_c)

    def extension_mm(self, temps_c) -> np.ndarray:
        """The nozzle grows toward the bed as it heats: the tip sits lower for the same commanded Z."""
        return (np.asarray(temps_c) - self.ambient_c) * self.expansion_um_per_c * 1e-3
