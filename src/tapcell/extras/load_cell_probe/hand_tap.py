"""LOAD_CELL_TEST_TAP's check of one tap by hand: did the cell see a clean press and release?

A tap by hand has no motion, so the tap analysis (lines fitted against the probing move and
the pullback) does not apply. What can be checked, in the guide's terms:

* the sensor reported no errors while the tap was recorded (wiring, grounding);
* the tap lasted long enough for the sensor to show its shape (MIN_PRESSED_SAMPLES samples
  above half the trigger force);
* the force came back where it started: BASELINE_FORCE_INCONSISTENT when the force after the
  release differs from the tare by more than `max_baseline_force_delta` percent of the peak
  (the guide's baseline component: drift from a bowden tube or cable chain, or something still
  pressing the nozzle).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

BASELINE_FORCE_INCONSISTENT = "BASELINE_FORCE_INCONSISTENT"
MIN_PRESSED_SAMPLES = 3


@dataclass(frozen=True)
class HandTap:
    peak_g: float
    after_g: float  # the force once released (median of the settled samples)
    pressed_samples: int
    problem: str | None  # None: a clean tap

    def describe(self) -> str:
        summary = f"peak {self.peak_g:.0f}g, back to {self.after_g:.1f}g"
        return f"{summary}: good" if self.problem is None else f"{summary}: bad tap: {self.problem}"


def check_hand_tap(force_g: np.ndarray, after_g: float, trigger_force_g: float, max_baseline_force_delta: float,
                   sensor_errors: int) -> HandTap:
    """`force_g`: the tared force from arming to the release; `after_g`: the force once settled."""
    force_g = np.asarray(force_g, dtype=float)
    peak_g = float(np.max(np.abs(force_g))) if len(force_g) else 0.0
    pressed = int(np.count_nonzero(np.abs(force_g) >= 0.5 * trigger_force_g))
    problem = None
    if sensor_errors:
        problem = (f"the sensor reported {sensor_errors} errors during the tap. Likely cause: wiring or grounding. "
                   "Fix: check the cable and ground the frame, power supply and bed (the guide's Grounding section)")
    elif pressed < MIN_PRESSED_SAMPLES:
        problem = (f"the tap lasted {pressed} samples above half the trigger force, too short to show its shape. "
                   "Fix: press a little longer (about a tenth of a second)")
    elif abs(after_g) > max_baseline_force_delta / 100.0 * peak_g:
        problem = (f"{BASELINE_FORCE_INCONSISTENT} - the force came back to {after_g:.1f}g, "
                   f"{abs(after_g) / peak_g:.0%} of the {peak_g:.0f}g peak (max_baseline_force_delta "
                   f"{max_baseline_force_delta:g}%). Likely cause: drift from the bowden tube or cable chain, or "
                   "something still presses the nozzle. Fix: free the nozzle; against drift set "
                   "drift_filter_cutoff_frequency (start at 0.5)")
    return HandTap(peak_g, float(after_g), pressed, problem)
