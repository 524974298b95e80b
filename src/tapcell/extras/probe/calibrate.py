"""PROBE_CALIBRATE (with TESTZ / ACCEPT / ABORT) and Z_OFFSET_APPLY_PROBE: the probe's z_offset.

PROBE_CALIBRATE probes at the current position, lifts 5 mm and starts a manual "paper test":
TESTZ Z=<mm> moves the nozzle by that much (Z=+ / Z=- go halfway to the nearest position
tried above / below), ACCEPT sets z_offset = (Z where the probe found the bed) - (Z of the
nozzle now), ABORT leaves it. Z_OFFSET_APPLY_PROBE folds the SET_GCODE_OFFSET Z of a print
into z_offset. Both queue the value for SAVE_CONFIG (the running probe keeps its old value
until the restart, as in Klipper).

A load cell probe is the nozzle itself: a TESTZ that would push the nozzle more than
MAX_PRESS_MM below the bed the probe just found is refused.
"""

from __future__ import annotations

from tapcell.host.gcode import GCodeCommand

LIFT_MM = 5.0
MAX_PRESS_MM = 0.05
SAVE_NOTE = "The SAVE_CONFIG command will update the printer config file\nwith the above and restart the printer."
TEMPORARY = ("TESTZ", "ACCEPT", "ABORT")


class ProbeCalibrate:
    def __init__(self, printer, probe):
        self.printer = printer
        self.probe = probe
        self.motion = probe.motion
        self.probed_z_mm: float | None = None  # toolhead Z at which the probe found the bed
        self.tried_z_mm: list[float] = []

    def _queue_z_offset(self, gcmd: GCodeCommand, z_offset_mm: float) -> None:
        self.printer.config.set(self.probe.name, "z_offset", f"{z_offset_mm:.3f}")
        gcmd.respond_info(f"{self.probe.name}: z_offset: {z_offset_mm:.3f}\n{SAVE_NOTE}")

    def cmd_PROBE_CALIBRATE(self, gcmd: GCodeCommand) -> None:
        if self.probed_z_mm is not None:
            raise gcmd.error("Already in a manual Z probe. Use ABORT to abort it.")
        x, y = self.probe.current_probe_xy()
        result = self.probe.probe_point(x, y, gcmd)
        self.probed_z_mm = result.z_mm + self.probe.options.z_offset_mm
        self.motion.move_to(z=self.probed_z_mm + LIFT_MM, speed_mm_s=self.probe.options.effective_lift_speed_mm_s)
        self.tried_z_mm = []
        gcode = self.printer.gcode
        for name in TEMPORARY:
            gcode.register_command(name, getattr(self, f"cmd_{name}"), desc=f"{name} of PROBE_CALIBRATE")
        gcmd.respond_info("Starting manual Z probe. Use TESTZ to adjust position.\n"
                          "Finish with ACCEPT or ABORT command.")
        self._report(gcmd)

    def _report(self, gcmd: GCodeCommand) -> None:
        z_now = self.motion.get_position()[2]
        below = [z for z in self.tried_z_mm if z < z_now - 1e-9]
        above = [z for z in self.tried_z_mm if z > z_now + 1e-9]
        low = f"{max(below):.3f}" if below else "??????"
        high = f"{min(above):.3f}" if above else "??????"
        gcmd.respond_info(f"Z position: {low} --> {z_now:.3f} <-- {high}")

    def cmd_TESTZ(self, gcmd: GCodeCommand) -> None:
        z_now = self.motion.get_position()[2]
        request = gcmd.get("Z")
        if request in ("+", "-"):
            side = [z for z in self.tried_z_mm if (z > z_now + 1e-9 if request == "+" else z < z_now - 1e-9)]
            if not side:
                raise gcmd.param_error(f"no position tried "
                                 f"{'above' if request == '+' else 'below'} yet; give a distance, e.g. TESTZ Z=-0.1")
            target = (z_now + (min(side) if request == "+" else max(side))) / 2.0
        else:
            target = z_now + gcmd.get_float("Z", minval=-LIFT_MM, maxval=LIFT_MM)
        lowest = self.probed_z_mm - MAX_PRESS_MM
        if target < lowest:
            raise gcmd.param_error(f"Z={target:.3f} is {self.probed_z_mm - target:.3f} mm "
                             f"below the bed the probe found (Z={self.probed_z_mm:.3f}): the nozzle would press into "
                             f"the bed (at most {MAX_PRESS_MM:g} mm below it)")
        self.tried_z_mm.append(z_now)
        self.motion.move_to(z=target, speed_mm_s=self.probe.options.speed_mm_s)
        self._report(gcmd)

    def _end(self) -> None:
        for name in TEMPORARY:
            self.printer.gcode.unregister_command(name)
        self.probed_z_mm = None

    def cmd_ACCEPT(self, gcmd: GCodeCommand) -> None:
        z_offset_mm = self.probed_z_mm - self.motion.get_position()[2]
        self._end()
        self._queue_z_offset(gcmd, z_offset_mm)

    def cmd_ABORT(self, gcmd: GCodeCommand) -> None:
        self._end()
        gcmd.respond_info("Manual probe aborted: z_offset unchanged")

    def cmd_Z_OFFSET_APPLY_PROBE(self, gcmd: GCodeCommand) -> None:
        gcode_offset_mm = self.printer.lookup_object("gcode_move").z_offset_mm()
        if gcode_offset_mm == 0.0:
            gcmd.respond_info("Nothing to do: Z Offset is 0")
            return
        self._queue_z_offset(gcmd, self.probe.options.z_offset_mm - gcode_offset_mm)


def register_probe_calibrate(printer, probe) -> ProbeCalibrate:
    calibrate = ProbeCalibrate(printer, probe)
    printer.gcode.register_command("PROBE_CALIBRATE", calibrate.cmd_PROBE_CALIBRATE,
                                   desc="Calibrate the probe's z_offset with a paper test (TESTZ, ACCEPT, ABORT)")
    printer.gcode.register_command("Z_OFFSET_APPLY_PROBE", calibrate.cmd_Z_OFFSET_APPLY_PROBE,
                                   desc="Fold the G-code Z offset into the probe's z_offset (for SAVE_CONFIG)")
    return calibrate
