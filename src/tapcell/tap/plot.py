"""A tap drawn like the spec's figures: force over time, the five fitted lines, phase bands,
the break-contact point and its Z."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tapcell.tap.model import TapAnalysis, TapData
from tapcell.tap.motion import MotionError, tap_motion

LINE_NAMES = ("approach", "compression", "dwell", "decompression", "departure")


def plot_tap(tap: TapData, analysis: TapAnalysis, out_path: str | Path, title: str = "") -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(figsize=(10, 5.5))
    t0 = float(tap.time_s[0])
    axes.plot(tap.time_s - t0, tap.force_g, color="black", linewidth=0.8, label="force")
    try:
        motion = tap_motion(tap)
        bands = (("probe", motion.home_end_s - motion.pullback_duration_s, motion.home_end_s, "tab:blue"),
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
        tb, fb = analysis.points[4]
        z_text = f"Z = {analysis.z_mm:.4f} mm ± {analysis.z_sigma_um:.2f} µm" if analysis.z_mm is not None else "no Z"
        axes.plot([tb - t0], [fb], "o", color="red", markersize=7)
        axes.annotate(f"break contact\n{z_text}", (tb - t0, fb), textcoords="offset points", xytext=(12, 18))
    status = "valid" if analysis.valid else f"{analysis.error}"
    quality = f", quality {analysis.quality:.1f}%" if analysis.quality is not None else ""
    axes.set_title(f"{title} — {status}{quality}".strip(" —"))
    axes.set_xlabel(f"time since {t0:.3f} s (s)")
    axes.set_ylabel("force (g)")
    axes.legend(loc="best", fontsize=8)
    figure.tight_layout()
    figure.savefig(out_path, dpi=110)
    plt.close(figure)
