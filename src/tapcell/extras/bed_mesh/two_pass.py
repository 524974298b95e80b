"""The load-cell ABL paper's two-pass probing on the virtual printer (`BED_MESH_CALIBRATE METHOD=two_pass`).

At each point (`tapcell.mesh.abl.point_plan`): travel above it, a fast descent toward the
travel limit (the paper's Z-2: `[stepper_z] position_min`) until the load cell triggers (z1),
back off 1 mm, a slow descent at 8 mm/s (z2), lift 3 mm. The point's height is the paper's
weighted value 0.4 z1 + 0.6 z2. z1 and z2 are where the descent halted, as in the paper; the
trigger is the firmware trigger at the load cell probe's `trigger_force`, tared before each
pass. Reaching the travel limit without contact stops the mesh with an error naming the point
and the pass. After the last point the topology report (extremes, range, tilt, flatness) is
printed; moves then follow the mesh (bilinear between probed points with `mesh_pps: 0`).

The paper's fast pass is 120 mm/s; a descent cannot be faster than the printer's
max_z_velocity, so it is clamped there (and the report says so). Even so the fast pass
moves ~50 um between two samples at 320 sps, over 1000 g on a stiff toolhead: the
firmware's drift_safety_limit would take that jump for drift, so it is off for these
passes (the paper has no such check); force_safety_limit still guards every pass.
"""

from __future__ import annotations

import numpy as np

from tapcell.host.gcode import GCodeCommand, GCodeError
from tapcell.extras.load_cell_probe.options import tare_sample_count
from tapcell.mesh.abl import NoContactError, PlanStep, TwoPassSettings, run_two_pass, topology_report
from tapcell.mesh.report import render_topology
from tapcell.mesh.run import MeshProbeRun
from tapcell.extras.load_cell_probe.threshold import ThresholdProber


def two_pass_settings(toolhead, travel_speed_mm_s: float) -> tuple[TwoPassSettings, str | None]:
    """The paper's settings on this printer: travel limit = position_min, fast pass clamped."""
    paper = TwoPassSettings()
    max_z_speed = toolhead.options.max_z_velocity_mm_s
    settings = TwoPassSettings(travel_limit_z_mm=toolhead.z_position_min(),
                               fast_speed_mm_s=min(paper.fast_speed_mm_s, max_z_speed),
                               slow_speed_mm_s=min(paper.slow_speed_mm_s, max_z_speed),
                               travel_speed_mm_s=travel_speed_mm_s)
    note = None
    if settings.fast_speed_mm_s < paper.fast_speed_mm_s:
        note = (f"fast pass at {settings.fast_speed_mm_s:g} mm/s (max_z_velocity; the paper moved its bed at "
                f"{paper.fast_speed_mm_s:g} mm/s)")
    return settings, note


class TwoPassMover:
    """Performs the plan's steps on the virtual printer (the `move` of `run_two_pass`)."""

    def __init__(self, prober: ThresholdProber, trigger_force_g: float, tare_time_s: float,
                 progress, point_count: int):
        self.prober = prober
        self.toolhead = prober.toolhead
        self.trigger_force_g = trigger_force_g
        self.tare_samples = tare_sample_count(tare_time_s, prober.device.sample_rate_sps)
        self.progress = progress
        self.point_count = point_count
        self.points_done = 0

    def __call__(self, step: PlanStep) -> float | None:
        toolhead = self.toolhead
        if step.kind == "travel":
            toolhead.move_to(x=step.x_mm, y=step.y_mm, speed_mm_s=step.speed_mm_s)
            return None
        if step.kind == "retract":
            toolhead.move_to(z=toolhead.get_position()[2] + step.z_mm, speed_mm_s=step.speed_mm_s)
            if step.z_mm > 1.0:  # the lift after the slow pass ends the point
                self.points_done += 1
                self.progress(self.points_done, self.point_count)
            return None
        # The nozzle rests in the air after a travel or a back-off: tare there, then descend.
        tare = self.prober.tare(f"two-pass {step.pass_name}", settle_s=0.0, sample_count=self.tare_samples)
        hit = self.prober.probe_z(tare, self.trigger_force_g, 0.0, step.z_mm, step.speed_mm_s,
                                  drift_safety_limit_g=0.0)
        return hit.halt_position_mm[2] if hit.triggered else None


def probe_points_two_pass(printer, options, gcmd: GCodeCommand, points_xy_mm: np.ndarray, progress) -> MeshProbeRun:
    """BED_MESH_CALIBRATE METHOD=two_pass."""
    device = printer.lookup_object("load_cell_probe", None)
    if device is None:
        raise GCodeError("METHOD=two_pass needs a [load_cell_probe] section")
    prober = ThresholdProber(device)
    toolhead = prober.toolhead
    probe = printer.lookup_object("probe")
    settings, note = two_pass_settings(toolhead, options.speed_mm_s)
    if note:
        gcmd.respond_info(note)
    if toolhead.get_position()[2] < options.horizontal_move_z_mm:
        toolhead.move_to(z=options.horizontal_move_z_mm, speed_mm_s=settings.travel_speed_mm_s)
    mover = TwoPassMover(prober, device.options.trigger_force_g, device.options.tare_time_s, progress,
                         len(points_xy_mm))
    try:
        points = run_two_pass(points_xy_mm, mover, settings)
    except NoContactError as exc:
        toolhead.move_to(z=toolhead.get_position()[2] + settings.lift_mm, speed_mm_s=settings.travel_speed_mm_s)
        raise GCodeError(f"BED_MESH_CALIBRATE METHOD=two_pass: {exc}") from None
    z_offset = probe.options.z_offset_mm
    z_mm = [point.z_mm - z_offset for point in points]
    xy = np.asarray(points_xy_mm, dtype=float)
    topology = topology_report(xy[:, 0], xy[:, 1], np.array(z_mm))
    details = {"method": "two_pass", "points": [p.to_status() for p in points], "topology": topology.to_status(),
               "fast_speed_mm_s": settings.fast_speed_mm_s, "slow_speed_mm_s": settings.slow_speed_mm_s}
    return MeshProbeRun(z_mm, render_topology(points, topology), details)
