"""The load-cell ABL paper's two-pass probing on the virtual printer (`BED_MESH_CALIBRATE METHOD=two_pass`).

At each point (`tapcell.mesh.abl.point_plan`): travel above it, a fast descent toward the
travel limit (the paper's Z-2: `[stepper_z] position_min`) until the load cell triggers (z1),
back off 1 mm, a slow descent at 8 mm/s (z2), lift 3 mm. The point's height is the paper's
weighted value 0.4 z1 + 0.6 z2. The trigger is the firmware trigger at the load cell probe's
`trigger_force`, tared before each pass; z1 and z2 are where the filtered force crossed it,
between the sample before the trigger and the triggering one (`ThresholdHit.crossing_z_mm`). The
paper took where the descent halted, which lands on the sample grid: the same spot read up to a
sample's travel apart with where in a conversion the contact fell. Reaching the travel limit
without contact stops the mesh with an error naming the point and the pass. After the last point
the topology report (extremes, range, tilt, flatness) is printed; moves then follow the mesh
(bilinear between probed points with `mesh_pps: 0`).

The paper's fast pass is 120 mm/s; a descent cannot be faster than the printer's
max_z_velocity, nor than the load cell probe's force guard allows (the fastest speed whose
worst-case overshoot stays within force_safety_limit), so it is clamped there (and the report
says so). Even so the fast pass moves ~50 um between two samples at 320 sps, over 1000 g on a
stiff toolhead: the firmware's drift_safety_limit would take that jump for drift, so it is off
for these passes (the paper has no such check); force_safety_limit still guards every pass.

Both heights are trigger-only, so each is checked: the force must hold after the halt like a
contact (else that descent is made again from where it stopped), the two passes of a point
must agree within `agreement_tolerance_mm` (else the point is probed again, up to
POINT_TRIES times), and a point far from its neighbours is probed again (`recheck_outliers`).
"""

from __future__ import annotations

import numpy as np

from tapcell.extras.load_cell_probe.options import tare_sample_count
from tapcell.extras.load_cell_probe.safety import agreement_tolerance_mm
from tapcell.extras.load_cell_probe.threshold import ThresholdProber
from tapcell.extras.probe.session import ProbeError
from tapcell.host.gcode import GCodeCommand, GCodeError
from tapcell.mesh.abl import NoContactError, PlanStep, TwoPassPoint, TwoPassSettings, run_two_pass, topology_report
from tapcell.mesh.outliers import recheck_outliers
from tapcell.mesh.report import render_topology
from tapcell.mesh.run import MeshProbeRun


# A descent whose force does not hold after the trigger is made again this many times at most;
# a point whose two passes disagree is probed this many times at most.
FALSE_TRIGGER_TRIES = 3
POINT_TRIES = 3
# The fast pass moves at most this far per sample. The crossing between two samples is a straight
# line; faster, the contact falls in the window before the trigger and bends it: on the virtual
# printer (320 sps) one spot read over sample phases spreads 1.3 um at 8 mm/s (25 um per sample),
# 5.6 um at max_z_velocity's 15 mm/s (47 um per sample), and 0.4 of the fast pass goes into each point.
FAST_PASS_MAX_UM_PER_SAMPLE = 25.0


def two_pass_settings(device, toolhead, travel_speed_mm_s: float) -> tuple[TwoPassSettings, str | None]:
    """The paper's settings on this printer: travel limit = position_min, fast pass clamped to
    max_z_velocity, to FAST_PASS_MAX_UM_PER_SAMPLE and to the fastest speed the force guard passes."""
    paper = TwoPassSettings()
    max_z_speed = toolhead.options.max_z_velocity_mm_s
    per_sample_speed = FAST_PASS_MAX_UM_PER_SAMPLE * device.sample_rate_sps / 1000.0
    params = two_pass_trigger_params(device)
    fastest = min(paper.fast_speed_mm_s, max_z_speed, per_sample_speed)
    fast = device.speed_guard.fastest_safe_mm_s(params, fastest)
    slow = min(paper.slow_speed_mm_s, max_z_speed)
    if fast is None:
        device.speed_guard.check(params, fastest)  # no speed is safe: raises and says why
    settings = TwoPassSettings(travel_limit_z_mm=toolhead.z_position_min(), fast_speed_mm_s=fast,
                               slow_speed_mm_s=min(slow, fast), travel_speed_mm_s=travel_speed_mm_s)
    note = None
    if settings.fast_speed_mm_s < paper.fast_speed_mm_s:
        if fast == max_z_speed:
            limit = "max_z_velocity"
        elif fast == per_sample_speed:
            limit = f"{FAST_PASS_MAX_UM_PER_SAMPLE:g} um per sample at {device.sample_rate_sps:g} samples/s"
        else:
            limit = "the force guard's limit for this sensor"
        note = (f"fast pass at {settings.fast_speed_mm_s:g} mm/s ({limit}; the paper moved its bed at "
                f"{paper.fast_speed_mm_s:g} mm/s)")
    return settings, note


def two_pass_trigger_params(device):
    """The paper has no drift check: the fast pass jumps more than drift_safety_limit per sample."""
    return device.trigger.move_params(device.config_settings, drift_safety_limit_g=0.0)


class TwoPassMover:
    """Performs the plan's steps on the virtual printer (the `move` of `run_two_pass`)."""

    def __init__(self, prober: ThresholdProber, trigger_force_g: float, tare_time_s: float):
        self.prober = prober
        self.toolhead = prober.toolhead
        self.trigger_force_g = trigger_force_g
        self.false_triggers = 0  # descents that triggered without the force of a contact
        self.tare_samples = tare_sample_count(tare_time_s, prober.device.sample_rate_sps)

    def __call__(self, step: PlanStep) -> float | None:
        toolhead = self.toolhead
        if step.kind == "travel":
            toolhead.move_to(x=step.x_mm, y=step.y_mm, speed_mm_s=step.speed_mm_s)
            return None
        if step.kind == "retract":
            toolhead.move_to(z=toolhead.get_position()[2] + step.z_mm, speed_mm_s=step.speed_mm_s)
            return None
        # The nozzle rests in the air after a travel or a back-off: tare there, then descend.
        for _ in range(FALSE_TRIGGER_TRIES):
            tare = self.prober.tare(f"two-pass {step.pass_name}", settle_s=0.0, sample_count=self.tare_samples)
            hit = self.prober.probe_z(tare, self.trigger_force_g, 0.0, step.z_mm, step.speed_mm_s,
                                      drift_safety_limit_g=0.0)
            if not hit.triggered:
                return None
            if hit.contact:
                return hit.crossing_z_mm
            self.false_triggers += 1  # not a contact: descend again from here
        raise ProbeError(f"BED_MESH_CALIBRATE METHOD=two_pass: the {step.pass_name} pass at {step.x_mm:.3f},"
                         f"{step.y_mm:.3f} triggered {FALSE_TRIGGER_TRIES} times without the force of a contact: "
                         "something pushes on the nozzle or the sensor jumps")


def probe_points_two_pass(printer, options, gcmd: GCodeCommand, points_xy_mm: np.ndarray, progress) -> MeshProbeRun:
    """BED_MESH_CALIBRATE METHOD=two_pass."""
    device = printer.lookup_object("load_cell_probe", None)
    if device is None:
        raise GCodeError("METHOD=two_pass needs a [load_cell_probe] section")
    prober = ThresholdProber(device)
    toolhead = prober.toolhead
    probe = printer.lookup_object("probe")
    with device.guarded():
        settings, note = two_pass_settings(device, toolhead, options.speed_mm_s)
        if note:
            gcmd.respond_info(note)
        mover = TwoPassMover(prober, device.options.trigger_force_g, device.options.tare_time_s)
        tolerance_mm = agreement_tolerance_mm(device.stop_timing, settings.fast_speed_mm_s, settings.slow_speed_mm_s)

        def probe_point(index: int) -> TwoPassPoint:
            """Both passes at one point until they agree (the point's own index in the report)."""
            for _ in range(POINT_TRIES):
                try:
                    (point,) = run_two_pass(points_xy_mm[index:index + 1], mover, settings)
                except NoContactError as exc:
                    toolhead.move_to(z=toolhead.get_position()[2] + settings.lift_mm,
                                     speed_mm_s=settings.travel_speed_mm_s)
                    raise GCodeError("BED_MESH_CALIBRATE METHOD=two_pass: " + str(NoContactError(
                        index, len(points_xy_mm), exc.x_mm, exc.y_mm, exc.pass_name, exc.travel_limit_z_mm))) from None
                if abs(point.z_fast_mm - point.z_slow_mm) <= tolerance_mm:
                    return TwoPassPoint(index, point.x_mm, point.y_mm, point.z_fast_mm, point.z_slow_mm, point.z_mm)
                gcmd.respond_info(f"Point {index + 1}: the passes disagree (fast {point.z_fast_mm:.3f}, slow "
                                  f"{point.z_slow_mm:.3f} mm; at most {tolerance_mm:.3f} mm apart): probing it again")
            raise ProbeError(f"BED_MESH_CALIBRATE METHOD=two_pass: the passes at point {index + 1} disagreed "
                             f"{POINT_TRIES} times: something pushes on the nozzle or the sensor jumps")

        if toolhead.get_position()[2] < options.horizontal_move_z_mm:
            toolhead.move_to(z=options.horizontal_move_z_mm, speed_mm_s=settings.travel_speed_mm_s)
        points = []  # each point ends lifted 3 mm above it: the travel to the next goes at that height
        for index in range(len(points_xy_mm)):
            points.append(probe_point(index))
            progress(index + 1, len(points_xy_mm))
        z_offset = probe.options.z_offset_mm

        def probe_again(index: int) -> float:
            points[index] = probe_point(index)
            return points[index].z_mm - z_offset

        z_mm = recheck_outliers(points_xy_mm, [point.z_mm - z_offset for point in points], probe_again,
                                tolerance_mm, gcmd.respond_info)
    xy = np.asarray(points_xy_mm, dtype=float)
    topology = topology_report(xy[:, 0], xy[:, 1], np.array(z_mm))
    details = {"method": "two_pass", "points": [p.to_status() for p in points], "topology": topology.to_status(),
               "fast_speed_mm_s": settings.fast_speed_mm_s, "slow_speed_mm_s": settings.slow_speed_mm_s,
               "false_triggers": mover.false_triggers}
    return MeshProbeRun(z_mm, render_topology(points, topology), details)
