"""Nozzle temperature (a first-order heater) and its thermal growth toward the bed."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tapcell.sim.heaters import FirstOrderHeater


@dataclass
class NozzleThermal(FirstOrderHeater):
    expansion_um_per_c: float = 0.0

    def extension_mm(self, temps_c) -> np.ndarray:
        """The nozzle grows toward the bed as it heats: the tip sits lower for the same commanded Z."""
        return (np.asarray(temps_c) - self.ambient_c) * self.expansion_um_per_c * 1e-3
