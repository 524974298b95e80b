"""`[prusa_probe]`: the Prusa-matched probing mode (spec: prusa-thresholds.md).

Instead of analysing the shape of a tap, Prusa's firmware trusts a force threshold:

* separate thresholds for Z fast, Z slow, mesh and XY probing (125 / 125 / 125 / 40 g), each
  armed on the firmware trigger with hysteresis (Z and mesh release 80 g lower, at 45 g;
  XY at half its threshold);
* a context-dependent tare, each one 300 ms of settling and 48 samples: Z probing
  (`LOADCELL_PROBE`) tares twice, a mesh tares once for the session reference and once per
  point (1 + N tares for N points);
* at each mesh point the tare is compared with the session reference: more than 125 g apart
  means something pulls on the nozzle, so lift 20 mm and tare again (the new reference);
* a mesh point that does not give a trigger is retried on rings 2 mm apart, at most 40 times.

The Z of a threshold probe is the toolhead Z where the filtered force crossed the threshold,
between the sample before the trigger and the triggering one (`ThresholdHit.crossing_z_mm`),
from the probing move's own trapezoids: a stepper position latched by an endstop at the
triggering sample would move by up to a sample's travel with where in a conversion the contact
fell.

Commands: PROBE_THRESHOLDS (alias SHOW_THRESHOLDS), SET_Z_FAST_THRESHOLD, SET_Z_SLOW_THRESHOLD,
SET_MESH_THRESHOLD, SET_XY_THRESHOLD (aliases SET_Z_FAST, SET_Z_SLOW, SET_MESH, SET_XY; all
take VALUE=grams), LOADCELL_PROBE. `BED_MESH_CALIBRATE METHOD=prusa` uses this mode.

The tares and threshold probing moves are `tapcell.extras.load_cell_probe.threshold`'s
`ThresholdProber`, shared with the two-pass ABL and XY probing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tapcell.host.config import ConfigSection
from tapcell.host.gcode import GCodeCommand, GCodeError
from tapcell.mesh.errors import MeshError
from tapcell.mesh.outliers import recheck_outliers
from tapcell.mesh.run import MeshProbeRun, mesh_travel_height_mm
from tapcell.mesh.prusa import (
    MAX_THRESHOLD_G,
    MESH,
    SET_COMMANDS,
    XY,
    Z_FAST,
    Z_SLOW,
    Thresholds,
    check_tare_deviation,
    retry_offsets_mm,
)
from tapcell.extras.load_cell_probe.safety import agreement_tolerance_mm
from tapcell.extras.load_cell_probe.threshold import ThresholdHit, ThresholdProber, TareRecord
from tapcell.extras.probe.options import MAX_RETRACT_MM, PROBE_SPEED_MM_S
from tapcell.extras.probe.session import ProbeError

SECTION = "prusa_probe"
THRESHOLD_OPTIONS = {Z_FAST: "z_fast_threshold", Z_SLOW: "z_slow_threshold", MESH: "mesh_threshold",
                     XY: "xy_threshold"}
THRESHOLD_LABELS = {Z_FAST: "Z fast", Z_SLOW: "Z slow", MESH: "Mesh", XY: "XY"}
# Mainsail buttons of the spec, same handlers.
ALIASES = {"SET_Z_FAST_THRESHOLD": "SET_Z_FAST", "SET_Z_SLOW_THRESHOLD": "SET_Z_SLOW",
           "SET_MESH_THRESHOLD": "SET_MESH", "SET_XY_THRESHOLD": "SET_XY"}


# -- the [prusa_probe] object -------------------------------------------------------------------

@dataclass(frozen=True)
class PrusaOptions:
    thresholds: Thresholds
    z_fast_speed_mm_s: float
    z_slow_speed_mm_s: float
    back_off_mm: float
    max_attempts: int


def read_prusa_options(section: ConfigSection) -> PrusaOptions:
    defaults = Thresholds()
    hysteresis = section.getfloat("hysteresis", defaults.hysteresis_g, minval=0.0, below=MAX_THRESHOLD_G)
    thresholds = Thresholds(hysteresis_g=hysteresis)
    for kind, option in THRESHOLD_OPTIONS.items():
        value = section.getfloat(option, defaults.value_g(kind), above=0.0, maxval=MAX_THRESHOLD_G)
        try:
            thresholds = thresholds.with_threshold(kind, value)
        except MeshError as exc:
            problem = str(exc).split(": ", 1)[1]
            raise section.error(option, problem) from None
    return PrusaOptions(
        thresholds=thresholds,
        z_fast_speed_mm_s=section.getfloat("z_fast_speed", 5.0, minval=PROBE_SPEED_MM_S[0],
                                           maxval=PROBE_SPEED_MM_S[1]),
        z_slow_speed_mm_s=section.getfloat("z_slow_speed", 1.0, minval=PROBE_SPEED_MM_S[0],
                                           maxval=PROBE_SPEED_MM_S[1]),
        back_off_mm=section.getfloat("back_off", 0.5, above=0.0, maxval=MAX_RETRACT_MM),
        max_attempts=section.getint("max_attempts", 40, minval=1, maxval=40),
    )


class PrusaProbe:
    """Thresholds, their commands, LOADCELL_PROBE and the mesh method `prusa`."""

    def __init__(self, section: ConfigSection, printer):
        self.printer = printer
        self.section_name = section.get_name()
        options = read_prusa_options(section)
        self.thresholds = options.thresholds
        self.options = options
        self.last_session: dict | None = None
        gcode = printer.gcode
        gcode.register_command("PROBE_THRESHOLDS", self.cmd_PROBE_THRESHOLDS, desc="Show the probe thresholds")
        gcode.register_command("SHOW_THRESHOLDS", self.cmd_PROBE_THRESHOLDS, desc="Show the probe thresholds")
        for kind, command in SET_COMMANDS.items():
            handler = self._set_threshold_handler(kind)
            desc = f"Set the {THRESHOLD_LABELS[kind]} probe threshold: VALUE=grams"
            gcode.register_command(command, handler, desc=desc)
            gcode.register_command(ALIASES[command], handler, desc=desc)
        gcode.register_command("LOADCELL_PROBE", self.cmd_LOADCELL_PROBE,
                               desc="Probe Z here with the Z fast and Z slow thresholds (double tare)")

    def prober(self) -> ThresholdProber:
        device = self.printer.lookup_object("load_cell_probe", None)
        if device is None:
            raise GCodeError(f"[{self.section_name}] needs a [load_cell_probe] section")
        return ThresholdProber(device)

    # -- thresholds ----------------------------------------------------------------------------
    def describe_thresholds(self) -> str:
        lines = ["Probe thresholds (grams of force on the nozzle):"]
        for kind, label in THRESHOLD_LABELS.items():
            lines.append(f"  {label + ':':<8}{self.thresholds.value_g(kind):g} g "
                         f"(releases at {self.thresholds.release_g(kind):g} g)")
        return "\n".join(lines)

    def cmd_PROBE_THRESHOLDS(self, gcmd: GCodeCommand) -> None:
        gcmd.respond_info(self.describe_thresholds())

    def _set_threshold_handler(self, kind: str):
        def handler(gcmd: GCodeCommand) -> None:
            value_g = gcmd.get_float("VALUE", above=0.0, maxval=MAX_THRESHOLD_G)
            try:
                self.thresholds = self.thresholds.with_threshold(kind, value_g)
            except MeshError as exc:
                raise gcmd.param_error(str(exc)) from None
            self.printer.config.set(self.section_name, THRESHOLD_OPTIONS[kind], f"{value_g:g}")
            gcmd.respond_info(f"{THRESHOLD_LABELS[kind]} threshold set to {value_g:g} g (releases at "
                              f"{self.thresholds.release_g(kind):g} g); SAVE_CONFIG keeps it")

        return handler

    # -- Z probing -------------------------------------------------------------------------------
    def cmd_LOADCELL_PROBE(self, gcmd: GCodeCommand) -> None:
        """Fast pass, back off, slow pass; the slow pass must find the fast pass's height (a
        trigger-only result counts only when a second, slower one agrees) and both must hold."""
        prober = self.prober()
        toolhead = prober.toolhead
        if not toolhead.is_z_homed():
            raise gcmd.error("Must home before probe (run G28)")
        z_min = toolhead.z_position_min()
        t = self.thresholds
        with prober.device.guarded():
            prober.tare("z probe, first tare")
            tare = prober.tare("z probe, second tare")
            fast = prober.probe_z(tare, t.z_fast_g, t.release_g(Z_FAST), z_min, self.options.z_fast_speed_mm_s)
            self._require_contact(fast, "fast", z_min)
            toolhead.move_to(z=fast.halt_position_mm[2] + self.options.back_off_mm, speed_mm_s=self.options.z_slow_speed_mm_s)
            slow = prober.probe_z(tare, t.z_slow_g, t.release_g(Z_SLOW), z_min, self.options.z_slow_speed_mm_s)
            self._require_contact(slow, "slow", z_min)
            tolerance_mm = agreement_tolerance_mm(prober.device.stop_timing, self.options.z_fast_speed_mm_s,
                                                  self.options.z_slow_speed_mm_s)
            if abs(slow.crossing_z_mm - fast.crossing_z_mm) > tolerance_mm:
                raise ProbeError(f"LOADCELL_PROBE: the slow pass found the bed at Z={slow.crossing_z_mm:.3f}, "
                                 f"the fast pass at Z={fast.crossing_z_mm:.3f} (more than {tolerance_mm:.3f} mm "
                                 "apart): something pushed on the nozzle; run it again")
            toolhead.move_to(z=slow.halt_position_mm[2] + self.options.back_off_mm,
                             speed_mm_s=self.options.z_slow_speed_mm_s)
        z_offset = self.printer.lookup_object("probe").options.z_offset_mm
        result = slow.crossing_z_mm - z_offset
        self.last_session = {"kind": "z", "tares": len(prober.tares), "z_mm": result,
                             "fast_z_mm": fast.crossing_z_mm - z_offset}
        gcmd.respond_info(f"LOADCELL_PROBE: z={result:.6f} (fast pass {fast.crossing_z_mm - z_offset:.6f}, "
                          f"thresholds {t.z_fast_g:g} / {t.z_slow_g:g} g, {len(prober.tares)} tares)")

    @staticmethod
    def _require_contact(hit: ThresholdHit, pass_name: str, z_min_mm: float) -> None:
        if not hit.triggered:
            raise ProbeError(f"LOADCELL_PROBE: no contact on the {pass_name} pass before the travel limit "
                             f"Z={z_min_mm:.3f}")
        if not hit.contact:
            raise ProbeError(f"LOADCELL_PROBE: the {pass_name} pass triggered at Z={hit.trigger_position_mm[2]:.3f} "
                             "but the force did not hold like a contact (a glitch or a push on the nozzle); run it "
                             "again")

    # -- the mesh method -------------------------------------------------------------------------
    def probe_mesh_points(self, options, gcmd: GCodeCommand, points_xy_mm: np.ndarray, progress):
        """Every point: tare (against the session reference), threshold probe, retried on rings
        around it when there is no contact or the force does not hold after the trigger. Then the
        point furthest from its neighbours is probed again until two probes agree
        (`recheck_outliers`): a push on the nozzle in the air never becomes a mesh point."""
        prober = self.prober()
        toolhead = prober.toolhead
        probe = self.printer.lookup_object("probe")
        z_offset, speed = probe.options.z_offset_mm, probe.options.speed_mm_s
        z_min = toolhead.z_position_min()
        t = self.thresholds
        offsets = retry_offsets_mm(self.options.max_attempts)
        reference: TareRecord | None = None
        retares = attempts = 0

        def probe_point(index: int, travel_z: float) -> float:
            nonlocal reference, retares, attempts
            x_mm, y_mm = points_xy_mm[index]
            for attempt, (dx, dy) in enumerate(offsets, start=1):
                attempts += 1
                if toolhead.get_position()[2] < travel_z:
                    toolhead.move_to(z=travel_z, speed_mm_s=speed)
                toolhead.move_to(x=float(x_mm + dx), y=float(y_mm + dy), speed_mm_s=options.speed_mm_s)
                tare = prober.tare(f"mesh point {index + 1}")
                check = check_tare_deviation(tare.force_g, reference.force_g)
                if check.action == "lift_and_retare":
                    gcmd.respond_info(f"Point {index + 1}: tare is {check.deviation_g:+.0f} g from the session "
                                      f"reference (limit 125 g): lifting {check.lift_mm:g} mm and taring again")
                    z_here = toolhead.get_position()[2]
                    toolhead.move_to(z=z_here + check.lift_mm, speed_mm_s=speed)
                    tare = reference = prober.tare(f"mesh point {index + 1}, re-tare")
                    toolhead.move_to(z=z_here, speed_mm_s=speed)
                    retares += 1
                hit = prober.probe_z(tare, t.mesh_g, t.release_g(MESH), z_min, speed)
                if hit.triggered and hit.contact:
                    return hit.crossing_z_mm - z_offset
                why = (f"no contact before Z={z_min:.3f}" if not hit.triggered else
                       f"triggered at Z={hit.trigger_position_mm[2]:.3f} but the force did not hold like a contact")
                gcmd.respond_info(f"Point {index + 1}: {why} (attempt {attempt} of {len(offsets)})")
            raise ProbeError(f"Mesh point {index + 1} at {x_mm:.3f},{y_mm:.3f}: no contact after "
                             f"{len(offsets)} attempts")

        with prober.device.guarded():
            reference = prober.tare("session reference")
            z_values = []
            contacts_xyz = []  # where the nozzle touched (toolhead Z): the travel height follows the bed
            for index, (x_mm, y_mm) in enumerate(points_xy_mm):
                travel_z = mesh_travel_height_mm(options, contacts_xyz, (float(x_mm), float(y_mm)))
                z_values.append(probe_point(index, travel_z))
                contacts_xyz.append((float(x_mm), float(y_mm), z_values[-1] + z_offset))
                progress(index + 1, len(points_xy_mm))
            tolerance_mm = agreement_tolerance_mm(prober.device.stop_timing, speed)
            z_values = recheck_outliers(points_xy_mm, z_values,
                                        lambda index: probe_point(index, options.horizontal_move_z_mm),
                                        tolerance_mm, gcmd.respond_info)
            toolhead.move_to(z=max(toolhead.get_position()[2], options.horizontal_move_z_mm), speed_mm_s=speed)
        self.last_session = {"kind": "mesh", "points": len(points_xy_mm), "tares": len(prober.tares),
                             "retares": retares, "attempts": attempts}
        report = (f"Prusa-matched mesh: threshold {t.mesh_g:g} g, {len(prober.tares)} tares for "
                  f"{len(points_xy_mm)} points ({retares} re-tares), {attempts} attempts")
        return MeshProbeRun(z_values, report, {"method": "prusa", **self.last_session})

    def get_status(self, eventtime=None) -> dict:
        return {"thresholds": self.thresholds.to_status(), "last_session": self.last_session}


def load_config(section: ConfigSection, printer) -> PrusaProbe:
    return PrusaProbe(section, printer)
