"""What the pages draw, as plain data from the store's rows: the tap plot, a mesh or the
difference of two, the bed map of rejected taps. No web framework here."""

from __future__ import annotations

import math

import numpy as np

from tapcell.store import health
from tapcell.tap import TapFileError
from tapcell.tap.motion import MotionError, tap_motion
from tapcell.tap.readers import tap_from_object


def _round(value, digits: int):
    return None if value is None or not math.isfinite(value) else round(float(value), digits)


def tap_plot(row: dict) -> dict:
    """Force against time and against Z, the fitted lines, both Z values, the cause in words."""
    document = row["document"]
    analysis = document.get("analysis") or {}
    printer = document.get("printer") or {}
    try:
        tap = tap_from_object(document, f"tap {row['id']}")
    except TapFileError as exc:
        return {"error": exc.problem}
    time_s = np.asarray(tap.time_s, dtype=float)
    origin = float(time_s[0])
    try:
        z_mm = tap.z_mm if tap.z_mm is not None else tap_motion(tap).z_at(time_s)
        z_list = [_round(z, 5) for z in np.asarray(z_mm, dtype=float)]
    except MotionError:
        z_list = None
    points = [p for p in analysis.get("points") or [] if p.get("time") is not None and p.get("force") is not None]
    return {
        "id": row["id"],
        "time_s": [round(t - origin, 6) for t in time_s.tolist()],
        "force_g": [_round(f, 3) for f in np.asarray(tap.force_g, dtype=float)],
        "z_mm": z_list,
        "fit_time_s": [round(p["time"] - origin, 6) for p in points],
        "fit_force_g": [p["force"] for p in points],
        "tapcell_z_mm": analysis.get("z"),
        "printer_z_mm": printer.get("z"),
        "tapcell_valid": row["tapcell_valid"],
        "printer_valid": row["printer_valid"],
        "cause": row["cause"] or "kept by the printer and by tapcell",
        "quality": analysis.get("quality"),
    }


def mesh_view(mesh: dict) -> dict:
    matrix = np.asarray(mesh["matrix"], dtype=float)
    return {"id": mesh["id"], "profile": mesh["profile"], "recorded_s": mesh["recorded_s"],
            "bounds_mm": [mesh["x_min_mm"], mesh["y_min_mm"], mesh["x_max_mm"], mesh["y_max_mm"]],
            "matrix": matrix.tolist(), "min_z_mm": float(matrix.min()), "max_z_mm": float(matrix.max()),
            "range_mm": float(matrix.max() - matrix.min())}


class MeshMismatch(ValueError):
    """Two meshes that cannot be subtracted point by point."""


def mesh_difference(mesh: dict, base: dict) -> dict:
    """`mesh` minus `base`, point by point (same grid and bounds), as a mesh view."""
    a, b = np.asarray(mesh["matrix"], dtype=float), np.asarray(base["matrix"], dtype=float)
    bounds = [mesh["x_min_mm"], mesh["y_min_mm"], mesh["x_max_mm"], mesh["y_max_mm"]]
    base_bounds = [base["x_min_mm"], base["y_min_mm"], base["x_max_mm"], base["y_max_mm"]]
    if a.shape != b.shape or not np.allclose(bounds, base_bounds):
        raise MeshMismatch(f"mesh {mesh['id']} ({a.shape[1]}×{a.shape[0]} over {bounds}) and mesh {base['id']} "
                           f"({b.shape[1]}×{b.shape[0]} over {base_bounds}) are not on the same grid")
    view = mesh_view(dict(mesh, matrix=(a - b).tolist()))
    view["profile"] = f"mesh {mesh['id']} − mesh {base['id']}"
    return view


def retried(spots_oldest_first: list[tuple[float, float, bool]]) -> list[bool]:
    """Whether each tap retried the one before it: the same spot, right after a rejected tap."""
    found = [False] * len(spots_oldest_first)
    for k in range(1, len(spots_oldest_first)):
        (x0, y0, rejected0), (x1, y1, _) = spots_oldest_first[k - 1], spots_oldest_first[k]
        found[k] = rejected0 and abs(x1 - x0) <= health.SPOT_MM / 2 and abs(y1 - y0) <= health.SPOT_MM / 2
    return found


def bed_map(spots: list[tuple[float, float, bool]]) -> dict:
    """Every tap's XY (oldest first) with whether it was rejected or a retry, and the faulty_region
    lines to suggest."""
    regions = health.faulty_regions(spots)
    lines = [line for number, region in enumerate(regions, 1) for line in region.config_lines(number)]
    return {"x_mm": [s[0] for s in spots], "y_mm": [s[1] for s in spots], "rejected": [s[2] for s in spots],
            "retried": retried(spots),
            "regions": [{"x_min_mm": r.x_min_mm, "y_min_mm": r.y_min_mm, "x_max_mm": r.x_max_mm,
                         "y_max_mm": r.y_max_mm, "rejected": r.rejected, "taps": r.taps} for r in regions],
            "faulty_region_lines": lines}
