"""The force guard of `[load_cell_probe]`: how fast a move toward the bed may go.

Before a probing move (and for the nozzle watch's speed cap) the guard predicts how hard the
nozzle could press at a speed (`safety.worst_stop`: the firmware trigger itself on ideal contact
ramps) on the stiffest bed it must assume: the stiffest valid kept tap's stiffness with a margin,
else `max_bed_stiffness` (100 g/um by default). A speed past [printer] max_z_velocity is capped (said once
per command). A speed that could press past force_safety_limit is refused with the safe speed once taps
have measured the bed; before that, the move goes at the speed that is safe on the stiffest bed the config
allows (said once per command), so the first tap of a fresh printer measures its bed slowly instead of
being refused.
"""

from __future__ import annotations

from collections.abc import Callable

from tapcell.extras.load_cell_probe import safety
from tapcell.extras.load_cell_probe.options import ERROR_PREFIX
from tapcell.extras.probe.session import ProbeError
from tapcell.mcu.trigger import TriggerParams


class SpeedGuard:
    """Speed checks against the worst-case stop (see the module docstring)."""

    def __init__(self, stop_timing: safety.StopTiming, max_z_velocity_mm_s: Callable[[], float],
                 known_stiffness_g_um: Callable[[], float | None], respond_info: Callable[[str], None],
                 max_bed_stiffness_g_um: float = safety.DEFAULT_STIFFNESS_G_UM):
        self.stop_timing = stop_timing
        self.max_bed_stiffness_g_um = max_bed_stiffness_g_um  # assumed until taps measure the bed
        self._max_z_velocity_mm_s = max_z_velocity_mm_s
        self._known_stiffness_g_um = known_stiffness_g_um
        self._respond_info = respond_info
        self._notes: set[tuple] = set()  # the speed notes given in this command

    def new_command(self) -> None:
        """A probing command starts: its speed notes are given once again."""
        self._notes.clear()

    def assumed_stiffness_g_um(self) -> tuple[float, bool]:
        """(stiffness the guard assumes, whether taps measured it): the stiffest bed the taps measured
        with a margin, else max_bed_stiffness."""
        measured = self._known_stiffness_g_um()
        if measured is None:
            return self.max_bed_stiffness_g_um, False
        return measured * safety.MEASURED_STIFFNESS_MARGIN, True

    def _note_once(self, key: tuple, message: str) -> None:
        if key not in self._notes:
            self._notes.add(key)
            self._respond_info(message)

    def check(self, params: TriggerParams, speed_mm_s: float) -> float:
        """The probing speed capped by max_z_velocity; ProbeError (why, and the safe speed) when it
        could press harder than force_safety_limit."""
        max_z_mm_s = self._max_z_velocity_mm_s()
        if speed_mm_s > max_z_mm_s:
            self._note_once((speed_mm_s, max_z_mm_s), f"Probing speed {speed_mm_s:g} mm/s is above [printer] "
                                                      f"max_z_velocity ({max_z_mm_s:g} mm/s): probing at {max_z_mm_s:g} mm/s")
            speed_mm_s = max_z_mm_s
        stiffness_g_um, measured = self.assumed_stiffness_g_um()
        prediction = safety.worst_stop(params, self.stop_timing, speed_mm_s, stiffness_g_um)
        if safety.exceeds_limit(prediction, params.force_safety_limit_g):
            slower = safety.safe_speed_mm_s(params, self.stop_timing, speed_mm_s, stiffness_g_um)
            if not measured and slower is not None:
                self._note_once(("unmeasured", speed_mm_s, slower),
                                f"Probing at {slower:g} mm/s, not {speed_mm_s:g} mm/s, until a tap measures the bed: "
                                f"up to {stiffness_g_um:g} g/um is assumed before that (max_bed_stiffness)")
                return slower
            raise ProbeError(ERROR_PREFIX + safety.speed_refusal(params, self.stop_timing, speed_mm_s, prediction,
                                                                 stiffness_g_um, measured, slower))
        return speed_mm_s

    def fastest_safe_mm_s(self, params: TriggerParams, up_to_mm_s: float) -> float | None:
        """`up_to_mm_s` when the guard passes it, else the fastest safe speed below (None: none)."""
        stiffness_g_um, _ = self.assumed_stiffness_g_um()
        prediction = safety.worst_stop(params, self.stop_timing, up_to_mm_s, stiffness_g_um)
        if not safety.exceeds_limit(prediction, params.force_safety_limit_g):
            return up_to_mm_s
        return safety.safe_speed_mm_s(params, self.stop_timing, up_to_mm_s, stiffness_g_um)
