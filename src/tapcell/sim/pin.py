"""A calibration pin: a vertical metal cylinder standing on the bed (XY probing, tool offsets).

Two ways the nozzle meets it:

* from above: inside the pin's radius the surface is the pin's flat top (`surface_z`), so a
  Z probe over the pin finds its height through the normal contact physics;
* from the side: with the nozzle tip below the top, the tip (a cylinder of
  `nozzle_tip_diameter`) presses into the pin's side. The toolhead deflects sideways with
  `side_stiffness` g/µm and the load cell, built to measure vertical force, sees only the
  share `side_coupling` of that force (its flexure is not perfectly decoupled). That share is
  what an XY probe triggers on (Prusa: 40 g).

Only tests and benchmarks may know where the pin is (it is part of the truth); the host
finds it by probing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class CalibrationPin:
    x_mm: float
    y_mm: float
    diameter_mm: float
    height_mm: float  # above the bed surface at the pin
    nozzle_tip_diameter_mm: float
    side_stiffness_g_um: float
    side_coupling: float

    def _distance_mm(self, x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
        return np.hypot(np.asarray(x_mm, dtype=float) - self.x_mm, np.asarray(y_mm, dtype=float) - self.y_mm)

    def surface_z(self, x_mm: np.ndarray, y_mm: np.ndarray, bed_z_mm: np.ndarray, bed_at_pin_mm: float) -> np.ndarray:
        """The surface the nozzle meets from above: the pin's top inside its radius, else the bed."""
        on_top = self._distance_mm(x_mm, y_mm) <= self.diameter_mm / 2.0
        return np.where(on_top, np.maximum(bed_z_mm, bed_at_pin_mm + self.height_mm), bed_z_mm)

    def side_force_g(self, x_mm: np.ndarray, y_mm: np.ndarray, tip_z_mm: np.ndarray, bed_at_pin_mm: float) -> np.ndarray:
        """The sideways force between the nozzle and the pin's side (0 when clear): what presses on
        the pin and the toolhead (the load cell reads `side_coupling` of it)."""
        distance_mm = self._distance_mm(x_mm, y_mm)
        interference_um = ((self.diameter_mm + self.nozzle_tip_diameter_mm) / 2.0 - distance_mm) * 1000.0
        beside = np.asarray(tip_z_mm, dtype=float) < bed_at_pin_mm + self.height_mm
        # With its centre inside the pin's radius the nozzle is on top of it (surface_z), not beside it.
        pressing = beside & (interference_um > 0.0) & (distance_mm > self.diameter_mm / 2.0)
        return np.where(pressing, self.side_stiffness_g_um * interference_um, 0.0)


def pin_from_params(params) -> CalibrationPin | None:
    if params.pin_diameter_mm <= 0.0:
        return None
    return CalibrationPin(params.pin_x_mm, params.pin_y_mm, params.pin_diameter_mm, params.pin_height_mm,
                          params.nozzle_tip_diameter_mm, params.pin_side_stiffness_g_um, params.pin_side_coupling)
