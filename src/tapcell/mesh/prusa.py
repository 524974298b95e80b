"""Prusa-matched probing: thresholds, the context-dependent tare plan, the reference-tare check.

Numbers from Prusa's firmware as recorded in the spec (prusa-thresholds.md):

* trigger thresholds (grams of compression): Z fast 125, Z slow 125, mesh 125, XY 40;
  the Z triggers release 80 g (hysteresis) below the threshold, i.e. at 45 g;
* a tare waits 300 ms for vibrations to settle, then averages 48 samples (150 ms at 320 Hz);
* Z homing (a standalone probe) tares twice; a mesh tares once for the session reference
  and once per point: 1 + N tares for N points (a 3x3 mesh: 10, not the 19 of tare-twice);
* at each mesh point the new tare is compared with the session reference: more than 125 g
  apart means something pulls on the nozzle (filament, debris), so lift 20 mm and re-tare;
* a mesh point is tried at most 40 times (MULTIPLE_PROBING), on rings 2 mm apart.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from tapcell.mesh.errors import MeshError

Z_FAST = "z_fast"
Z_SLOW = "z_slow"
MESH = "mesh"
XY = "xy"
# The G-code command that sets each threshold (each takes VALUE=<grams>).
SET_COMMANDS = {
    Z_FAST: "SET_Z_FAST_THRESHOLD",
    Z_SLOW: "SET_Z_SLOW_THRESHOLD",
    MESH: "SET_MESH_THRESHOLD",
    XY: "SET_XY_THRESHOLD",
}
# Above the load cell probe's default drift_safety_limit the probe errors before triggering.
MAX_THRESHOLD_G = 1000.0

TARE_SETTLE_S = 0.300
TARE_SAMPLE_COUNT = 48
TARE_SAMPLE_RATE_HZ = 320.0
REFERENCE_DEVIATION_LIMIT_G = 125.0
DEVIATION_LIFT_MM = 20.0
MAX_PROBE_ATTEMPTS = 40
RETRY_RING_SPACING_MM = 2.0


@dataclass(frozen=True)
class Thresholds:
    """Trigger thresholds in grams (compression magnitude) and the Z hysteresis."""

    z_fast_g: float = 125.0
    z_slow_g: float = 125.0
    mesh_g: float = 125.0
    xy_g: float = 40.0
    hysteresis_g: float = 80.0

    def value_g(self, kind: str) -> float:
        return getattr(self, f"{_checked_kind(kind)}_g")

    def release_g(self, kind: str) -> float:
        """Load below which a triggered probe releases: threshold - hysteresis for Z and mesh,
        half the threshold for XY (Prusa releases XY at 20 g of 40)."""
        if _checked_kind(kind) == XY:
            return self.xy_g / 2.0
        return self.value_g(kind) - self.hysteresis_g

    def with_threshold(self, kind: str, value_g: float) -> Thresholds:
        """A copy with one threshold changed, checked as its SET_..._THRESHOLD VALUE= parameter."""
        command = SET_COMMANDS[_checked_kind(kind)]
        if not (isinstance(value_g, (int, float)) and math.isfinite(value_g) and 0 < value_g <= MAX_THRESHOLD_G):
            raise MeshError(f"{command} VALUE={value_g}: must be a number of grams above 0 and at most {MAX_THRESHOLD_G:g}")
        if kind != XY and value_g <= self.hysteresis_g:
            raise MeshError(
                f"{command} VALUE={value_g:g}: must be above the hysteresis ({self.hysteresis_g:g} g), "
                "or the trigger would never release with the nozzle at rest"
            )
        return replace(self, **{f"{kind}_g": float(value_g)})

    def to_status(self) -> dict:
        return {
            "z_fast_g": self.z_fast_g,
            "z_slow_g": self.z_slow_g,
            "mesh_g": self.mesh_g,
            "xy_g": self.xy_g,
            "hysteresis_g": self.hysteresis_g,
        }


def _checked_kind(kind: str) -> str:
    if kind not in SET_COMMANDS:
        raise MeshError(f"unknown threshold '{kind}': must be one of " + ", ".join(SET_COMMANDS))
    return kind


@dataclass(frozen=True)
class Tare:
    """One tare: wait settle_s, then average sample_count samples."""

    purpose: str
    settle_s: float = TARE_SETTLE_S
    sample_count: int = TARE_SAMPLE_COUNT

    @property
    def duration_s(self) -> float:
        return self.settle_s + self.sample_count / TARE_SAMPLE_RATE_HZ


def z_home_tares() -> tuple[Tare, ...]:
    """Z homing (or a standalone probe): two tares back to back for the best zero."""
    return (Tare("z home, first tare"), Tare("z home, second tare"))


def mesh_tares(point_count: int) -> tuple[Tare, ...]:
    """A mesh: one session reference tare, then a single tare at each point."""
    if not isinstance(point_count, int) or point_count < 1:
        raise MeshError(f"mesh tare plan: point count {point_count} must be a positive integer")
    return (Tare("session reference"), *(Tare(f"mesh point {n}") for n in range(1, point_count + 1)))


@dataclass(frozen=True)
class TareCheck:
    """Decision after a mesh-point tare. action: "accept" or "lift_and_retare"."""

    action: str
    deviation_g: float
    lift_mm: float

    def to_status(self) -> dict:
        return {"action": self.action, "deviation_g": self.deviation_g, "lift_mm": self.lift_mm}


def check_tare_deviation(
    tare_g: float,
    reference_tare_g: float,
    limit_g: float = REFERENCE_DEVIATION_LIMIT_G,
    lift_mm: float = DEVIATION_LIFT_MM,
) -> TareCheck:
    """Compare a point's tare with the session reference (both in grams).

    More than `limit_g` apart: lift `lift_mm` and re-tare (the new tare becomes the
    reference); otherwise accept the tare.
    """
    deviation_g = float(tare_g - reference_tare_g)
    if abs(deviation_g) > limit_g:
        return TareCheck("lift_and_retare", deviation_g, lift_mm)
    return TareCheck("accept", deviation_g, 0.0)


def retry_offsets_mm(attempts: int = MAX_PROBE_ATTEMPTS) -> np.ndarray:
    """(attempts, 2) X, Y offsets from the point for each attempt, Prusa's spiral of rings.

    Ring k has radius 2k mm and floor(2 pi r / 2) + 1 evenly spaced positions
    (1, 7, 13, 19, ...), so 40 attempts stay within 6 mm of the point.
    """
    if not isinstance(attempts, int) or not 1 <= attempts <= MAX_PROBE_ATTEMPTS:
        raise MeshError(f"retry attempts {attempts}: must be an integer from 1 to {MAX_PROBE_ATTEMPTS}")
    offsets = []
    ring = 0
    while len(offsets) < attempts:
        radius_mm = RETRY_RING_SPACING_MM * ring
        count = math.floor(2 * math.pi * radius_mm / RETRY_RING_SPACING_MM) + 1
        angles = 2 * math.pi * np.arange(count) / count
        offsets.extend(zip(radius_mm * np.cos(angles), radius_mm * np.sin(angles)))
        ring += 1
    return np.array(offsets[:attempts])
