"""Whether a mesh's zero reference lies where Z was homed.

A load cell homes Z on the bed itself, at the X/Y where G28 Z tapped (the datum): Z 0 is the bed
there. `zero_reference_position` / `relative_reference_index` shift the whole mesh so that it is 0
at another point. When the bed there is not as high as at the datum, every move is off by the
difference: lower by it when the reference point is higher, and `G1 Z0.2` presses the nozzle into
the bed (issue 19: 0.33 mm, 1,070 g on a tilted bed). The nozzle watch catches the press; this
check says why before it happens.
"""

from __future__ import annotations

# Differences below this are the mesh's own noise (a few µm) plus a margin: not reported.
TOLERANCE_MM = 0.02


def zero_reference_warning(mesh, reference_xy_mm: tuple[float, float] | None,
                           datum_xy_mm: tuple[float, float] | None) -> str | None:
    """The warning when the mesh's zero reference is not where the Z datum was taken and the bed
    differs there by more than TOLERANCE_MM (None otherwise, or when either point is unknown)."""
    if mesh is None or reference_xy_mm is None or datum_xy_mm is None:
        return None
    difference_mm = float(mesh.z_at(*reference_xy_mm)) - float(mesh.z_at(*datum_xy_mm))
    if abs(difference_mm) <= TOLERANCE_MM:
        return None
    way = "into the bed" if difference_mm > 0 else "above the bed"
    return (f"bed_mesh: the mesh's zero reference ({reference_xy_mm[0]:.1f}, {reference_xy_mm[1]:.1f}) is not where "
            f"Z was homed ({datum_xy_mm[0]:.1f}, {datum_xy_mm[1]:.1f}), and the bed there is {difference_mm:+.3f} mm "
            f"higher: every move is {abs(difference_mm):.3f} mm {way}. A load cell's Z 0 is the bed where it "
            "homed: remove zero_reference_position / relative_reference_index from [bed_mesh], or home Z at the "
            "reference point")
