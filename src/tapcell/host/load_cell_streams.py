"""The load-cell streams of Klipper's API: `load_cell/dump_force` and `load_cell_probe/dump_taps`.

Real printers name them this way: `load_cell/dump_force` is selected by `load_cell=<last word
of the section name>` (`[load_cell]` -> "load_cell", `[load_cell_probe]` -> "load_cell_probe")
and answers with the header `["time", "force (g)", "counts", "tare_counts"]`, then pushes
`{"data": [[time, grams, counts, tare_counts], ...], "errors": n, "overflows": n}`.
`load_cell_probe/dump_taps` is selected by `load_cell_probe=<section name>`, answers
`["probe_tap_event"]` and pushes one `{"tap": {...}}` per tap, with the fields of the
Klipper-family tap event (times re-based to the first sample). tapcell adds `sample_rate`,
`probe` and `meta`, which the tap readers use and other clients ignore.
"""

from __future__ import annotations

from typing import Any

import numpy as np

FORCE_HEADER = ["time", "force (g)", "counts", "tare_counts"]
TAP_HEADER = ["probe_tap_event"]
MAX_ROWS_PER_PUSH = 1000  # ~60 kB of JSON: far below Moonraker's 20 MiB message limit


def load_cells(printer) -> dict[str, Any]:
    """Every load cell of the printer by its dump_force name: `[load_cell NAME]` objects and
    the cell inside a `[load_cell_probe]`."""
    cells = {}
    for section, obj in printer.objects.items():
        cell = obj if _is_load_cell(obj) else getattr(obj, "load_cell", None)
        if _is_load_cell(cell):
            cells[section.split()[-1]] = cell
    return cells


def tap_probes(printer) -> dict[str, Any]:
    """Every tapping probe by its dump_taps name (the full section name)."""
    return {section: obj for section, obj in printer.objects.items() if hasattr(obj, "add_tap_client")}


def _is_load_cell(obj) -> bool:
    return hasattr(obj, "add_client") and hasattr(obj, "counts_to_grams")


def force_rows(load_cell, batch) -> list[list]:
    """A sample batch as dump_force rows; grams and tare are None until the cell is calibrated."""
    counts = np.asarray(batch.counts)
    grams = load_cell.counts_to_grams(counts)
    tare = load_cell.tare_counts
    return [[float(t), None if grams is None else round(float(g), 3), int(c), tare]
            for t, g, c in zip(batch.t_s, grams if grams is not None else [None] * len(counts), counts)]


def tap_event(recorded) -> dict:
    """One recorded tap (tapcell.extras.load_cell_probe.RecordedTap) as a dump_taps push."""
    tap, analysis = recorded.tap, recorded.analysis
    t0_s = float(tap.time_s[0])
    x_mm, y_mm = float(tap.probe.get("x", 0.0)), float(tap.probe.get("y", 0.0))  # the toolhead's frame
    moves = [{"print_time": m.print_time - t0_s, "move_t": m.move_t, "start_v": m.start_v, "accel": m.accel,
              "start_x": x_mm, "start_y": y_mm, "start_z": m.start_z,
              "x_r": 0.0, "y_r": 0.0, "z_r": m.z_r} for m in tap.moves]
    error = None if recorded.valid else {"error_code": analysis.error or "TAP_INVALID", "message": analysis.message}
    event = {
        "time": [float(t) - t0_s for t in tap.time_s],
        "force": [float(f) for f in tap.force_g],
        "tap_points": [{"time": t - t0_s, "force": f} for t, f in analysis.points],
        # f = slope*t + intercept, with t counted from the first sample
        "tap_lines": [{"slope": slope, "intercept": intercept + slope * t0_s} for slope, intercept in analysis.lines],
        "tap_angles": list(analysis.angles_deg),
        "tap_pos": None if analysis.z_mm is None else [x_mm, y_mm, float(analysis.z_mm)],
        "moves": moves,
        **{name: float(tap.events[name]) - t0_s for name in ("home_end_time", "pullback_start_time",
                                                              "pullback_end_time") if name in tap.events},
        "collection_time": 0.0,  # the virtual printer's samples are there when the pullback ends
        "elapsed": analysis.elapsed_ms / 1000.0,
        "is_valid": bool(recorded.valid),
        "error": error,
        "sample_rate": tap.sample_rate_sps,
        "probe": {**tap.probe, "x": x_mm, "y": y_mm},
        "meta": dict(tap.meta),
    }
    return {"tap": event}
