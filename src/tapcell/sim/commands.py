"""G-code commands of the virtual printer, for people exploring it from the console.

On real hardware you put a weight on the scale or tap the nozzle with a finger; on
the virtual printer these commands do it:

    SIM_PLACE_WEIGHT GRAMS=500 [ADD=1] [LOAD_CELL=name]
                                                  a known weight rests on the cell (it replaces
                                                  the one there; ADD=1 puts it on top)
    SIM_REMOVE_WEIGHT [LOAD_CELL=name]            take it off again
    SIM_TAP [FORCE=300] [DURATION=0.2] [DELAY=0]  a hand tap on the nozzle (no motion), DELAY s from now
    SIM_FAULT NAME=<fault> [AT=s] [WHEN=cond [NTH=n]] [DURATION=s] [<PARAM>=value ...]
    SIM_TRUTH                                     what the simulator knows and the host must not

SIM_TRUTH prints simulator truth (the cell's real counts_per_gram, its zero offset,
the bed height under the nozzle, the largest force the nozzle put on the bed or, sideways, on
the calibration pin since the previous SIM_TRUTH as `peak_force_g: N` (each alone as
`peak_bed_force_g` and `peak_pin_force_g`), and the gap between nozzle tip and bed now as `nozzle_clearance_mm: N`,
negative when the nozzle is pressed into the bed): it is there to check calibration and
probing by eye and in tests, and no tapcell algorithm ever reads it.
"""

from __future__ import annotations

from tapcell.host.gcode import GCodeCommand
from tapcell.sim.faults import CONDITIONS, FAULT_DEFAULTS, FaultError
from tapcell.sim.printer import VirtualPrinter

MAX_WEIGHT_GRAMS = 100_000.0
MAX_TAP_FORCE_G = 10_000.0
MAX_TAP_DELAY_S = 600.0
# Putting a weight down (or lifting it off) takes a person about this long; the next
# command then reads a settled cell, as it would on a real printer.
WEIGHT_HANDLING_TIME_S = 0.5
# Parameters of SIM_FAULT itself; every other parameter is passed to the fault.
SIM_FAULT_OWN_PARAMETERS = ("NAME", "AT", "WHEN", "NTH", "DURATION")
MAX_FAULT_TIME_S = 86_400.0  # AT and DURATION: a fault a day away is as good as never
# The range of every numeric fault parameter (tapcell.sim.faults.FAULT_DEFAULTS), by name.
FAULT_PARAMETER_RANGES: dict[str, tuple[float, float]] = {
    "offset_jump_counts": (-(1 << 24), 1 << 24),  # a 24-bit chip's whole span, either way
    "gap_s": (0.0, 10.0),
    "count": (1, 1000),
    "spacing_s": (0.001, 60.0),
    "grams": (-MAX_WEIGHT_GRAMS, MAX_WEIGHT_GRAMS),
    "force_g": (-MAX_TAP_FORCE_G, MAX_TAP_FORCE_G),
}


def _parse_fault_value(gcmd: GCodeCommand, key: str, text: str, default):
    """A fault parameter in the type of its default (number, true/false or word), numbers range-checked."""
    if isinstance(default, bool):
        if text.lower() not in ("0", "1", "true", "false"):
            raise gcmd.param_error(f"{key.upper()} must be 0/1 or true/false")
        return text.lower() in ("1", "true")
    if isinstance(default, (int, float)):
        low, high = FAULT_PARAMETER_RANGES[key.lower()]
        getter = gcmd.get_int if isinstance(default, int) else gcmd.get_float
        return getter(key, minval=low, maxval=high)
    return text


class SimCommands:
    def __init__(self, printer, vp: VirtualPrinter):
        self.printer = printer
        self.vp = vp

    def _weight_target(self, gcmd: GCodeCommand):
        """The virtual sensor of LOAD_CELL=name (a [load_cell NAME] or [load_cell] /
        [load_cell_probe]), or the printer's own cell when LOAD_CELL is not given."""
        name = gcmd.get("LOAD_CELL", None)
        if name is None:
            return self.vp
        candidates = [f"load_cell {name}", name]
        for section in candidates:
            load_cell = self.printer.lookup_object(section, None)
            sensor = getattr(load_cell, "sensor", None)
            if sensor is None:
                sensor = getattr(getattr(load_cell, "load_cell", None), "sensor", None)  # [load_cell_probe]
            if sensor is not None:
                return sensor
        raise gcmd.param_error(f"no load cell '{name}' "
                               f"(no [load_cell {name}] or [{name}] section)")

    def cmd_place_weight(self, gcmd: GCodeCommand) -> None:
        grams = gcmd.get_float("GRAMS", above=0.0, maxval=MAX_WEIGHT_GRAMS)
        add = bool(gcmd.get_int("ADD", 0, minval=0, maxval=1))
        total_g = self._weight_target(gcmd).place_weight(grams, add=add)
        self.vp.dwell(WEIGHT_HANDLING_TIME_S)
        if add:
            gcmd.respond_info(f"{grams:g} g more on the load cell: {total_g:g} g rest on it now")
        else:
            gcmd.respond_info(f"A {grams:g} g weight now rests on the load cell")

    def cmd_remove_weight(self, gcmd: GCodeCommand) -> None:
        self._weight_target(gcmd).remove_weight()
        self.vp.dwell(WEIGHT_HANDLING_TIME_S)
        gcmd.respond_info("The weight is off the load cell")

    def cmd_tap(self, gcmd: GCodeCommand) -> None:
        force_g = gcmd.get_float("FORCE", 300.0, above=0.0, maxval=MAX_TAP_FORCE_G)
        duration_s = gcmd.get_float("DURATION", 0.2, above=0.0, maxval=10.0)
        delay_s = gcmd.get_float("DELAY", 0.0, minval=0.0, maxval=MAX_TAP_DELAY_S)
        self.vp.tap_nozzle(force_g, duration_s, delay_s=delay_s)
        when = f" in {delay_s:g} s" if delay_s else ""
        gcmd.respond_info(f"Tapped the nozzle{when}: {force_g:g} g for {duration_s:g} s")

    def cmd_fault(self, gcmd: GCodeCommand) -> None:
        name = gcmd.get_choice("NAME", list(FAULT_DEFAULTS))
        at_s = gcmd.get_float("AT", None, minval=0.0, maxval=MAX_FAULT_TIME_S)
        when = gcmd.get_choice("WHEN", CONDITIONS, None)
        nth = gcmd.get_int("NTH", 1, minval=1, maxval=100_000)
        params = {}
        duration_s = gcmd.get_float("DURATION", None, above=0.0, maxval=MAX_FAULT_TIME_S)
        if duration_s is not None:
            params["duration_s"] = duration_s
        defaults = FAULT_DEFAULTS[name]
        for key, text in gcmd.get_command_parameters().items():
            if key in SIM_FAULT_OWN_PARAMETERS:
                continue
            option = key.lower()
            if option not in defaults:
                allowed = ", ".join(k.upper() for k in defaults) or "none"
                raise gcmd.param_error(f"fault '{name}' has no parameter {key}"
                                       f" (its parameters: {allowed}; and AT, WHEN, NTH, DURATION)")
            params[option] = _parse_fault_value(gcmd, key, text, defaults[option])
        try:
            self.vp.inject_fault(name, at_s=at_s, when=when, nth=nth, **params)
        except FaultError as exc:
            raise gcmd.param_error(str(exc)) from None
        start = f"at {at_s:g} s" if at_s is not None else (f"on {when}" if when else "now")
        gcmd.respond_info(f"Fault '{name}' injected ({start})")

    def cmd_truth(self, gcmd: GCodeCommand) -> None:
        truth = self.vp.truth
        x, y, _ = self.vp.position
        peak_bed_g, peak_pin_g = truth.take_peak_forces_g()
        lines = [
            "Simulator truth (for checking by eye; no tapcell algorithm reads it):",
            f"cell counts_per_gram: {truth.counts_per_gram:.3f}",
            f"cell zero offset: {truth.zero_offset_counts:.0f} counts",
            f"bed surface under the nozzle (X{x:.1f} Y{y:.1f}): Z={float(truth.surface_z(x, y)):.4f} mm"
            " in machine coordinates",
            f"simulated time: {self.vp.now_s:.3f} s",
            f"peak_force_g: {max(peak_bed_g, peak_pin_g):.1f}",
            f"peak_bed_force_g: {peak_bed_g:.1f}",
            f"peak_pin_force_g: {peak_pin_g:.1f}",
            f"nozzle_clearance_mm: {truth.nozzle_clearance_mm:.4f}",
        ]
        gcmd.respond_info("\n".join(lines))


def register_sim_commands(printer) -> None:
    """Adds the SIM_* commands when the printer runs on the virtual printer."""
    vp = printer.backend
    if not isinstance(vp, VirtualPrinter):
        return
    commands = SimCommands(printer, vp)
    gcode = printer.gcode
    gcode.register_command("SIM_PLACE_WEIGHT", commands.cmd_place_weight,
                           desc="Virtual printer: rest a weight on the load cell (replacing the one there), GRAMS= [ADD=1]")
    gcode.register_command("SIM_REMOVE_WEIGHT", commands.cmd_remove_weight,
                           desc="Virtual printer: take the weight off the load cell")
    gcode.register_command("SIM_TAP", commands.cmd_tap,
                           desc="Virtual printer: tap the nozzle by hand, [FORCE=g] [DURATION=s] [DELAY=s]")
    gcode.register_command("SIM_FAULT", commands.cmd_fault,
                           desc="Virtual printer: inject a fault, NAME= [AT=] [WHEN= [NTH=]] [DURATION=] [params]")
    gcode.register_command("SIM_TRUTH", commands.cmd_truth,
                           desc="Virtual printer: show simulator truth (calibration, bed height, peak force, "
                                "nozzle clearance)")
