"""The bed surface: flat, tilted, smoothly warped or read from a CSV grid.

Heights are in mm, in the printer's Z frame. Only tests and benchmarks may read them
(through `VirtualPrinter.truth`); no algorithm above the MCU link does.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import RegularGridInterpolator

from tapcell.files import FileRefused, read_limited

MAX_CSV_BYTES = 16 * 1024 * 1024  # a 1000 x 1000 grid of heights is ~10 MB


class BedError(ValueError):
    """The bed height CSV cannot be used."""


@dataclass(frozen=True)
class WarpMode:
    amplitude_mm: float
    kx: int            # half-waves across X
    ky: int            # half-waves across Y
    phase_x: float
    phase_y: float


def random_warp_modes(rng: np.random.Generator, count: int, peak_mm: float) -> list[WarpMode]:
    """Smooth low-order modes: a real bed bows and saddles, it does not ripple."""
    modes = []
    for i in range(count):
        amp = peak_mm / (i + 1) * rng.uniform(0.6, 1.0) * rng.choice((-1.0, 1.0))
        modes.append(WarpMode(amp, int(rng.integers(1, 3)), int(rng.integers(1, 3)),
                              rng.uniform(0, np.pi), rng.uniform(0, np.pi)))
    return modes


def read_height_csv(path: str) -> np.ndarray:
    """Rows are Y (first row = front, y=0), columns X; values in mm."""
    try:
        text = read_limited(path, MAX_CSV_BYTES).decode("utf-8")
        rows = [row for row in csv.reader(text.splitlines()) if row and not row[0].lstrip().startswith("#")]
    except OSError as exc:
        raise BedError(f"bed CSV '{path}': cannot read ({exc.strerror})") from None
    except (FileRefused, UnicodeDecodeError, csv.Error) as exc:
        raise BedError(f"bed CSV '{path}': {exc}") from None
    try:
        grid = np.array([[float(v) for v in row] for row in rows])
    except ValueError as exc:
        raise BedError(f"bed CSV '{path}': {exc}; expected numbers (mm) in every cell") from None
    if grid.ndim != 2 or grid.shape[0] < 2 or grid.shape[1] < 2 or not np.all(np.isfinite(grid)):
        raise BedError(f"bed CSV '{path}': expected a rectangular grid of at least 2x2 finite heights")
    return grid


class BedSurface:
    """surface_z(x, y) for arrays of coordinates."""

    def __init__(self, size_x_mm: float, size_y_mm: float, z_offset_mm: float = 0.0,
                 tilt_x_mm: float = 0.0, tilt_y_mm: float = 0.0, warp_modes: list[WarpMode] = (),
                 grid_mm: np.ndarray | None = None):
        self.size_x_mm, self.size_y_mm = size_x_mm, size_y_mm
        self.z_offset_mm = z_offset_mm
        self.tilt_x_mm, self.tilt_y_mm = tilt_x_mm, tilt_y_mm
        self.warp_modes = list(warp_modes)
        self._grid = None
        if grid_mm is not None:
            ys = np.linspace(0.0, size_y_mm, grid_mm.shape[0])
            xs = np.linspace(0.0, size_x_mm, grid_mm.shape[1])
            self._grid = RegularGridInterpolator((ys, xs), grid_mm, bounds_error=False, fill_value=None)

    def surface_z(self, x_mm, y_mm):
        x = np.asarray(x_mm, dtype=float)
        y = np.asarray(y_mm, dtype=float)
        u = x / self.size_x_mm - 0.5           # -0.5 .. 0.5 across the bed
        v = y / self.size_y_mm - 0.5
        z = self.z_offset_mm + self.tilt_x_mm * u + self.tilt_y_mm * v
        for m in self.warp_modes:
            z = z + m.amplitude_mm * np.sin(np.pi * m.kx * (u + 0.5) + m.phase_x) * np.sin(
                np.pi * m.ky * (v + 0.5) + m.phase_y)
        if self._grid is not None:
            pts = np.stack(np.broadcast_arrays(y, x), axis=-1)
            z = z + self._grid(pts.reshape(-1, 2)).reshape(pts.shape[:-1])
        return z if np.ndim(z) else float(z)


def bed_from_params(params, rng: np.random.Generator) -> BedSurface:
    shape = params.bed_shape
    return BedSurface(
        params.bed_x_mm, params.bed_y_mm, params.bed_z_offset_mm,
        tilt_x_mm=params.bed_tilt_x_mm if shape == "tilted" else 0.0,
        tilt_y_mm=params.bed_tilt_y_mm if shape == "tilted" else 0.0,
        warp_modes=random_warp_modes(rng, params.bed_warp_modes, params.bed_warp_mm) if shape == "warped" else (),
        grid_mm=read_height_csv(params.bed_csv) if shape == "csv" else None,
    )
