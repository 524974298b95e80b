"""The probing methods of BED_MESH_CALIBRATE, by METHOD= name.

A method is `probe_points(printer, options, gcmd, points_xy_mm, progress) -> MeshProbeRun`:
it probes every point (probing order) and calls `progress(done, total)` after each. The
trigger-only methods (`two_pass`, `prusa`) end with one analysed tap that corrects their known
offset (`tapcell.extras.bed_mesh.offset_tap`).
"""

from __future__ import annotations

from tapcell.extras.bed_mesh.offset_tap import with_tap_offset
from tapcell.extras.bed_mesh.prusa import probe_points_prusa
from tapcell.extras.bed_mesh.tap import probe_points_by_tapping
from tapcell.extras.bed_mesh.two_pass import probe_points_two_pass

METHODS = {
    "tap": probe_points_by_tapping,
    "two_pass": with_tap_offset(probe_points_two_pass),
    "prusa": with_tap_offset(probe_points_prusa),
}
