"""Assemble a printer from a config file: one object per section, status, events, RESTART.

`Printer.from_config(path)` reads the config, builds the backend (the virtual printer, from
`[virtual_printer]`, declared by `tapcell.host.backend.Backend`), then loads every section by
convention: the first word of a section name is a module of `tapcell.extras` (`[load_cell]`
and `[load_cell NAME]` -> `tapcell.extras.load_cell`; `[printer]` is the host's own toolhead),
which provides `load_config(section, printer)` for `[name]` and/or
`load_config_prefix(section, printer)` for `[name instance]`. A new config section is a new
module in `extras/`; there is no table to register it in. The object a module returns is
stored under the full section name and, if it has `get_status(eventtime)`, appears in
`get_status()` (and so in G-code macros as `printer.<name>` / `printer["<name>"]`).

Sections in `READ_BY` have no module of their own: the module of another section reads
them (the toolhead reads `[stepper_x]`). Modules are imported only when a config uses them.
"""

from __future__ import annotations

import difflib
import importlib
import json
import pkgutil
import time
from typing import Any, Callable

from tapcell.host.backend import Backend, DeviceError
from tapcell.host.config import ConfigError, ConfigFile
from tapcell.host.gcode import GCodeCommand, GCodeDispatch, GCodeError, ResponseSink

# `[name]` -> module EXTRAS_PACKAGE.name; `[printer]` is the toolhead of the host itself.
EXTRAS_PACKAGE = "tapcell.extras"
TOOLHEAD_SECTION = "printer"
TOOLHEAD_MODULE = "tapcell.host.toolhead"

# Sections without a module of their own -> the section whose module reads them.
READ_BY: dict[str, str] = {
    "stepper_x": "printer",
    "stepper_y": "printer",
    "stepper_z": "printer",
    "extruder": "printer",
}
# Hardware and UI sections taken as written and not modelled (a real printer.cfg's [mcu], [tmc2209 ...]).
ACCEPTED_MODULE = "tapcell.extras.accepted_sections"

# The backend's section: read by the virtual printer itself.
BACKEND_SECTION = "virtual_printer"
BACKEND_MODULE = "tapcell.sim"
# What the printer's own config says about the machine, for the virtual printer to follow.
MACHINE_MODULE = "tapcell.sim.machine"
# G-code commands that act on the virtual hardware (SIM_PLACE_WEIGHT, ...).
BACKEND_COMMANDS_MODULE = "tapcell.sim.commands"

# G-code that still works while the printer is shut down or its config is broken.
WHEN_NOT_READY = ("RESTART", "FIRMWARE_RESTART", "HELP", "STATUS")

# Sections loaded before the others (in this order), because others look them up.
LOAD_FIRST = (TOOLHEAD_SECTION,)
# Objects Klipper has whether or not the config names them (UIs read their status; an
# [idle_timeout] section only changes its options).
DEFAULT_SECTIONS = ("idle_timeout", "motion_report", "system_stats", "query_endstops", "force_move")
# The section a served printer gets when its config has none and `tapcell serve --gcodes-dir`
# names Moonraker's gcodes folder (a file uploaded in Mainsail prints from there).
GCODES_SECTION = "virtual_sdcard"
LOADERS = ("load_config", "load_config_prefix")

_MISSING = object()


def section_module_name(kind: str) -> str | None:
    """The module that loads sections whose first word is `kind` (None: not a module name)."""
    if kind == TOOLHEAD_SECTION:
        return TOOLHEAD_MODULE
    if not kind.isidentifier() or kind.startswith("_"):
        return None
    return f"{EXTRAS_PACKAGE}.{kind}"


def import_section_module(kind: str):
    """The module of a section kind, or None when there is none (a broken import inside it raises)."""
    module_name = section_module_name(kind)
    if module_name is None:
        return None
    try:
        return importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        if exc.name is not None and module_name.startswith(exc.name):
            return None
        raise


def accepted_sections() -> dict[str, str]:
    """Section kinds taken as written and not modelled (kind -> what it is)."""
    return importlib.import_module(ACCEPTED_MODULE).ACCEPTED_SECTIONS


def section_kinds() -> list[str]:
    """Every section kind a config may use (for the error that lists them)."""
    package = importlib.import_module(EXTRAS_PACKAGE)
    kinds = {TOOLHEAD_SECTION, BACKEND_SECTION, *READ_BY}
    for info in pkgutil.iter_modules(package.__path__):
        module = import_section_module(info.name)
        if module is not None and any(hasattr(module, loader) for loader in LOADERS):
            kinds.add(info.name)
    return sorted(kinds)


class Printer:
    """The host side of one printer: config, backend, G-code, objects by section."""

    def __init__(self, config_path: str, *, backend: Backend | None = None, responses: ResponseSink | None = None):
        self.config_path = str(config_path)
        self._given_backend = backend
        self.gcode = GCodeDispatch(responses)
        self.gcode.on_device_error(self._device_failed)
        self.config: ConfigFile | None = None
        self.backend: Backend | None = backend
        self.objects: dict[str, Any] = {}
        self.warnings: list[str] = []  # runtime warnings, reported by the API as Klipper's printer.info does
        self.notices: list[str] = []  # shown once at start (what is simulated, what only accepted)
        self._accepted: list[str] = []  # sections taken as written, not modelled
        self.state = "starting"  # "ready", "error" or "shutdown"
        self.state_message = ""
        self._shutdown_reason: str | None = None  # an emergency stop whose heaters-off is still to do
        self._event_handlers: dict[str, list[Callable[..., Any]]] = {}
        self._loading: set[str] = set()
        self._loaded: set[str] = set()  # sections loaded, whether or not they made an object
        self.gcodes_dir: str | None = None  # tapcell serve --gcodes-dir (see GCODES_SECTION)
        # Set by a live server (tapcell.host.print_clock): what the machine is doing now.
        self.print_clock = None
        self.endpoints: dict[str, Callable[[dict], dict]] = {}  # API endpoints of modules (path -> callback)
        self._background: list[Callable[[], None]] = []  # work a live server runs between scripts

    @classmethod
    def from_config(cls, path: str, *, backend: Backend | None = None,
                    responses: ResponseSink | None = None) -> Printer:
        """Build a ready printer from `path`; raises ConfigError for any problem in the file."""
        printer = cls(path, backend=backend, responses=responses)
        printer._build()
        return printer

    # -- objects -------------------------------------------------------------

    def lookup_object(self, name: str, default: Any = _MISSING) -> Any:
        if name in self.objects:
            return self.objects[name]
        if default is _MISSING:
            raise ConfigError(f"Unknown printer object '{name}' (known: {', '.join(sorted(self.objects))})")
        return default

    def add_object(self, name: str, obj: Any) -> None:
        if name in self.objects:
            raise ConfigError(f"Printer object '{name}' already exists")
        self.objects[name] = obj

    def load_object(self, section_name: str) -> Any:
        """The object of a section, loading it now if it was not loaded yet (None if absent)."""
        if section_name in self._loading:
            raise ConfigError(f"{self.config.section_file(section_name)}: [{section_name}] depends on itself "
                              f"while loading", file=self.config.section_file(section_name), section=section_name)
        if section_name not in self._loaded and self.config.has_section(section_name):
            self._load_section(section_name)
        return self.objects.get(section_name)

    def get_time(self) -> float:
        """The printer's clock: the backend's simulated seconds (`now_s`), else the host's monotonic clock."""
        now_s = getattr(self.backend, "now_s", None)
        return float(now_s) if now_s is not None else time.monotonic()

    def estimated_print_time(self) -> float:
        """Klipper's estimated print time: the machine's "now" while queued moves still play
        (tapcell serve), else the backend's clock (every move already ran to its end)."""
        if self.print_clock is not None:
            return self.print_clock.estimated_s
        return self.get_time()

    def register_endpoint(self, path: str, callback: Callable[[dict], dict]) -> None:
        """An API endpoint (`query_endstops/status`) served by a module: callback(params) -> result."""
        self.endpoints[path] = callback

    def register_background(self, callback: Callable[[], None]) -> None:
        """Work a live server runs on the printer's thread between scripts (a file being printed)."""
        self._background.append(callback)

    def run_background(self) -> None:
        for callback in list(self._background):
            callback()

    def get_status(self, eventtime: float | None = None) -> dict[str, dict]:
        """Every object's status under its section name (plain, JSON-ready data)."""
        eventtime = self.get_time() if eventtime is None else eventtime
        return {name: obj.get_status(eventtime) for name, obj in self.objects.items()
                if hasattr(obj, "get_status")}

    # -- events --------------------------------------------------------------

    def register_event_handler(self, event: str, callback: Callable[..., Any]) -> None:
        """Call `callback(*args)` on `send_event(event, *args)`.

        Events sent by the printer: "printer:ready" (all sections loaded),
        "printer:restart" (before the objects are dropped by RESTART) and "printer:positions_lost"
        (the machine lost the stepper positions under a command, e.g. its MCU reset).
        """
        self._event_handlers.setdefault(event, []).append(callback)

    def send_event(self, event: str, *args: Any) -> list[Any]:
        return [callback(*args) for callback in self._event_handlers.get(event, [])]

    # -- building ------------------------------------------------------------

    def _build(self) -> None:
        self.objects.clear()
        self.warnings.clear()
        self.notices.clear()
        self._accepted.clear()
        self.gcode.set_refusal(None)
        self._shutdown_reason = None
        self._loaded.clear()
        self._event_handlers.clear()
        self.endpoints.clear()
        self._background.clear()
        self.config = None
        self.gcode.clear_commands()
        self._register_builtin_commands()
        try:
            self.config = ConfigFile.read(self.config_path)
            self._check_section_names()
            self._build_backend()
            ordered = [n for n in LOAD_FIRST if self.config.has_section(n)]
            ordered += [n for n in self.config.sections() if n not in ordered]
            for name in ordered:
                if name != BACKEND_SECTION and name not in self._loaded:
                    self._load_section(name)
            implied = [GCODES_SECTION] if self.gcodes_dir is not None else []
            for name in (*DEFAULT_SECTIONS, *implied):
                if name not in self._loaded and import_section_module(name) is not None:
                    self._load_section(name)
            self.config.check_unused_options()
            accepted = importlib.import_module(ACCEPTED_MODULE)
            notice = accepted.startup_notice(self.config.sections(), self._accepted)
            world = getattr(self.backend, "world_notice", None)
            if notice is not None:  # a config with hardware in it: say what stands in for it
                self.notices += [world, notice] if world else [notice]
        except (ConfigError, GCodeError) as exc:
            self.state, self.state_message = "error", str(exc)
            # Only the built-ins stay, so the user can fix the file and RESTART.
            self.objects.clear()
            self.gcode.clear_commands()
            self._register_builtin_commands()
            raise exc if isinstance(exc, ConfigError) else ConfigError(str(exc)) from exc
        self.state, self.state_message = "ready", "Printer is ready"
        self.send_event("printer:ready")

    def _check_section_names(self) -> None:
        if not self.config.sections():  # Klipper refuses an empty printer.cfg too
            raise ConfigError(f"{self.config_path}: the config file has no sections (it is empty or only "
                              f"comments): a printer needs at least [printer] and its steppers", file=self.config_path)
        for name in self.config.sections():
            kind = name.split()[0]
            if (kind != BACKEND_SECTION and kind not in READ_BY and kind not in accepted_sections()
                    and import_section_module(kind) is None):
                # The known kinds are many (the accepted ones included): name the closest.
                close = difflib.get_close_matches(kind, section_kinds() + sorted(accepted_sections()), n=3)
                hint = f" (did you mean {' or '.join(close)}?)" if close else ""
                raise ConfigError(f"{self.config.section_file(name)}: [{name}]: Section '{name}' is not a "
                                  f"valid config section{hint}", file=self.config.section_file(name), section=name)
            reader = READ_BY.get(name)
            if reader is not None and not self.config.has_section(reader):
                raise ConfigError(f"{self.config.section_file(name)}: [{name}]: this section is read by "
                                  f"[{reader}], which is missing", file=self.config.section_file(name),
                                  section=name)

    def _build_backend(self) -> None:
        if self._given_backend is not None:
            self.backend = self._given_backend
            if hasattr(self.backend, "release_emergency_stop"):  # a restart resets the machine
                self.backend.release_emergency_stop()
            self.config.mark_section_read(BACKEND_SECTION)
        else:
            sim = importlib.import_module(BACKEND_MODULE)
            machine = importlib.import_module(MACHINE_MODULE).machine_params(self.config)
            self.backend = sim.VirtualPrinter.from_config(self.config.getsection(BACKEND_SECTION), machine=machine)
        self.objects[BACKEND_SECTION] = self.backend
        importlib.import_module(BACKEND_COMMANDS_MODULE).register_sim_commands(self)

    def _device_failed(self, error: DeviceError) -> str:
        """The machine failed under a command. When it lost the stepper positions (an MCU reset),
        every module forgets them ("printer:positions_lost"; the toolhead its homing) and the
        user reads what to do."""
        if not error.positions_lost:
            return ""
        self.send_event("printer:positions_lost")
        return ". The stepper positions are no longer known: home (G28) before moving again"

    def _load_section(self, name: str) -> None:
        self._loading.add(name)
        self._loaded.add(name)
        try:
            kind, _, instance = name.partition(" ")
            if kind in accepted_sections():
                self.config.mark_section_read(name)  # options taken as written
                self._accepted.append(name)
                return
            if kind in READ_BY:
                self.load_object(READ_BY[kind])
                return
            module = import_section_module(kind)
            loader_name = "load_config_prefix" if instance else "load_config"
            loader = getattr(module, loader_name, None)
            if loader is None:
                form = f"[{kind} NAME]" if instance else f"[{kind}]"
                raise ConfigError(f"{self.config.section_file(name)}: [{name}]: Section '{name}' is not a valid "
                                  f"config section ({module.__name__} does not support {form})",
                                  file=self.config.section_file(name), section=name)
            try:
                obj = loader(self.config.getsection(name), self)
            except GCodeError as exc:  # e.g. a command registered twice
                raise ConfigError(f"{self.config.section_file(name)}: [{name}]: {exc}",
                                  file=self.config.section_file(name), section=name) from exc
            if obj is not None:
                self.add_object(name, obj)
        finally:
            self._loading.discard(name)

    # -- restart / built-in commands ----------------------------------------

    def restart(self) -> None:
        """Drop every object and build the printer again from the config file on disk.

        The virtual printer is rebuilt too (like a power cycle) unless a backend
        object was handed to from_config, which is kept.  A broken config leaves
        the printer in the "error" state with only HELP/STATUS/RESTART, and raises.
        """
        self.send_event("printer:restart")
        self._build()

    def _register_builtin_commands(self) -> None:
        self.gcode.register_command("STATUS", self._cmd_status,
                                    desc="Report the printer state; OBJECT=name shows one object's status")
        self.gcode.register_command("RESTART", self._cmd_restart,
                                    desc="Reload the config file and rebuild the printer")
        # The virtual printer is rebuilt on RESTART too (a power cycle), so both are the same here.
        self.gcode.register_command("FIRMWARE_RESTART", self._cmd_restart,
                                    desc="Restart the virtual printer and reload the config file")
        self.gcode.register_command("SAVE_CONFIG", self._cmd_save_config,
                                    desc="Write pending config changes (e.g. a calibration) and restart")
        self.gcode.register_command("M112", self._cmd_M112, desc="Emergency stop: heaters off, printer halted")

    def request_emergency_stop(self, reason: str, message: str | None = None) -> None:
        """From any thread (a second API connection, the console's Ctrl-C): the steppers stop at the
        next sample the machine produces, the running command and the rest of its script fail with
        the shutdown message (`message`, else the reason and RESTART advice), and every command but
        HELP/STATUS/RESTART is refused. Only flags are set here; the thread that runs G-code turns
        the heaters and fans off next (finish_shutdown)."""
        if self.state == "shutdown":
            return
        self._shutdown_reason = reason
        self.state_message = message or f"{reason}\nOnce the underlying issue is corrected, use RESTART"
        self.state = "shutdown"
        self.gcode.set_refusal(WHEN_NOT_READY, self.state_message)
        if self.backend is not None and hasattr(self.backend, "emergency_stop"):
            self.backend.emergency_stop()

    def finish_shutdown(self) -> None:
        """On the G-code thread, after an emergency stop asked for elsewhere: heaters and fans off."""
        reason, self._shutdown_reason = self._shutdown_reason, None
        if reason is None:
            return
        heaters = self.lookup_object("heaters", None)
        for heater in (heaters.heaters.values() if heaters else ()):
            heater.set_temperature(0.0)
        self.send_event("printer:shutdown")

    def invoke_shutdown(self, reason: str, message: str | None = None) -> None:
        """Halt like Klipper's shutdown: motion stops, heaters and fans off, only HELP/STATUS/RESTART work."""
        self.request_emergency_stop(reason, message)
        self.finish_shutdown()

    def _cmd_M112(self, gcmd: GCodeCommand) -> None:
        self.invoke_shutdown("Shutdown due to M112 command")
        gcmd.respond_raw("!! Shutdown due to M112 command")

    def _cmd_status(self, gcmd: GCodeCommand) -> None:
        name = gcmd.get("OBJECT", None)
        status = self.get_status()
        if name is not None:
            if name not in status:
                raise gcmd.param_error(f"no status object '{name}' "
                                       f"(one of: {', '.join(sorted(status))})")
            gcmd.respond_info("\n".join(f"{key}: {_format_status_value(value)}"
                                        for key, value in status[name].items()))
            return
        lines = [self.state_summary(status)]
        lines += [f"Warning: {warning}" for warning in self.warnings]
        lines += [f"{obj}: " + " ".join(f"{key}={_format_status_value(value)}" for key, value in fields.items())
                  for obj, fields in status.items()]
        gcmd.respond_info("\n".join(lines))

    def state_summary(self, status: dict | None = None) -> str:
        """The state message and, when ready, what is still to do before probing, each with the
        command that does it (a fresh printer is "ready" in Klipper's sense long before it can home)."""
        if self.state != "ready":
            return self.state_message
        steps = setup_steps(self.get_status() if status is None else status)
        return f"{self.state_message}; before probing: {'; '.join(steps)}" if steps else self.state_message

    def _cmd_restart(self, gcmd: GCodeCommand) -> None:
        try:
            self.restart()
        except ConfigError as exc:
            raise gcmd.error(f"{exc}\nThe printer is halted: fix the config file, then RESTART") from exc
        gcmd.respond_info(self.state_message)

    def _cmd_save_config(self, gcmd: GCodeCommand) -> None:
        if self.config is None or not self.config.has_pending_changes():
            gcmd.respond_info("No pending config changes to save")
            return
        self.config.save()
        gcmd.respond_info(f"Config saved to {self.config_path}; restarting")
        self._cmd_restart(gcmd)


def setup_steps(status: dict) -> list[str]:
    """What a printer's status says is still to do before it can probe: an uncalibrated load cell
    (each cell once: `load_cell` may name the probe's cell too) and axes not homed."""
    steps = []
    uncalibrated = {name: fields for name, fields in status.items()
                    if (name in ("load_cell", "load_cell_probe") or name.startswith("load_cell "))
                    and fields.get("is_calibrated") is False}
    if "load_cell" in uncalibrated and "load_cell_probe" in uncalibrated:
        del uncalibrated["load_cell"]  # the probe's cell, reported under both names
    for name in sorted(uncalibrated):
        command = "LOAD_CELL_CALIBRATE" + (f" LOAD_CELL={name.split(' ', 1)[1]}" if " " in name else "")
        steps.append(f"{name} is not calibrated: run {command} (then SAVE_CONFIG)")
    homed = status.get("toolhead", {}).get("homed_axes")
    if homed is not None and homed != "xyz":
        steps.append(f"not homed{f' (homed: {homed})' if homed else ''}: run G28")
    return steps


def _format_status_value(value: Any) -> str:
    """A status value as JSON (what Moonraker clients see), floats to 6 significant digits."""
    return json.dumps(_rounded(value), default=_plain)


def _plain(value: Any) -> Any:
    """numpy scalars and arrays as their Python values; anything else as text."""
    return value.tolist() if hasattr(value, "tolist") else str(value)


def _rounded(value: Any) -> Any:
    if isinstance(value, float):
        return float(f"{value:.6g}")
    if isinstance(value, dict):
        return {str(key): _rounded(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_rounded(item) for item in value]
    return value

