"""`BED_MESH_CALIBRATE METHOD=tap` (the default): the load-cell probe's tap analysis at every point."""

from __future__ import annotations

import numpy as np

from tapcell.host.gcode import GCodeCommand, GCodeError

from tapcell.mesh.run import MeshProbeRun, Progress, mesh_travel_height_mm


def probe_points_by_tapping(printer, options, gcmd: GCodeCommand,
                            points_xy_mm: np.ndarray, progress: Progress) -> MeshProbeRun:
    """The `tap` method: one probe session (with the command's overrides) over every point of the
    command's `options` (BedMeshOptions).

    Between points the nozzle lifts to `horizontal_move_z`, or with `horizontal_z_clearance`
    only that much above the bed on the way to the next point (`mesh_travel_height_mm`).
    """
    probe = printer.lookup_object("probe", None)
    if probe is None:
        raise GCodeError("BED_MESH_CALIBRATE needs a probe: add a [load_cell_probe] section")
    toolhead = printer.lookup_object("toolhead")
    x_offset, y_offset = probe.options.x_offset_mm, probe.options.y_offset_mm
    z_values = []
    attempts = []
    contacts_xyz: list[tuple[float, float, float]] = []  # where the nozzle touched (toolhead Z)
    with probe.session(gcmd) as session:
        lift_speed = session.options.effective_lift_speed_mm_s
        for index, (x_mm, y_mm) in enumerate(points_xy_mm):
            travel_z = mesh_travel_height_mm(options, contacts_xyz, (float(x_mm), float(y_mm)))
            if toolhead.get_position()[2] < travel_z:
                toolhead.move_to(z=travel_z, speed_mm_s=lift_speed)
            toolhead.move_to(x=float(x_mm) - x_offset, y=float(y_mm) - y_offset, speed_mm_s=options.speed_mm_s)
            result = session.probe_point(float(x_mm), float(y_mm))
            z_values.append(result.z_mm)
            attempts.append(result.attempts)
            contacts_xyz.append((result.tapped_x_mm, result.tapped_y_mm, result.z_mm + session.options.z_offset_mm))
            progress(index + 1, len(points_xy_mm))
        toolhead.move_to(z=max(toolhead.get_position()[2], mesh_travel_height_mm(options, contacts_xyz, None)),
                         speed_mm_s=lift_speed)
    extra = sum(attempts) - len(attempts)
    report = f"{len(attempts)} points, {sum(attempts)} taps" + (f" ({extra} retried)" if extra else "")
    return MeshProbeRun(z_values, report, {"method": "tap", "taps": int(sum(attempts))})
