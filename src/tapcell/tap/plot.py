"""A tap drawn like the spec's figures: force over time, the five fitted lines, phase bands,
the six points and the break contact's Z."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tapcell.tap.model import TapAnalysis, TapData
from tapcell.tap.motion import MotionError, tap_motion

POINT_NAMES = ("approach start", "contact", "compression end", "decompression start", "break contact",
               "departure end")


def plot_tap(tap: TapData, analysis: TapAnalysis, out_path: str | Path, title: str = "") -> None:
    """Write the tap's figure as an image (PNG by the file's suffix)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(figsize=(10, 5.5))
    draw_tap(axes, tap, analysis, title)
    figure.tight_layout()
    figure.savefig(out_path, dpi=110)
    plt.close(figure)


def draw_tap(axes, tap: TapData, analysis: TapAnalysis, title: str = "") -> None:
    """Draw the tap on matplotlib `axes`: force, phase bands, the five lines, the six points, Z."""
    t0 = float(tap.time_s[0])
    axes.plot(tap.time_s - t0, tap.force_g, color="black", linewidth=0.8, label="force")
    try:
        motion = tap_motion(tap)
        # The probing move began before the first recorded sample: its band starts with the data.
        bands = (("probe", t0, motion.home_end_s, "tab:blue"),
                 ("dwell", motion.home_end_s, motion.pullback_start_s, "tab:green"),
                 ("pullback", motion.pullback_start_s, motion.pullback_end_s, "tab:red"))
        for name, start, end, colour in bands:
            axes.axvspan(start - t0, end - t0, color=colour, alpha=0.08, label=name)
            axes.axvline(end - t0, color=colour, linewidth=0.8)
    except MotionError:
        pass  # no usable motion: the force and the lines still tell the story
    if len(analysis.points) == 6 and all(np.isfinite(p[0]) for p in analysis.points):
        for k, (slope, intercept) in enumerate(analysis.lines):
            (ta, _), (tb, _) = analysis.points[k], analysis.points[k + 1]
            span = np.array([ta, tb])
            axes.plot(span - t0, slope * span + intercept, color="red", linewidth=1.6,
                      label="fitted lines" if k == 0 else None)
        for k, ((tp, fp), name) in enumerate(zip(analysis.points, POINT_NAMES)):
            axes.plot([tp - t0], [fp], "o", color="darkred", markersize=4)
            axes.annotate(f"P{k} {name}", (tp - t0, fp), textcoords="offset points", fontsize=7,
                          xytext={0: (6, -12), 5: (-90, -12)}.get(k, (6, 6)))
        tb, fb = analysis.points[4]
        z_text = f"Z = {analysis.z_mm:.4f} mm ± {analysis.z_sigma_um:.2f} µm" if analysis.z_mm is not None else "no Z"
        axes.plot([tb - t0], [fb], "o", color="red", markersize=7)
        axes.annotate(z_text, (tb - t0, fb), textcoords="offset points", xytext=(12, 22))
    status = "valid" if analysis.valid else f"{analysis.error}"
    quality = f", quality {analysis.quality:.1f}%" if analysis.quality is not None else ""
    axes.set_title(f"{title} — {status}{quality}".strip(" —"))
    axes.set_xlabel(f"time since {t0:.3f} s (s)")
    axes.set_ylabel("force (g)")
    axes.legend(loc="best", fontsize=8)
