"""`[pause_resume]`: PAUSE, RESUME, CLEAR_PAUSE and CANCEL_PRINT (status `pause_resume`).

PAUSE keeps the G-code state (SAVE_GCODE_STATE NAME=PAUSE_STATE); RESUME goes back to it at
recover_velocity (RESTORE_GCODE_STATE ... MOVE=1). A file printing from [virtual_sdcard] stops,
goes on and is cancelled with them (the events "pause_resume:pause", ":resume", ":cancel");
Mainsail's PAUSE/RESUME/CANCEL_PRINT macros rename these and build on them.
"""

from __future__ import annotations

from tapcell.host.config import ConfigSection
from tapcell.host.gcode import GCodeCommand
from tapcell.host.limits import SPEED_RANGE

PAUSE_STATE = "PAUSE_STATE"


class PauseResume:
    def __init__(self, printer, recover_velocity_mm_s: float):
        self.printer = printer
        self.recover_velocity_mm_s = recover_velocity_mm_s
        self.is_paused = False

    def cmd_PAUSE(self, gcmd: GCodeCommand) -> None:
        if self.is_paused:
            gcmd.respond_info("Print already paused")
            return
        self.printer.gcode.run_script(f"SAVE_GCODE_STATE NAME={PAUSE_STATE}")
        self.is_paused = True
        self.printer.send_event("pause_resume:pause")  # a file printing stops feeding (virtual_sdcard)

    def cmd_RESUME(self, gcmd: GCodeCommand) -> None:
        velocity = gcmd.get_float("VELOCITY", self.recover_velocity_mm_s, **SPEED_RANGE)
        if not self.is_paused:
            gcmd.respond_info("Print is not paused, resume aborted")
            return
        self.printer.gcode.run_script(f"RESTORE_GCODE_STATE NAME={PAUSE_STATE} MOVE=1 MOVE_SPEED={velocity:g}")
        self.is_paused = False
        self.printer.send_event("pause_resume:resume")

    def cmd_CLEAR_PAUSE(self, gcmd: GCodeCommand) -> None:
        self.is_paused = False

    def cmd_CANCEL_PRINT(self, gcmd: GCodeCommand) -> None:
        self.is_paused = False
        self.printer.send_event("pause_resume:cancel")

    def get_status(self, eventtime=None) -> dict:
        return {"is_paused": self.is_paused}


COMMANDS = {
    "PAUSE": "Pause: keep the G-code state to resume from",
    "RESUME": "Resume from a pause: back to the kept position [VELOCITY=mm/s]",
    "CLEAR_PAUSE": "Forget a pause without moving",
    "CANCEL_PRINT": "Cancel the print (clears a pause)",
}


def load_config(section: ConfigSection, printer) -> PauseResume:
    pause = PauseResume(printer, section.getfloat("recover_velocity", 50.0, **SPEED_RANGE))
    for name, desc in COMMANDS.items():
        printer.gcode.register_command(name, getattr(pause, f"cmd_{name}"), desc=desc)
    return pause
