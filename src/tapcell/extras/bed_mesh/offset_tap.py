"""The trigger-only methods' known offset, corrected from one analysed tap.

`two_pass` and `prusa` take each height where the force crossed a threshold (between two samples:
`tapcell.extras.load_cell_probe.trigger_crossing`): the nozzle is then already pressed into the
bed by the threshold's force over the bed's stiffness (on the virtual printer 23 and 38 um). Left in, the first layer at
`G1 Z0.2` is printed that much too low. So after the last point the mesh method taps once more
with `[load_cell_probe]`'s tap analysis (break contact: where the nozzle really touched) at the
probed point nearest the middle, and raises every point by the difference. The command says
what it found; the shape of the mesh is the method's own.
"""

from __future__ import annotations

import numpy as np

from tapcell.host.gcode import GCodeCommand
from tapcell.mesh.run import MeshProbeRun, mesh_travel_height_mm


def middle_point_index(points_xy_mm: np.ndarray) -> int:
    """The probed point nearest the middle of the points (the first of equals)."""
    xy = np.asarray(points_xy_mm, dtype=float)
    return int(np.argmin(np.hypot(*(xy - xy.mean(axis=0)).T)))


def corrected_by_a_tap(printer, options, gcmd: GCodeCommand, points_xy_mm: np.ndarray,
                       run: MeshProbeRun) -> MeshProbeRun:
    """`run` with every height raised by (tap analysis - trigger height) at the middle point, and
    a line saying so. Without a tap-analysing probe the run is kept and the line says what is left."""
    probe = printer.lookup_object("probe", None)
    method = (run.details or {}).get("method", "this method")
    if probe is None or not hasattr(probe, "session"):
        gcmd.respond_info(f"METHOD={method}: trigger-only heights, not corrected (no [load_cell_probe] to tap "
                          "with): the mesh sits a trigger's depth below the bed, so the first layer prints that "
                          "much low")
        return run
    toolhead = printer.lookup_object("toolhead")
    index = middle_point_index(points_xy_mm)
    x_mm, y_mm = (float(v) for v in points_xy_mm[index])
    z_offset = probe.options.z_offset_mm
    contacts = [(float(x), float(y), float(z) + z_offset) for (x, y), z in zip(points_xy_mm, run.z_mm)]
    approach_z = mesh_travel_height_mm(options, contacts, (x_mm, y_mm))
    if toolhead.get_position()[2] < approach_z:
        toolhead.move_to(z=approach_z, speed_mm_s=options.speed_mm_s)
    toolhead.move_to(x=x_mm - probe.options.x_offset_mm, y=y_mm - probe.options.y_offset_mm,
                     speed_mm_s=options.speed_mm_s)
    toolhead.move_to(z=approach_z, speed_mm_s=options.speed_mm_s)
    tapped_z = probe.probe_point(x_mm, y_mm).z_mm
    toolhead.move_to(z=max(toolhead.get_position()[2], approach_z), speed_mm_s=options.speed_mm_s)
    offset_mm = tapped_z - float(run.z_mm[index])
    line = (f"METHOD={method} offset: a tap at {x_mm:.1f},{y_mm:.1f} found the bed at Z={tapped_z:.4f}, the "
            f"trigger-only height there was {run.z_mm[index]:.4f}: every point raised by {offset_mm * 1000:+.1f} um "
            "(the trigger's depth into the bed)")
    details = {**(run.details or {}), "tap_offset_mm": offset_mm, "tap_offset_xy_mm": [x_mm, y_mm]}
    report = f"{run.report}\n{line}" if run.report else line
    return MeshProbeRun([float(z) + offset_mm for z in run.z_mm], report, details)


def with_tap_offset(method):
    """A trigger-only probing method whose heights come out corrected by one analysed tap."""
    def probe_points(printer, options, gcmd: GCodeCommand, points_xy_mm: np.ndarray, progress) -> MeshProbeRun:
        run = method(printer, options, gcmd, points_xy_mm, progress)
        return corrected_by_a_tap(printer, options, gcmd, points_xy_mm, run)

    probe_points.__doc__ = method.__doc__
    return probe_points
