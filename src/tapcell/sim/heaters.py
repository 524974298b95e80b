"""First-order heaters of the virtual printer (nozzle, bed, any [heater_generic]) and its recorded outputs.

A heater's temperature approaches its set point exponentially with time constant `tau_s`
(a first-order thermal plant under ideal control). A heater cannot cool: a set point
below the room (0 = off) lets it fall back to the room temperature. Fans and output pins
are recorded, with the time each value was set, for tests and the console to read back.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


@dataclass
class FirstOrderHeater:
    ambient_c: float
    tau_s: float
    temp_at_ref_c: float
    ref_time_s: float = 0.0
    target_c: float | None = None   # the set point the temperature approaches (never below ambient)

    def __post_init__(self):
        if self.target_c is None:
            self.target_c = self.temp_at_ref_c

    def temps_at(self, t_s) -> np.ndarray:
        """Temperature approaches the set point exponentially from the last change."""
        age = np.maximum(np.asarray(t_s, dtype=float) - self.ref_time_s, 0.0)
        return self.target_c + (self.temp_at_ref_c - self.target_c) * np.exp(-age / self.tau_s)

    def set_target(self, now_s: float, target_c: float) -> None:
        self.temp_at_ref_c = float(self.temps_at(now_s))
        self.ref_time_s = now_s
        self.target_c = max(float(target_c), self.ambient_c)

    def time_to_settle_s(self, now_s: float, within_c: float = 1.0) -> float:
        """How long until the temperature is within `within_c` of the set point."""
        error = abs(float(self.temps_at(now_s)) - self.target_c)
        return 0.0 if error <= within_c else self.tau_s * math.log(error / within_c)


@dataclass
class OutputLog:
    """Every value set on a fan or pin: name -> [(time_s, value), ...] in order."""

    changes: dict[str, list[tuple[float, float]]] = field(default_factory=dict)

    def set(self, name: str, t_s: float, value: float) -> None:
        self.changes.setdefault(name, []).append((float(t_s), float(value)))

    def value(self, name: str) -> float:
        """The last value set (0 when never set)."""
        history = self.changes.get(name)
        return history[-1][1] if history else 0.0
