"""`[display_status]` (also loaded by `[display]`): M117 and M73, status `display_status`."""

from __future__ import annotations

from tapcell.host.config import ConfigSection
from tapcell.host.gcode import GCodeCommand


class DisplayStatus:
    """`progress` is the last M73 P, else (no M73 yet) the file's progress of [virtual_sdcard]."""

    def __init__(self, printer=None):
        self.printer = printer
        self.message: str | None = None
        self.progress = 0.0
        self.progress_from_m73 = False

    def cmd_M117(self, gcmd: GCodeCommand) -> None:
        self.message = gcmd.rawparams or None

    def cmd_M73(self, gcmd: GCodeCommand) -> None:
        percent = gcmd.get_float("P", None, minval=0.0, maxval=100.0)
        for ignored in ("R", "Q", "S"):  # remaining time and the silent-mode values slicers add
            gcmd.get(ignored, None)
        if percent is not None:
            self.progress = percent / 100.0
            self.progress_from_m73 = True

    def get_status(self, eventtime=None) -> dict:
        progress = self.progress
        sdcard = None if self.printer is None else self.printer.lookup_object("virtual_sdcard", None)
        if not self.progress_from_m73 and sdcard is not None:
            progress = sdcard.get_status()["progress"]
        return {"progress": progress, "message": self.message}


def load_display_status(printer) -> DisplayStatus:
    """The one `display_status` object ([display] and [display_status] share it)."""
    status = printer.lookup_object("display_status", None)
    if status is None:
        status = DisplayStatus(printer)
        printer.add_object("display_status", status)
        printer.gcode.register_command("M117", status.cmd_M117, desc="Show a message: M117 <text>")
        printer.gcode.register_command("M73", status.cmd_M73, desc="Set the print progress: M73 P<percent>")
    return status


def load_config(section: ConfigSection, printer) -> None:
    load_display_status(printer)
    return None
