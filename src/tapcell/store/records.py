"""Rows of the store from plain data: a tap document (tapcell.tap.v1 with `analysis` and, from
a monitor, `printer`), a bed mesh status, a probe's settings. Pure functions, no database."""

from __future__ import annotations

import hashlib
import json
import math
import zlib
from dataclasses import dataclass
from typing import Any


class RecordError(ValueError):
    """A document the store cannot keep; says what is missing or wrong."""


@dataclass(frozen=True)
class TapRecord:
    """One tap as a row of `taps` (the document compressed, the columns the pages filter by)."""

    tap_key: str
    recorded_s: float
    x_mm: float | None
    y_mm: float | None
    printer_z_mm: float | None
    printer_valid: bool | None
    printer_error: str | None
    tapcell_z_mm: float | None
    tapcell_valid: bool
    tapcell_error: str | None
    cause: str
    quality: float | None
    stiffness_g_um: float | None
    noise_sigma_g: float | None
    document: bytes

    def columns(self) -> dict[str, Any]:
        return {name: getattr(self, name) for name in self.__dataclass_fields__}


@dataclass(frozen=True)
class MeshRecord:
    mesh_key: str
    recorded_s: float
    profile: str
    x_min_mm: float
    y_min_mm: float
    x_max_mm: float
    y_max_mm: float
    matrix: str  # JSON rows

    def columns(self) -> dict[str, Any]:
        return {name: getattr(self, name) for name in self.__dataclass_fields__}


def _digest(value: Any) -> str:
    return hashlib.sha256(json.dumps(value, sort_keys=True, allow_nan=False).encode()).hexdigest()


def _finite(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        return None
    return float(value)


def cause_text(printer: dict, analysis: dict) -> str:
    """Why a tap was rejected, in words: the printer's reason, then tapcell's ('' when both kept it)."""
    causes = []
    error = printer.get("error")
    if printer.get("is_valid") is False and isinstance(error, dict):
        causes.append(f"printer: {error.get('error_code')} - {error.get('message')}")
    if not analysis.get("valid"):
        causes.append(f"tapcell: {analysis.get('error')} - {analysis.get('message')}")
    return "; ".join(causes)


def tap_record(document: dict, recorded_s: float) -> TapRecord:
    """The row for a tapcell.tap.v1 document that carries tapcell's `analysis`."""
    analysis = document.get("analysis")
    if not isinstance(analysis, dict) or "valid" not in analysis:
        raise RecordError("the tap has no 'analysis' result (analyse it first)")
    if not isinstance(document.get("time"), list) or not isinstance(document.get("force"), list):
        raise RecordError("the tap has no 'time' and 'force' sample lists")
    printer = document.get("printer") if isinstance(document.get("printer"), dict) else {}
    position = printer.get("tap_pos") if isinstance(printer.get("tap_pos"), list) else None
    probe = document.get("probe") if isinstance(document.get("probe"), dict) else {}
    x_mm, y_mm = (position[0], position[1]) if position and len(position) >= 2 else (probe.get("x"), probe.get("y"))
    printer_error = printer.get("error")
    stiffness = analysis.get("stiffness_decompression_g_um")
    if _finite(stiffness) is None:
        stiffness = analysis.get("stiffness_compression_g_um")
    return TapRecord(
        tap_key=_digest([document["time"], document["force"]]),
        recorded_s=float(recorded_s),
        x_mm=_finite(x_mm), y_mm=_finite(y_mm),
        printer_z_mm=_finite(printer.get("z")),
        printer_valid=printer.get("is_valid") if isinstance(printer.get("is_valid"), bool) else None,
        printer_error=str(printer_error.get("error_code"))[:100] if isinstance(printer_error, dict) else None,
        tapcell_z_mm=_finite(analysis.get("z")),
        tapcell_valid=bool(analysis["valid"]),
        tapcell_error=None if analysis.get("error") is None else str(analysis["error"])[:100],
        cause=cause_text(printer, analysis),
        quality=_finite(analysis.get("quality")),
        stiffness_g_um=_finite(stiffness),
        noise_sigma_g=_finite(analysis.get("noise_sigma_g")),
        document=zlib.compress(json.dumps(document, allow_nan=False, separators=(",", ":")).encode(), 6),
    )


def tap_document(blob: bytes) -> dict:
    """A stored tap's document back from its compressed column."""
    return json.loads(zlib.decompress(blob))


def mesh_record(status: dict, recorded_s: float) -> MeshRecord | None:
    """The row for a `bed_mesh` status, or None when no mesh is loaded (an empty probed_matrix)."""
    matrix = status.get("probed_matrix")
    if not isinstance(matrix, list) or not matrix or not all(isinstance(row, list) and row for row in matrix):
        return None
    rows = [[float(z) for z in row] for row in matrix]
    if len({len(row) for row in rows}) != 1 or not all(math.isfinite(z) for row in rows for z in row):
        raise RecordError("bed_mesh probed_matrix rows differ in length or hold a non-number")
    mesh_min, mesh_max = status.get("mesh_min"), status.get("mesh_max")
    if not (isinstance(mesh_min, list | tuple) and isinstance(mesh_max, list | tuple)
            and len(mesh_min) == 2 and len(mesh_max) == 2):
        raise RecordError("bed_mesh status has no mesh_min/mesh_max pair")
    profile = str(status.get("profile_name") or "")[:100]
    bounds = [float(mesh_min[0]), float(mesh_min[1]), float(mesh_max[0]), float(mesh_max[1])]
    return MeshRecord(_digest([profile, bounds, rows]), float(recorded_s), profile, *bounds,
                      json.dumps(rows, separators=(",", ":")))


def settings_key(settings: dict) -> str:
    return _digest(settings)
