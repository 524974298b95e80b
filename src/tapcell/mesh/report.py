"""Reports of a mesh for people: text tables, error against a known bed, heat-map PNGs.

The text functions return strings (the G-code layer prints them as responses); the PNG
writer uses matplotlib's object API, so no display or global pyplot state is involved.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tapcell.mesh.abl import TopologyReport, TwoPassPoint
from tapcell.mesh.errors import MeshError
from tapcell.mesh.zmesh import ZMesh

# Bed height in mm at arrays of x, y (mm): the truth a simulated bed is built from.
TruthFn = Callable[[np.ndarray, np.ndarray], np.ndarray]


def render_mesh(mesh: ZMesh) -> str:
    """The BED_MESH_OUTPUT text: probed heights laid out like the bed seen from above."""
    grid, interpolation = mesh.grid, mesh.interpolation
    probed = mesh.probed_matrix_mm
    x_positions, y_positions = grid.x_positions_mm(), grid.y_positions_mm()
    lines = [
        f"Mesh '{mesh.profile_name}': {grid.x_count} x {grid.y_count} probed points, "
        f"X {grid.min_x_mm:.1f} .. {grid.max_x_mm:.1f} mm, Y {grid.min_y_mm:.1f} .. {grid.max_y_mm:.1f} mm",
        "Probed bed height in mm (back of the bed at the top, front at the bottom):",
        "   Y \\ X " + "".join(f"{x:>9.1f}" for x in x_positions),
    ]
    for row in range(grid.y_count - 1, -1, -1):
        lines.append(f"{y_positions[row]:>8.1f} " + "".join(f"{z:>9.4f}" for z in probed[row]))
    low, high = float(probed.min()), float(probed.max())
    lines.append(f"Lowest {low:.4f} mm, highest {high:.4f} mm: the bed varies by {high - low:.4f} mm")
    mesh_rows, mesh_columns = mesh.mesh_matrix_mm.shape
    if interpolation.algorithm == "direct":
        lines.append("Moves follow the probed points directly (bilinear between them)")
    else:
        lines.append(
            f"Interpolation: {interpolation.algorithm}, {interpolation.mesh_x_pps}, {interpolation.mesh_y_pps} "
            f"points between probed points -> {mesh_columns} x {mesh_rows} mesh points"
        )
    if mesh.zero_reference_offset_mm != 0.0:
        lines.append(f"Shifted by {-mesh.zero_reference_offset_mm:+.4f} mm so the zero reference position is at Z 0")
    return "\n".join(lines)


@dataclass(frozen=True)
class MeshErrorSummary:
    """How far a mesh is from the true bed, in micrometres."""

    max_abs_at_probed_um: float
    rms_at_probed_um: float
    max_abs_over_area_um: float
    rms_over_area_um: float
    worst_over_area_xy_mm: tuple[float, float]

    def to_status(self) -> dict:
        return {
            "max_abs_at_probed_um": self.max_abs_at_probed_um,
            "rms_at_probed_um": self.rms_at_probed_um,
            "max_abs_over_area_um": self.max_abs_over_area_um,
            "rms_over_area_um": self.rms_over_area_um,
            "worst_over_area_xy_mm": list(self.worst_over_area_xy_mm),
        }


def _area_grid(mesh: ZMesh, samples_per_axis: int) -> tuple[np.ndarray, np.ndarray]:
    if samples_per_axis < 2:
        raise MeshError(f"error map needs at least 2 samples per axis, got {samples_per_axis}")
    grid = mesh.grid
    return np.meshgrid(
        np.linspace(grid.min_x_mm, grid.max_x_mm, samples_per_axis),
        np.linspace(grid.min_y_mm, grid.max_y_mm, samples_per_axis),
    )


def mesh_error(mesh: ZMesh, truth_z_mm: TruthFn, samples_per_axis: int = 101) -> MeshErrorSummary:
    """Mesh minus truth at the probed points and on a dense grid over the whole mesh area."""
    probed_x, probed_y = np.meshgrid(mesh.grid.x_positions_mm(), mesh.grid.y_positions_mm())
    at_probed_um = (mesh.probed_matrix_mm - truth_z_mm(probed_x, probed_y)) * 1000.0
    area_x, area_y = _area_grid(mesh, samples_per_axis)
    over_area_um = (mesh.z_at(area_x, area_y) - truth_z_mm(area_x, area_y)) * 1000.0
    worst = np.unravel_index(np.argmax(np.abs(over_area_um)), over_area_um.shape)
    return MeshErrorSummary(
        max_abs_at_probed_um=float(np.max(np.abs(at_probed_um))),
        rms_at_probed_um=float(np.sqrt(np.mean(at_probed_um**2))),
        max_abs_over_area_um=float(np.max(np.abs(over_area_um))),
        rms_over_area_um=float(np.sqrt(np.mean(over_area_um**2))),
        worst_over_area_xy_mm=(float(area_x[worst]), float(area_y[worst])),
    )


def render_mesh_error(summary: MeshErrorSummary) -> str:
    x_mm, y_mm = summary.worst_over_area_xy_mm
    return "\n".join(
        [
            "Mesh compared with the true bed (1 um = 0.001 mm):",
            f"  at the probed points: largest error {summary.max_abs_at_probed_um:.2f} um, "
            f"typical (RMS) {summary.rms_at_probed_um:.2f} um  <- how well the probe measured",
            f"  everywhere in between: largest error {summary.max_abs_over_area_um:.2f} um at "
            f"X {x_mm:.1f} Y {y_mm:.1f}, typical (RMS) {summary.rms_over_area_um:.2f} um  "
            "<- what interpolation misses between points",
        ]
    )


def render_topology(points: Sequence[TwoPassPoint], topology: TopologyReport) -> str:
    """The two-pass ABL result: per-point passes and weighting, then the bed summary."""
    lines = [
        "Bed topology (two-pass probing, Z = 0.4 * fast + 0.6 * slow):",
        "  point        X        Y   fast z1   slow z2  weighted",
    ]
    for point in points:
        lines.append(
            f"  {point.index + 1:>5} {point.x_mm:>8.1f} {point.y_mm:>8.1f} {point.z_fast_mm:>9.3f} "
            f"{point.z_slow_mm:>9.3f} {point.z_mm:>9.3f}"
        )
    t = topology
    lines += [
        f"  lowest {t.min_z_mm:.3f} mm at ({t.min_at_xy_mm[0]:.1f}, {t.min_at_xy_mm[1]:.1f}), "
        f"highest {t.max_z_mm:.3f} mm at ({t.max_at_xy_mm[0]:.1f}, {t.max_at_xy_mm[1]:.1f}), "
        f"range {t.range_mm:.3f} mm, mean {t.mean_z_mm:.3f} mm",
        f"  tilt: {t.tilt_x_mm_per_mm * 100:+.3f} mm per 100 mm in X, {t.tilt_y_mm_per_mm * 100:+.3f} mm per 100 mm "
        f"in Y ({t.tilt_deg:.3f} deg)",
        f"  after removing the tilt the bed is flat within {t.flatness_after_tilt_mm:.3f} mm "
        f"(RMS {t.residual_rms_mm:.3f} mm)",
    ]
    return "\n".join(lines)


def write_mesh_png(path: str | Path, mesh: ZMesh, truth_z_mm: TruthFn | None = None, samples_per_axis: int = 101) -> Path:
    """Heat map of the mesh (and of mesh - truth, when the truth is known) as a PNG."""
    from matplotlib.figure import Figure  # imported here: only this function needs matplotlib

    area_x, area_y = _area_grid(mesh, samples_per_axis)
    panels = [("Mesh: bed height (um)", mesh.z_at(area_x, area_y) * 1000.0, "viridis")]
    if truth_z_mm is not None:
        panels.append(
            ("Mesh - true bed (um)", (mesh.z_at(area_x, area_y) - truth_z_mm(area_x, area_y)) * 1000.0, "coolwarm")
        )
    grid = mesh.grid
    extent = (grid.min_x_mm, grid.max_x_mm, grid.min_y_mm, grid.max_y_mm)
    probed = grid.probe_points_mm()
    figure = Figure(figsize=(5.5 * len(panels), 4.8), layout="constrained")
    for number, (title, values_um, colormap) in enumerate(panels, start=1):
        axes = figure.add_subplot(1, len(panels), number)
        if colormap == "coolwarm":
            # Symmetric limits so zero error is the neutral colour.
            limit = max(float(np.max(np.abs(values_um))), 1e-9)
            image = axes.imshow(values_um, origin="lower", extent=extent, cmap=colormap, vmin=-limit, vmax=limit)
        else:
            image = axes.imshow(values_um, origin="lower", extent=extent, cmap=colormap)
        axes.plot(probed[:, 0], probed[:, 1], "k.", markersize=4, label="probed points")
        axes.set_title(title)
        axes.set_xlabel("X (mm)")
        axes.set_ylabel("Y (mm)")
        figure.colorbar(image, ax=axes)
    output = Path(path)
    figure.savefig(output, dpi=100)
    return output
