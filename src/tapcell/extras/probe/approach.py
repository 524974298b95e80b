"""Where a probing move starts and where it must give up, from the bed height the probe expects.

Two rules around every tap (pure arithmetic; the load-cell probe applies them):

* **Room to reach the speed.** The tap analysis needs the probing move at its cruise speed when
  the nozzle meets the bed (a move still accelerating is COASTING_MOVE_ACCELERATION). A probe
  that starts closer than the distance the Z axis needs to reach that speed, plus a margin,
  lifts first: e.g. PROBE_ACCURACY PROBE_SPEED=10 right after another PROBE_ACCURACY, which
  ended at the top of its last pullback (0.15 mm up; 10 mm/s at 200 mm/s² needs 0.25 mm).
* **No contact, stop** (the ABL paper): no contact by 2 mm below the expected bed height is an
  error, not a reason to drive on to the end of the axis.

The expected bed height at X, Y: the nearest contact this probe made since Z was homed when it
is within NEAR_CONTACT_MM, else the active bed mesh there, else the nearest contact anywhere,
else 0 (homing puts the bed at Z 0).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

NO_CONTACT_DEPTH_MM = 2.0  # the paper: no hit by 2 mm below the bed -> error
NEAR_CONTACT_MM = 10.0
# Beyond the distance to reach the speed: this many samples of cruise before contact, plus
# this much for a bed higher than expected (a tilt between points, a hotter, longer nozzle).
CRUISE_SAMPLES = 4
BED_UNCERTAINTY_MM = 0.1
# Enough for any mesh (a 15 x 15 mesh with retries); older contacts are dropped, so the memory
# stays the same size over a long session.
MAX_CONTACTS = 512


def acceleration_distance_mm(speed_mm_s: float, accel_mm_s2: float) -> float:
    """Distance to reach `speed` from rest at `accel`."""
    return speed_mm_s * speed_mm_s / (2.0 * accel_mm_s2)


def approach_height_mm(speed_mm_s: float, accel_mm_s2: float, sample_rate_sps: float) -> float:
    """How far above the expected bed a probing move must start to meet it at cruise speed."""
    return (acceleration_distance_mm(speed_mm_s, accel_mm_s2) + CRUISE_SAMPLES * speed_mm_s / sample_rate_sps
            + BED_UNCERTAINTY_MM)


def no_contact_message(z_min_mm: float, expected_z_mm: float) -> str:
    """The error when the probing move found no bed by NO_CONTACT_DEPTH_MM below the expected one."""
    return (f"no contact down to Z={z_min_mm:.3f}, {NO_CONTACT_DEPTH_MM:g} mm below the expected bed height "
            f"{expected_z_mm:.3f}: probing stopped there. Likely cause: the nozzle is not over the bed, the bed or "
            "sheet is missing, or Z was homed at another height. Fix: check the bed under the nozzle and home Z "
            "again (G28 Z), then probe")


class BedHeightMemory:
    """The contacts a probe made since Z was homed, and the bed height it expects from them."""

    def __init__(self, mesh_height_mm: Callable[[float, float], float | None]):
        self._mesh_height_mm = mesh_height_mm  # the active bed mesh at (x, y), None without one
        self.contacts_xyz_mm = np.zeros((0, 3))

    def forget(self) -> None:
        """Z was homed again: the contacts were measured in another frame."""
        self.contacts_xyz_mm = np.zeros((0, 3))

    def remember(self, x_mm: float, y_mm: float, z_mm: float) -> None:
        kept = self.contacts_xyz_mm[-(MAX_CONTACTS - 1):]
        self.contacts_xyz_mm = np.vstack([kept, [(float(x_mm), float(y_mm), float(z_mm))]])

    def expected_z_mm(self, x_mm: float, y_mm: float) -> float:
        contacts = self.contacts_xyz_mm
        if len(contacts):
            distances = np.hypot(contacts[:, 0] - x_mm, contacts[:, 1] - y_mm)
            nearest = int(np.argmin(distances))
            if distances[nearest] <= NEAR_CONTACT_MM:
                return float(contacts[nearest, 2])
        mesh_z = self._mesh_height_mm(x_mm, y_mm)
        if mesh_z is not None:
            return mesh_z
        return float(contacts[nearest, 2]) if len(contacts) else 0.0
