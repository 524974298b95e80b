"""`[idle_timeout]`: Klipper's activity state, and its G-code after `timeout` idle seconds.

Always loaded (Mainsail and Fluidd read `idle_timeout.state`); the section only changes its
options. Status: `state` is "Printing" while queued moves still play or a file prints, "Ready"
once the printer has nothing left to do, "Idle" at start and after the timeout's G-code ran;
`printing_time` counts the seconds of the current Printing stretch.

Activity is read off the print clock (tapcell.host.print_clock), so behind `tapcell serve` a
move keeps the state at Printing for as long as it plays and the timeout counts from the end of
the last move. The live server checks the timeout between scripts. Without one (`tapcell run`,
the console) nothing runs unasked: the state is Printing while a file prints, else Idle.

Commands: SET_IDLE_TIMEOUT [TIMEOUT=seconds].
"""

from __future__ import annotations

from tapcell.host.config import ConfigSection
from tapcell.host.gcode import GCodeCommand, GCodeError
from tapcell.host.templates import ENVIRONMENT, GCodeTemplate, StatusView, compile_template

DEFAULT_TIMEOUT_S = 600.0
MAX_TIMEOUT_S = 7 * 24 * 3600.0
# Klipper's default: heaters off (when there are any), then motors off.
DEFAULT_GCODE = "{% if 'heaters' in printer %}\nTURN_OFF_HEATERS\n{% endif %}\nM84\n"


class IdleTimeout:
    def __init__(self, printer, timeout_s: float, template: GCodeTemplate):
        self.printer = printer
        self.timeout_s = timeout_s
        self.template = template
        self.timed_out_after_s: float | None = None  # the activity end the timeout G-code ran for

    def _printing_file(self) -> bool:
        sdcard = self.printer.lookup_object("virtual_sdcard", None)
        return bool(sdcard is not None and sdcard.is_active())

    def state(self) -> str:
        clock = self.printer.print_clock
        if self._printing_file() or (clock is not None and clock.is_busy()):
            return "Printing"
        if clock is None or clock.last_busy_end_s is None or clock.last_busy_end_s == self.timed_out_after_s:
            return "Idle"
        return "Ready"

    def update(self) -> None:
        """Run the timeout G-code once the printer has been Ready for `timeout` seconds."""
        clock = self.printer.print_clock
        if self.state() != "Ready" or clock.estimated_s - clock.last_busy_end_s < self.timeout_s:
            return
        self.timed_out_after_s = clock.last_busy_end_s
        try:
            self.printer.gcode.run_script(self.template.render({"printer": StatusView(self.printer)}))
        except GCodeError as exc:
            self.printer.gcode.respond_error(f"idle timeout G-code failed: {exc}")

    def cmd_SET_IDLE_TIMEOUT(self, gcmd: GCodeCommand) -> None:
        timeout_s = gcmd.get_float("TIMEOUT", None, above=0.0, maxval=MAX_TIMEOUT_S)
        if timeout_s is not None:
            self.timeout_s = timeout_s
            gcmd.respond_info(f"idle_timeout: Timeout set to {timeout_s:.2f} s")
        else:
            gcmd.respond_info(f"idle_timeout: Timeout is {self.timeout_s:.2f} s")

    def get_status(self, eventtime=None) -> dict:
        state = self.state()
        clock = self.printer.print_clock
        printing_s = 0.0
        if state == "Printing" and clock is not None and clock.busy_since_s is not None:
            printing_s = max(0.0, clock.estimated_s - clock.busy_since_s)
        return {"state": state, "printing_time": printing_s}


def load_config(section: ConfigSection, printer) -> IdleTimeout:
    timeout_s = section.getfloat("timeout", DEFAULT_TIMEOUT_S, above=0.0, maxval=MAX_TIMEOUT_S)
    if section.has_option("gcode"):
        template = compile_template(section, "gcode", "idle_timeout gcode")
    else:
        template = GCodeTemplate(ENVIRONMENT.from_string(DEFAULT_GCODE), "idle_timeout gcode")
    idle = IdleTimeout(printer, timeout_s, template)
    printer.gcode.register_command("SET_IDLE_TIMEOUT", idle.cmd_SET_IDLE_TIMEOUT,
                                   desc="Set the idle timeout: [TIMEOUT=seconds]")
    printer.register_background(idle.update)
    return idle
