"""`[xy_probe]`: touch a pin from the side with the load cell and report where it is.

The nozzle is lowered beside a calibration pin and moved sideways until the force on the
load cell passes the XY threshold (40 g, Prusa's XY_PROBE_THRESHOLD; `SET_XY_THRESHOLD` of
`[prusa_probe]` changes it). The contact position is the nozzle position at the triggering
sample. Touching the pin from both sides on each axis gives its centre: the toolhead's
sideways give before the trigger is the same on both sides and cancels out. That centre,
measured with each tool, is the basis of tool-offset calibration.

Commands:
* `XY_PROBE DIRECTION=+X|-X|+Y|-Y [DISTANCE=] [SPEED=] [FORCE=]`: from where the nozzle is,
  move that way until contact; report the contact position.
* `XY_PROBE_PIN [X=] [Y=] [Z=]`: find the centre of the pin near X, Y (default: `pin_x`,
  `pin_y`) from four sides at nozzle height Z (default `probe_z`); report the centre, its
  offset from the nominal position and the apparent diameter (pin + nozzle tip, less the give).
"""

from __future__ import annotations

from dataclasses import dataclass

from tapcell.extras.load_cell_probe import safety
from tapcell.extras.load_cell_probe.threshold import ThresholdProber
from tapcell.host.config import ConfigSection
from tapcell.host.gcode import GCodeCommand, GCodeError
from tapcell.host.toolhead import COORDINATE_RANGE, MAX_COORDINATE_MM, SPEED_RANGE
from tapcell.mesh.prusa import XY, Thresholds

SECTION = "xy_probe"
DIRECTIONS = {"+X": (1.0, 0.0), "-X": (-1.0, 0.0), "+Y": (0.0, 1.0), "-Y": (0.0, -1.0)}
# A sideways touch slower than 0.5 mm/s takes minutes of simulated sampling for nothing.
XY_PROBE_SPEED_MM_S = (0.5, 20.0)
MAX_TRAVEL_MM = 50.0
MAX_SIZE_MM = 100.0  # pin and nozzle tip diameters, clearance
# The stiffest toolhead the speed guard assumes against the pin, sideways, unless the config says
# less (`max_side_stiffness`): the worst case, as the Z guard's bed (a belt-driven toolhead is far
# softer: the virtual printer's is 4 g/um).
DEFAULT_MAX_SIDE_STIFFNESS_G_UM = 100.0
# The load cell, built for vertical force, reads at least this share of a sideways one (the
# virtual toolhead: 0.5): the force on the pin when the XY threshold is read is at most
# threshold / this.
MIN_SIDE_COUPLING = 0.25


@dataclass(frozen=True)
class XYProbeOptions:
    pin_x_mm: float | None
    pin_y_mm: float | None
    pin_diameter_mm: float
    nozzle_tip_diameter_mm: float
    probe_z_mm: float  # nozzle height beside the pin (below its top)
    safe_z_mm: float  # travel height above the pin
    clearance_mm: float  # start this far from the nominal pin surface
    speed_mm_s: float
    travel_speed_mm_s: float
    max_travel_mm: float
    max_side_stiffness_g_um: float


@dataclass(frozen=True)
class SideGuard:
    """How hard a sideways touch can press the pin: the force read at the threshold, one step of
    the motor past it, and the travel between the triggering sample and the halt, all on the
    stiffest toolhead the config allows."""

    stiffness_g_um: float
    step_um: float
    lag_s_per_mm_s: float   # seconds of travel after contact before the halt (safety.trigger_lag_mm)
    force_safety_limit_g: float

    def peak_force_g(self, threshold_g: float, speed_mm_s: float) -> float:
        travel_um = self.step_um + 1000.0 * speed_mm_s * self.lag_s_per_mm_s
        return threshold_g / MIN_SIDE_COUPLING + self.stiffness_g_um * travel_um

    def safe_speed_mm_s(self, threshold_g: float) -> float:
        """The fastest speed whose worst press stays within force_safety_limit (<= 0: none)."""
        budget_g = self.force_safety_limit_g - self.peak_force_g(threshold_g, 0.0)
        return budget_g / (self.stiffness_g_um * 1000.0 * self.lag_s_per_mm_s)


def read_xy_probe_options(section: ConfigSection) -> XYProbeOptions:
    probe_z = section.getfloat("probe_z", 2.0, **COORDINATE_RANGE)
    return XYProbeOptions(
        pin_x_mm=section.getfloat("pin_x", None, **COORDINATE_RANGE),
        pin_y_mm=section.getfloat("pin_y", None, **COORDINATE_RANGE),
        pin_diameter_mm=section.getfloat("pin_diameter", 6.0, above=0.0, maxval=MAX_SIZE_MM),
        nozzle_tip_diameter_mm=section.getfloat("nozzle_tip_diameter", 1.0, above=0.0, maxval=MAX_SIZE_MM),
        probe_z_mm=probe_z,
        safe_z_mm=section.getfloat("safe_z", 10.0, above=probe_z, maxval=MAX_COORDINATE_MM),
        clearance_mm=section.getfloat("clearance", 2.0, above=0.0, maxval=MAX_SIZE_MM),
        speed_mm_s=section.getfloat("speed", 2.0, minval=XY_PROBE_SPEED_MM_S[0], maxval=XY_PROBE_SPEED_MM_S[1]),
        travel_speed_mm_s=section.getfloat("travel_speed", 50.0, **SPEED_RANGE),
        max_travel_mm=section.getfloat("max_travel", 10.0, above=0.0, maxval=MAX_TRAVEL_MM),
        max_side_stiffness_g_um=section.getfloat("max_side_stiffness", DEFAULT_MAX_SIDE_STIFFNESS_G_UM,
                                                 above=0.0, maxval=10000.0),
    )


class XYProbe:
    def __init__(self, section: ConfigSection, printer):
        self.printer = printer
        self.options = read_xy_probe_options(section)
        self.last_result: dict | None = None
        gcode = printer.gcode
        gcode.register_command("XY_PROBE", self.cmd_XY_PROBE,
                               desc="Move sideways until the nozzle touches: DIRECTION=+X|-X|+Y|-Y [DISTANCE=] [SPEED=]")
        gcode.register_command("XY_PROBE_PIN", self.cmd_XY_PROBE_PIN,
                               desc="Find the calibration pin's centre from four sides: [X=] [Y=] [Z=]")

    def _threshold(self) -> Thresholds:
        prusa = self.printer.lookup_object("prusa_probe", None)
        return Thresholds() if prusa is None else prusa.thresholds

    def _prober(self) -> ThresholdProber:
        device = self.printer.lookup_object("load_cell_probe", None)
        if device is None:
            raise GCodeError("XY probing needs a [load_cell_probe] section")
        prober = ThresholdProber(device)
        if prober.toolhead.status()["homed_axes"] != "xyz":
            raise GCodeError("XY probing: home all axes first (G28)")
        return prober

    def _guard(self, prober: ThresholdProber) -> SideGuard:
        device = prober.device
        step_um = 1000.0 * max(float(d) for d in list(prober.backend.step_distance_mm)[:2])
        return SideGuard(self.options.max_side_stiffness_g_um, step_um,
                         safety.trigger_lag_mm(device.stop_timing, 1.0), device.options.force_safety_limit_g)

    def guarded_speed_mm_s(self, gcmd: GCodeCommand, prober: ThresholdProber, speed_mm_s: float, force_g: float,
                           asked: bool) -> float:
        """The speed of a sideways touch whose worst press stays within force_safety_limit: a
        configured speed above it is lowered (with a note), an asked one (SPEED=) refused; no
        speed at all (a slow sensor, a stiff toolhead) is refused. force_safety_limit 0: as given."""
        guard = self._guard(prober)
        if guard.force_safety_limit_g <= 0.0:
            return speed_mm_s
        safe_mm_s = guard.safe_speed_mm_s(force_g)
        if speed_mm_s <= safe_mm_s:
            return speed_mm_s
        why = (f"on a toolhead of up to {guard.stiffness_g_um:g} g/um sideways ([xy_probe] max_side_stiffness) "
               f"it could press the pin with up to {guard.peak_force_g(force_g, speed_mm_s):.0f}g, more than "
               f"force_safety_limit ({guard.force_safety_limit_g:g}g)")
        slowest = XY_PROBE_SPEED_MM_S[0]
        if safe_mm_s < slowest:
            raise gcmd.error(f"XY probing refused: even at {slowest:g} mm/s {why}; set max_side_stiffness "
                             f"to your toolhead's sideways stiffness if it is softer")
        safe_mm_s = max(slowest, float(int(safe_mm_s * 100.0)) / 100.0)
        if asked:
            raise gcmd.error(f"XY probing at {speed_mm_s:g} mm/s refused: {why}; probe at {safe_mm_s:g} mm/s "
                             f"or slower")
        gcmd.respond_info(f"XY probing at {safe_mm_s:g} mm/s, not {speed_mm_s:g}: {why}")
        return safe_mm_s

    def touch(self, prober: ThresholdProber, direction: tuple[float, float], distance_mm: float,
              speed_mm_s: float, force_g: float) -> tuple[float, float]:
        """Tare, then move `distance_mm` along `direction` until the force passes force_g; returns
        the nozzle X, Y at the triggering sample (GCodeError when nothing was touched)."""
        x0, y0, _ = prober.toolhead.get_position()
        tare = prober.tare("xy probe")
        hit = prober.probe_xy(tare, force_g, force_g / 2.0, x0 + direction[0] * distance_mm,
                              y0 + direction[1] * distance_mm, speed_mm_s)
        if not hit.triggered:
            raise GCodeError(f"XY probe: no contact within {distance_mm:g} mm from X={x0:.3f} Y={y0:.3f}")
        return hit.trigger_position_mm[0], hit.trigger_position_mm[1]

    def cmd_XY_PROBE(self, gcmd: GCodeCommand) -> None:
        name = gcmd.get_choice("DIRECTION", list(DIRECTIONS))
        distance = gcmd.get_float("DISTANCE", self.options.max_travel_mm, above=0.0, maxval=MAX_TRAVEL_MM)
        speed = gcmd.get_float("SPEED", self.options.speed_mm_s, minval=XY_PROBE_SPEED_MM_S[0],
                               maxval=XY_PROBE_SPEED_MM_S[1])
        force = gcmd.get_float("FORCE", self._threshold().value_g(XY), above=0.0, maxval=1000.0)
        prober = self._prober()
        speed = self.guarded_speed_mm_s(gcmd, prober, speed, force, asked=gcmd.has("SPEED"))
        x_start, y_start, _ = prober.toolhead.get_position()
        x_mm, y_mm = self.touch(prober, DIRECTIONS[name], distance, speed, force)
        # Back off to where the move started, so the nozzle does not keep pressing.
        prober.toolhead.move_to(x=x_start, y=y_start, speed_mm_s=speed)
        self.last_result = {"direction": name, "contact_x": x_mm, "contact_y": y_mm, "force_g": force}
        gcmd.respond_info(f"XY_PROBE: contact at X={x_mm:.4f} Y={y_mm:.4f} (moving {name}, {force:g} g)")

    def cmd_XY_PROBE_PIN(self, gcmd: GCodeCommand) -> None:
        opts = self.options
        x_nominal = gcmd.get_float("X", opts.pin_x_mm, **COORDINATE_RANGE)
        y_nominal = gcmd.get_float("Y", opts.pin_y_mm, **COORDINATE_RANGE)
        if x_nominal is None or y_nominal is None:
            raise gcmd.param_error("give X= and Y= (or pin_x, pin_y in [xy_probe])")
        z_mm = gcmd.get_float("Z", opts.probe_z_mm, **COORDINATE_RANGE)
        force = self._threshold().value_g(XY)
        prober = self._prober()
        speed = self.guarded_speed_mm_s(gcmd, prober, opts.speed_mm_s, force, asked=False)
        toolhead = prober.toolhead
        reach_mm = (opts.pin_diameter_mm + opts.nozzle_tip_diameter_mm) / 2.0 + opts.clearance_mm
        contacts = {}
        for name, (dx, dy) in DIRECTIONS.items():
            start = (x_nominal - dx * reach_mm, y_nominal - dy * reach_mm)
            toolhead.move_to(z=max(toolhead.get_position()[2], opts.safe_z_mm), speed_mm_s=opts.travel_speed_mm_s)
            toolhead.move_to(x=start[0], y=start[1], speed_mm_s=opts.travel_speed_mm_s)
            toolhead.move_to(z=z_mm, speed_mm_s=opts.travel_speed_mm_s)
            # Never further than the nominal centre: missing the pin by then means it is not there.
            contacts[name] = self.touch(prober, (dx, dy), reach_mm, speed, force)
            toolhead.move_to(x=start[0], y=start[1], speed_mm_s=speed)
        toolhead.move_to(z=opts.safe_z_mm, speed_mm_s=opts.travel_speed_mm_s)
        x_center = (contacts["+X"][0] + contacts["-X"][0]) / 2.0
        y_center = (contacts["+Y"][1] + contacts["-Y"][1]) / 2.0
        width_x = contacts["-X"][0] - contacts["+X"][0]
        width_y = contacts["-Y"][1] - contacts["+Y"][1]
        self.last_result = {"center_x": x_center, "center_y": y_center, "width_x": width_x, "width_y": width_y,
                            "offset_x": x_center - x_nominal, "offset_y": y_center - y_nominal, "force_g": force}
        gcmd.respond_info(
            f"XY_PROBE_PIN: pin centre at X={x_center:.4f} Y={y_center:.4f} "
            f"(offset from X={x_nominal:g} Y={y_nominal:g}: {x_center - x_nominal:+.4f}, {y_center - y_nominal:+.4f} mm)\n"
            f"apparent diameter (pin + nozzle tip, less the give at {force:g} g): "
            f"X {width_x:.4f} mm, Y {width_y:.4f} mm")

    def get_status(self, eventtime=None) -> dict:
        return {"last_result": self.last_result, "xy_threshold_g": self._threshold().value_g(XY)}


def load_config(section: ConfigSection, printer) -> XYProbe:
    return XYProbe(section, printer)
