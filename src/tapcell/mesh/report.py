"""Reports of a mesh for people: text tables, error against a known bed, heat-map PNGs.

The text functions return strings (the G-code layer prints them as responses); the PNG
writer uses matplotlib's object API, so no display or global pyplot state is involved.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tapcell.mesh.abl import TopologyReport, TwoPassPoint
from tapcell.mesh.errors import MeshError
from tapcell.mesh.faulty_regions import ProbingPlan
from tapcell.mesh.zmesh import ZMesh

# Bed height in mm at arrays of x, y (mm): the truth a simulated bed is built from.
TruthFn = Callable[[np.ndarray, np.ndarray], np.ndarray]


def render_probed_matrix(mesh: ZMesh) -> str:
    """BED_MESH_OUTPUT's first part, as Klipper prints it: the probed Z, front row first."""
    lines = ["Mesh Leveling Probed Z positions:"]
    lines += ["".join(f" {z:f}" for z in row) for row in mesh.probed_matrix_mm]
    return "\n".join(lines)


def render_mesh(mesh: ZMesh, search_height_mm: float, probe_offsets_xy_mm: tuple[float, float]) -> str:
    """BED_MESH_OUTPUT's second part, as Klipper prints it: the interpolated mesh (back row first).

    `Mesh Range` is `ZMesh.z_range_mm`, the one range every report of this mesh gives."""
    rows, columns = mesh.mesh_matrix_mm.shape
    low, high = mesh.z_range_mm()
    lines = [
        f"Mesh X,Y: {columns},{rows}",
        f"Search Height: {search_height_mm:.0f}",
        f"Mesh Offsets: X={probe_offsets_xy_mm[0]:.4f}, Y={probe_offsets_xy_mm[1]:.4f}",
        f"Mesh Average: {mesh.average_mm():.2f}",
        f"Mesh Range: min={low:.4f} max={high:.4f}",
        f"Interpolation Algorithm: {mesh.interpolation.algorithm}",
        "Measured points:",
    ]
    lines += ["".join(f"  {z:f}" for z in row) for row in mesh.mesh_matrix_mm[::-1]]
    return "\n".join(lines)


def render_generated_points(plan: ProbingPlan, probe_offsets_xy_mm: tuple[float, float],
                            zero_reference_xy_mm: tuple[float, float] | None) -> str:
    """BED_MESH_OUTPUT PGP=1, as Klipper prints it: each point where the nozzle goes and where the
    probe is, then the zero reference and the faulty-region substitutes."""
    x_offset, y_offset = probe_offsets_xy_mm
    lines = ["bed_mesh: generated points", "Index |  Tool Adjusted  |   Probe"]
    for index, (x_mm, y_mm) in enumerate(plan.points_mm):
        nozzle = f"({x_mm - x_offset:.1f}, {y_mm - y_offset:.1f})"
        lines.append(f"  {index:<4d}| {nozzle:<16s}| ({x_mm:.1f}, {y_mm:.1f})")
    if zero_reference_xy_mm is not None:
        lines.append(f"bed_mesh: zero_reference_position is ({zero_reference_xy_mm[0]:.2f}, "
                     f"{zero_reference_xy_mm[1]:.2f})")
    substituted = plan.substituted
    if substituted:
        lines.append("bed_mesh: faulty region points")
        for index, places in substituted.items():
            x_mm, y_mm = plan.points_mm[index]
            listed = ", ".join(f"({px:.1f}, {py:.1f})" for px, py in places)
            lines.append(f"{index} ({x_mm:.2f}, {y_mm:.2f}), substituted points: [{listed}]")
    return "\n".join(lines)


def render_mesh_map(mesh: ZMesh) -> str:
    """BED_MESH_MAP: the probed mesh as one JSON line for tools (Klipper's `mesh_map_output`)."""
    return "mesh_map_output " + json.dumps({
        "mesh_min": [mesh.grid.min_x_mm, mesh.grid.min_y_mm],
        "mesh_max": [mesh.grid.max_x_mm, mesh.grid.max_y_mm],
        "z_positions": mesh.probed_matrix_mm.tolist(),
    })


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
    output = Path(path)
    mesh_figure(mesh, truth_z_mm, samples_per_axis).savefig(output, dpi=100)
    return output


# Room around the map, as a share of its span, so the probed points on its edges show whole.
MAP_MARGIN = 0.04


def mesh_figure(mesh: ZMesh, truth_z_mm: TruthFn | None = None, samples_per_axis: int = 101):
    """The heat map figure: the mesh in mm, its colour bar labelled and limited to the mesh's
    range (ZMesh.z_range_mm, as BED_MESH_OUTPUT's Mesh Range), min/max/range in the title; with
    the truth a second panel of mesh - truth in µm, zero the neutral colour, its worst spot
    marked, and said to be the simulator's (a real printer does not know its true bed). The
    probed points show whole (a margin around the map) and the legend sits under the map."""
    from matplotlib.figure import Figure  # imported here: only the heat maps need matplotlib

    area_x, area_y = _area_grid(mesh, samples_per_axis)
    low, high = mesh.z_range_mm()
    height = ("Mesh: bed height\n"
              f"min {low:.4f} mm, max {high:.4f} mm, range {high - low:.4f} mm",
              mesh.z_at(area_x, area_y), "viridis", "bed height (mm)", (low, high))
    panels = [height]
    worst = None
    if truth_z_mm is not None:
        error_um = (mesh.z_at(area_x, area_y) - truth_z_mm(area_x, area_y)) * 1000.0
        at = np.unravel_index(int(np.argmax(np.abs(error_um))), error_um.shape)
        limit = max(float(np.abs(error_um[at])), 1e-9)  # symmetric: zero error is the neutral colour
        worst = (float(area_x[at]), float(area_y[at]), float(error_um[at]))
        panels.append(("Mesh - true bed (simulator only: a real printer\ndoes not know its true bed), "
                       f"largest {limit:.1f} µm", error_um, "coolwarm", "mesh - true bed (µm)", (-limit, limit)))
    grid = mesh.grid
    extent = (grid.min_x_mm, grid.max_x_mm, grid.min_y_mm, grid.max_y_mm)
    pad_x = MAP_MARGIN * (grid.max_x_mm - grid.min_x_mm)
    pad_y = MAP_MARGIN * (grid.max_y_mm - grid.min_y_mm)
    probed = grid.probe_points_mm()
    figure = Figure(figsize=(5.5 * len(panels), 5.2), layout="constrained")
    for number, (title, values, colormap, unit, (vmin, vmax)) in enumerate(panels, start=1):
        axes = figure.add_subplot(1, len(panels), number)
        image = axes.imshow(values, origin="lower", extent=extent, cmap=colormap, vmin=vmin, vmax=vmax)
        axes.set_xlim(grid.min_x_mm - pad_x, grid.max_x_mm + pad_x)
        axes.set_ylim(grid.min_y_mm - pad_y, grid.max_y_mm + pad_y)
        axes.plot(probed[:, 0], probed[:, 1], "k.", markersize=4, label="probed points")
        if number == 2 and worst is not None:
            axes.plot([worst[0]], [worst[1]], marker="o", markersize=11, markerfacecolor="none",
                      markeredgecolor="black", markeredgewidth=1.5, linestyle="none",
                      label=f"largest error {worst[2]:+.1f} µm at X {worst[0]:.1f} Y {worst[1]:.1f}")
        axes.set_title(title, fontsize=10)
        axes.set_xlabel("X (mm)")
        axes.set_ylabel("Y (mm)")
        axes.legend(loc="upper center", bbox_to_anchor=(0.5, -0.13), fontsize=7, frameon=False, ncol=2)
        figure.colorbar(image, ax=axes, label=unit)
    return figure
