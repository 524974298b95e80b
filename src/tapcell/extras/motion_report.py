"""`motion_report`: where the toolhead is right now (Klipper's status object; always loaded).

Mainsail and Fluidd show `live_position` and `live_velocity` as the toolhead's position and
speed. They are read off the virtual printer's motion history at the estimated print time
(`Printer.estimated_print_time`): behind `tapcell serve` a G1 plays out over its real duration,
so the position moves during the move and ends where the move ends. The extruder has no motor
on the virtual printer: `live_extruder_velocity` is 0 and E is the commanded position.
"""

from __future__ import annotations

from tapcell.host.config import ConfigSection

STEPPERS = ["stepper_x", "stepper_y", "stepper_z", "extruder"]
TRAPQ = ["toolhead", "extruder"]


class MotionReport:
    def __init__(self, printer, toolhead):
        self.printer = printer
        self.toolhead = toolhead

    def live_position(self) -> list[float]:
        """X, Y, Z in the toolhead frame at the estimated print time, and the commanded E."""
        backend = self.printer.backend
        t_s = self.printer.estimated_print_time()
        machine = backend.position_at(t_s)
        offsets = self.toolhead.frame_offset_mm
        return [float(machine[i]) + offsets[axis] for i, axis in enumerate("xyz")] + [self.toolhead.e_position_mm]

    def get_status(self, eventtime=None) -> dict:
        return {
            "live_position": self.live_position(),
            "live_velocity": float(self.printer.backend.speed_at(self.printer.estimated_print_time())),
            "live_extruder_velocity": 0.0,
            "steppers": list(STEPPERS),
            "trapq": list(TRAPQ),
        }


def load_config(section: ConfigSection, printer) -> MotionReport | None:
    toolhead = printer.lookup_object("toolhead", None)
    if toolhead is None or not hasattr(printer.backend, "position_at"):
        return None
    return MotionReport(printer, toolhead)
