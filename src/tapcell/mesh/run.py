"""A mesh probing run: what a probing method hands back, and how it reports progress."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

# progress(done, total) after each probed point.
Progress = Callable[[int, int], None]


@dataclass
class MeshProbeRun:
    """What a probing method returns: bed height per point (probing order) and a report."""

    z_mm: list[float]
    report: str = ""
    details: dict | None = None  # JSON-ready, shown in status as last_calibration
