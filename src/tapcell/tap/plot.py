"""A tap drawn like the spec's figures: force over time, the five fitted lines, phase bands,
the six points, the trigger force and, for a valid tap, the break contact's Z.

Readable by design: the points carry short labels (P0..P5, placed by where each point sits
so neighbours do not overprint) explained in a key; a long capture (minutes of approach) is
zoomed to the tap and says so; a rejected tap shows its code, never a Z.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from tapcell.tap.model import TapAnalysis, TapData
from tapcell.tap.motion import MotionError, tap_motion

POINT_NAMES = ("approach start", "contact", "compression end", "decompression start", "break contact",
               "departure end")
# Where each point's label goes, in points from the point, so neighbours never share a spot:
# P0, P1 and P4 below, P2 and P3 above and to either side (close in time on a short dwell),
# P5 above (close to P4 when the nozzle never left the bed).
LABEL_OFFSETS = ((4, -12), (4, -12), (-4, 6), (4, 6), (4, -12), (-4, 6))
LABEL_ALIGN = ("left", "left", "right", "left", "left", "right")
# Zoom: the approach shown before contact, and the margin after the departure, as shares of
# the tap (contact to departure end). A capture reaching further is zoomed to this.
APPROACH_SHOWN = 0.5
MARGIN_AFTER = 0.1


def plot_tap(tap: TapData, analysis: TapAnalysis, out_path: str | Path, title: str = "") -> None:
    """Write the tap's figure as an image (PNG by the file's suffix)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(figsize=(11.5, 5.5))
    draw_tap(axes, tap, analysis, title)
    figure.tight_layout()
    figure.savefig(out_path, dpi=110)
    plt.close(figure)


def tap_window_s(tap: TapData, analysis: TapAnalysis) -> tuple[float, float]:
    """(start, end) of the span to show: the tap itself with some approach before it."""
    first, last = float(tap.time_s[0]), float(tap.time_s[-1])
    if _points_usable(analysis):
        begin, end = analysis.points[1][0], analysis.points[5][0]
    elif "home_end_time" in tap.events and "pullback_end_time" in tap.events:
        begin, end = tap.events["home_end_time"], tap.events["pullback_end_time"]
    else:
        return first, last
    span = max(end - begin, 1e-6)
    return max(first, begin - APPROACH_SHOWN * span), min(last, end + MARGIN_AFTER * span)


def _points_usable(analysis: TapAnalysis) -> bool:
    return len(analysis.points) == 6 and all(math.isfinite(t) and math.isfinite(f) for t, f in analysis.points)


def draw_tap(axes, tap: TapData, analysis: TapAnalysis, title: str = "") -> None:
    """Draw the tap on matplotlib `axes`: force, phase bands, trigger force, lines, points, Z."""
    t0 = float(tap.time_s[0])
    start_s, end_s = tap_window_s(tap, analysis)
    shown = (tap.time_s >= start_s) & (tap.time_s <= end_s)
    axes.plot(tap.time_s[shown] - t0, tap.force_g[shown], color="black", linewidth=0.8, label="force (g)")
    _draw_phases(axes, tap, t0, start_s)
    trigger_g = tap.probe.get("trigger_force")
    if isinstance(trigger_g, int | float) and trigger_g > 0:
        level = math.copysign(float(trigger_g), analysis.polarity or 1)
        axes.axhline(level, color="tab:purple", linestyle="--", linewidth=1.0,
                     label=f"trigger force ({float(trigger_g):g} g)")
    if _points_usable(analysis):
        _draw_lines_and_points(axes, analysis, t0)
    if analysis.valid and analysis.z_mm is not None and _points_usable(analysis):
        tb, fb = analysis.points[4]
        axes.plot([tb - t0], [fb], "o", color="red", markersize=7)
        sigma = f" ± {analysis.z_sigma_um:.2f} µm" if analysis.z_sigma_um is not None else ""
        # In the free space under the dwell (above it for a tap that pulls the force down).
        text_y = 0.3 if analysis.polarity >= 0 else 0.7
        axes.annotate(f"Z = {analysis.z_mm:.4f} mm{sigma}", (tb - t0, fb), xytext=(0.42, text_y),
                      textcoords="axes fraction", fontsize=10,
                      bbox={"boxstyle": "round", "facecolor": "white", "edgecolor": "red"},
                      arrowprops={"arrowstyle": "->", "color": "red"})
    status = "valid" if analysis.valid else f"rejected: {analysis.error}"
    quality = f", quality {analysis.quality:.1f}%" if analysis.quality is not None else ""
    axes.set_title(f"{title} — {status}{quality}".strip(" —"))
    capture_s = float(tap.time_s[-1]) - t0
    zoomed = start_s > t0 + 1e-9 or end_s < float(tap.time_s[-1]) - 1e-9
    label = f"time (s) since the first sample ({t0:.3f} s)"
    axes.set_xlabel(label + (f" — zoomed to the tap; the capture is {capture_s:.2f} s long" if zoomed else ""))
    axes.set_ylabel("force (g)")
    axes.set_xlim(start_s - t0, end_s - t0)
    axes.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)


def _draw_phases(axes, tap: TapData, t0: float, start_s: float) -> None:
    try:
        motion = tap_motion(tap)
    except MotionError:
        return  # no usable motion: the force and the lines still tell the story
    # The probing move began before the first sample shown: its band starts with the data.
    bands = (("probing move", start_s, motion.home_end_s, "tab:blue"),
             ("dwell", motion.home_end_s, motion.pullback_start_s, "tab:green"),
             ("pullback", motion.pullback_start_s, motion.pullback_end_s, "tab:red"))
    for name, begin, end, colour in bands:
        axes.axvspan(begin - t0, end - t0, color=colour, alpha=0.08, label=name)
        axes.axvline(end - t0, color=colour, linewidth=0.8)


def _draw_lines_and_points(axes, analysis: TapAnalysis, t0: float) -> None:
    for k, (slope, intercept) in enumerate(analysis.lines):
        (ta, _), (tb, _) = analysis.points[k], analysis.points[k + 1]
        span = np.array([ta, tb])
        axes.plot(span - t0, slope * span + intercept, color="red", linewidth=1.6,
                  label="fitted lines" if k == 0 else None)
    key = []
    for k, ((tp, fp), name) in enumerate(zip(analysis.points, POINT_NAMES)):
        axes.plot([tp - t0], [fp], "o", color="darkred", markersize=4)
        axes.annotate(f"P{k}", (tp - t0, fp), textcoords="offset points", xytext=LABEL_OFFSETS[k],
                      ha=LABEL_ALIGN[k], fontsize=8, color="darkred")
        key.append(f"P{k} {name}")
    # Beside the plot, under the legend: never over the data.
    axes.text(1.01, 0.0, "\n".join(key), transform=axes.transAxes, ha="left", va="bottom", fontsize=7,
              bbox={"boxstyle": "round", "facecolor": "white"})
