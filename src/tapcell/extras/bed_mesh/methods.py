"""The probing methods of BED_MESH_CALIBRATE, by METHOD= name.

A method is `probe_points(printer, options, gcmd, points_xy_mm, progress) -> MeshProbeRun`:
it probes every point (probing order) and calls `progress(done, total)` after each.
"""

from __future__ import annotations

from tapcell.extras.bed_mesh.prusa import probe_points_prusa
from tapcell.extras.bed_mesh.tap import probe_points_by_tapping
from tapcell.extras.bed_mesh.two_pass import probe_points_two_pass

METHODS = {
    "tap": probe_points_by_tapping,
    "two_pass": probe_points_two_pass,
    "prusa": probe_points_prusa,
}
