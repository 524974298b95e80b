"""The status objects Klipper's API shows, for a tapcell printer.

API clients (Moonraker, Mainsail, Fluidd, KlipperScreen) read Klipper's status objects by
name and field, and break on a missing field or a field of another type. `ApiObjects`
gives them that view of a tapcell printer:

* the printer's own objects (toolhead, extruder, probe, load_cell_probe, bed_mesh, ...),
  completed with the Klipper fields they lack, with Klipper's types;
* stand-ins for what the virtual printer has no model of (a heated bed): room
  temperature, no target, no power;
* the objects of the host itself: webhooks, print_stats, virtual_sdcard, display_status,
  pause_resume, configfile, heaters and gcode_move.

It also registers the G-code commands behind those objects (PAUSE, RESUME, CANCEL_PRINT,
M117). Everything here runs on the thread that owns the printer.
"""

from __future__ import annotations

import re
from typing import Any

# Fields Klipper's objects have and tapcell's lack: added with these values (the object's own
# values win). The extruder has no motor on the virtual printer, so it cannot extrude.
EXTRUDER_FIELDS: dict[str, Any] = {
    "temperature": 0.0, "target": 0.0, "power": 0.0, "can_extrude": False,
    "pressure_advance": 0.0, "smooth_time": 0.04, "motion_queue": None,
}
TOOLHEAD_FIELDS: dict[str, Any] = {
    "extruder": "extruder", "stalls": 0, "square_corner_velocity": 5.0, "minimum_cruise_ratio": 0.5,
}
HEATER_FIELDS: dict[str, Any] = {"temperature": 0.0, "target": 0.0, "power": 0.0}
COMPLETED_FIELDS = {"extruder": EXTRUDER_FIELDS, "toolhead": TOOLHEAD_FIELDS, "heater_bed": HEATER_FIELDS}
# Heaters every Klipper-family UI expects; the ones the printer lacks are stand-ins.
HEATERS = ("heater_bed", "extruder")
ROOM_TEMPERATURE_C = 25.0  # a stand-in bed's temperature when the virtual printer states no ambient

READY_MESSAGE = "Printer is ready"
SHUTDOWN_ADVICE = ("Once the underlying issue is corrected, use the \"FIRMWARE_RESTART\" command to "
                   "restart the virtual printer and reload the config.\nPrinter is shutdown")

_NUMBER_RE = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$")


def setting_value(text: str) -> Any:
    """A config option's text as Klipper's `configfile.settings` shows it: a number, a bool,
    a list of numbers ("5, 5" -> [5, 5]) or else the text itself."""
    stripped = text.strip()
    if _NUMBER_RE.match(stripped):
        return int(stripped) if re.fullmatch(r"[+-]?\d+", stripped) else float(stripped)
    if stripped.lower() in ("true", "false"):
        return stripped.lower() == "true"
    if "," in stripped and "\n" not in stripped:
        items = [item.strip() for item in stripped.split(",")]
        if all(_NUMBER_RE.match(item) for item in items):
            return [setting_value(item) for item in items]
    return text


class ApiObjects:
    """Klipper's object view of one printer build (make a new one after RESTART)."""

    def __init__(self, printer, gcodes_dir: str | None = None):
        self.printer = printer
        self.gcodes_dir = gcodes_dir
        self.shutdown_message: str | None = None
        self.display_message: str | None = None
        self.is_paused = False
        self.print_state = "standby"  # print_stats.state: standby, printing, paused, complete, cancelled, error
        self._config_status = self._read_config()

    # -- state ---------------------------------------------------------------------------

    def state(self) -> tuple[str, str]:
        """(webhooks state, state message): startup, ready, error or shutdown."""
        if self.shutdown_message is not None:
            return "shutdown", self.shutdown_message
        if self.printer.state == "shutdown":  # M112 on the printer itself
            return "shutdown", self.printer.state_message
        state = {"ready": "ready", "error": "error"}.get(self.printer.state, "startup")
        message = READY_MESSAGE if state == "ready" else self.printer.state_message
        return state, message

    def shutdown(self, reason: str) -> None:
        """Halt like Klipper's shutdown: only RESTART, FIRMWARE_RESTART, HELP and STATUS work after it.
        Safe from any thread (an emergency stop from a second connection while a script runs): it
        sets the printer's stop flags; the printer's thread turns the heaters off (finish_shutdown)."""
        if self.shutdown_message is None:
            self.shutdown_message = f"{reason}\n{SHUTDOWN_ADVICE}"
            self.printer.request_emergency_stop(reason, self.shutdown_message)
            if self.print_state in ("printing", "paused"):
                self.print_state = "error"

    # -- commands ------------------------------------------------------------------------

    def register_commands(self, gcode) -> None:
        """Klipper's commands behind these objects; the printer's own (M117 of [display_status], M112)
        and a config's macro of the same name win."""
        commands = (("PAUSE", self.cmd_PAUSE, "Pause the current print"),
                    ("RESUME", self.cmd_RESUME, "Resume the print from a pause"),
                    ("CANCEL_PRINT", self.cmd_CANCEL_PRINT, "Cancel the current print"),
                    ("M117", self.cmd_M117, "Show a message on the display (display_status)"))
        for name, handler, desc in commands:
            if not gcode.is_registered(name):
                gcode.register_command(name, handler, desc=desc)

    def cmd_PAUSE(self, gcmd) -> None:
        if self.is_paused:
            gcmd.respond_info("Print already paused")
            return
        self.is_paused = True
        if self.print_state == "printing":
            self.print_state = "paused"
        self.printer.send_event("pause_resume:pause")

    def cmd_RESUME(self, gcmd) -> None:
        if not self.is_paused:
            gcmd.respond_info("Print is not paused, resume aborted")
            return
        self.is_paused = False
        if self.print_state == "paused":
            self.print_state = "printing"
        self.printer.send_event("pause_resume:resume")

    def cmd_CANCEL_PRINT(self, gcmd) -> None:
        self.is_paused = False
        if self.print_state in ("printing", "paused"):
            self.print_state = "cancelled"
        self.printer.send_event("pause_resume:cancel")

    def cmd_M117(self, gcmd) -> None:
        self.display_message = gcmd.rawparams or None

    # -- status ----------------------------------------------------------------------------

    def names(self) -> list[str]:
        return list(self.status())

    def status(self) -> dict[str, dict]:
        """Every object's status, by name (plain JSON-ready data)."""
        own = self.printer.get_status()
        status: dict[str, dict] = {}
        state, message = self.state()
        status["webhooks"] = {"state": state, "state_message": message}
        status["configfile"] = dict(self._config_status, **self._pending_config())
        for name, fields in own.items():
            status[name] = {**COMPLETED_FIELDS.get(name, {}), **fields}
        for heater in HEATERS:
            if heater not in status:
                status[heater] = {**HEATER_FIELDS, "temperature": self._room_temperature_c()}
        own_heaters = own.get("heaters", {})
        status["heaters"] = {
            "available_heaters": list(HEATERS) + [h for h in own_heaters.get("available_heaters", ()) if h not in HEATERS],
            "available_sensors": list(HEATERS) + [h for h in own_heaters.get("available_sensors", ()) if h not in HEATERS],
            "available_monitors": []}
        if "toolhead" in status:
            toolhead = status["toolhead"]
            toolhead.setdefault("estimated_print_time", toolhead.get("print_time", 0.0))
            status.setdefault("gcode_move", self._gcode_move(toolhead))
        # Stand-ins for a printer without [virtual_sdcard] (which makes the real ones).
        status.setdefault("print_stats", {"filename": "", "total_duration": 0.0, "print_duration": 0.0,
                                          "filament_used": 0.0, "state": self.print_state, "message": "",
                                          "info": {"total_layer": None, "current_layer": None}})
        status.setdefault("virtual_sdcard", {"file_path": None, "progress": 0.0, "is_active": False,
                                             "file_position": 0, "file_size": 0})
        status.setdefault("display_status", {"progress": 0.0, "message": self.display_message})
        status.setdefault("pause_resume", {"is_paused": self.is_paused})
        return status

    @staticmethod
    def _gcode_move(toolhead: dict) -> dict:
        return {
            "speed_factor": 1.0,
            "speed": float(toolhead.get("speed", 25.0)),
            "extrude_factor": 1.0,
            "absolute_coordinates": bool(toolhead.get("absolute_coordinates", True)),
            "absolute_extrude": True,
            "homing_origin": [0.0, 0.0, 0.0, 0.0],
            "position": [float(v) for v in toolhead.get("position", [0.0] * 4)],
            "gcode_position": [float(v) for v in toolhead.get("gcode_position", toolhead.get("position", [0.0] * 4))],
        }

    def _room_temperature_c(self) -> float:
        params = getattr(self.printer.backend, "params", None)
        return float(getattr(params, "ambient_c", ROOM_TEMPERATURE_C))

    def _read_config(self) -> dict:
        """configfile's config (texts) and settings (parsed), read once per build."""
        config = self.printer.config
        texts: dict[str, dict[str, str]] = {}
        if config is not None:
            for name in config.sections():
                texts[name] = config.section_options(name)
        if self.gcodes_dir is not None:
            # Moonraker checks that the printer prints from its own gcodes folder.
            texts.setdefault("virtual_sdcard", {"path": self.gcodes_dir})
        settings = {name.lower(): {option: setting_value(text) for option, text in options.items()}
                    for name, options in texts.items()}
        warnings = [{"type": "runtime_warning", "message": warning} for warning in self.printer.warnings]
        return {"config": texts, "settings": settings, "warnings": warnings}

    def _pending_config(self) -> dict:
        config = self.printer.config
        pending = config.pending_changes() if config is not None else {}
        return {"save_config_pending": bool(pending), "save_config_pending_items": pending}
