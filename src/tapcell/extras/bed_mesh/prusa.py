"""`BED_MESH_CALIBRATE METHOD=prusa`: Prusa-matched thresholds and tare plan (`[prusa_probe]`)."""

from __future__ import annotations

import numpy as np

from tapcell.extras.prusa_probe import SECTION
from tapcell.host.gcode import GCodeCommand, GCodeError


def probe_points_prusa(printer, options, gcmd: GCodeCommand, points_xy_mm: np.ndarray, progress):
    """BED_MESH_CALIBRATE METHOD=prusa."""
    prusa = printer.lookup_object(SECTION, None)
    if prusa is None:
        raise GCodeError("METHOD=prusa needs a [prusa_probe] section")
    return prusa.probe_mesh_points(options, gcmd, points_xy_mm, progress)
