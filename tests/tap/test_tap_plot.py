"""Tap plots a user can read: no overprinted labels, the trigger force drawn, long captures
zoomed to the tap, no Z for a rejected tap, units and a legend (taps from tapcell.tap.synth)."""

import itertools

import pytest

from tapcell.tap import analyze_tap
from tapcell.tap.plot import draw_tap
from tapcell.tap.synth import synth_tap

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure


def drawn(**changes):
    tap = synth_tap(**changes)
    tap.probe["trigger_force"] = 75.0
    analysis = analyze_tap(tap)
    figure = Figure(figsize=(11.5, 5.5))
    FigureCanvasAgg(figure)
    axes = figure.add_subplot()
    draw_tap(axes, tap, analysis, "t")
    figure.canvas.draw()
    return tap, analysis, figure, axes


def label_boxes(figure, axes):
    renderer = figure.canvas.get_renderer()
    return [text.get_window_extent(renderer) for text in axes.texts if text.get_text() in {f"P{k}" for k in range(6)}]


@pytest.mark.parametrize("changes", [dict(seed=4), dict(seed=6, polarity=-1), dict(seed=5, pullback_distance_mm=0.015),
                                     dict(seed=7, dwell_s=0.02)])
def test_point_labels_never_overprint(changes):
    _, _, figure, axes = drawn(**changes)
    boxes = label_boxes(figure, axes)
    assert len(boxes) == 6
    for first, second in itertools.combinations(boxes, 2):
        assert not first.overlaps(second)


def test_trigger_force_units_and_legend():
    _, analysis, _, axes = drawn(seed=4)
    trigger = [line for line in axes.lines if line.get_label() == "trigger force (75 g)"]
    assert trigger and set(trigger[0].get_ydata()) == {75.0}
    assert axes.get_ylabel() == "force (g)" and axes.get_xlabel().startswith("time (s)")
    labels = [text.get_text() for text in axes.get_legend().get_texts()]
    assert labels[:2] == ["force (g)", "probing move"] and "fitted lines" in labels
    _, negative, _, axes = drawn(seed=6, polarity=-1)
    assert set([line for line in axes.lines if line.get_label().startswith("trigger")][0].get_ydata()) == {-75.0}


def test_a_rejected_tap_has_no_z():
    _, analysis, _, axes = drawn(seed=5, pullback_distance_mm=0.015)
    assert not analysis.valid
    assert not any(text.get_text().startswith("Z =") for text in axes.texts)
    assert axes.get_title() == "t — rejected: TAP_PULLBACK_TOO_SHORT"


def test_a_long_capture_is_zoomed_to_the_tap():
    tap, analysis, _, axes = drawn(seed=1, sample_rate_sps=330.0, approach_time_s=44.8)
    low, high = axes.get_xlim()
    t0 = float(tap.time_s[0])
    contact_s, departure_s = analysis.points[1][0] - t0, analysis.points[5][0] - t0
    assert high - low < 1.0 and low < contact_s < departure_s <= high  # the 45 s capture: its last second
    assert axes.get_xlabel().endswith("zoomed to the tap; the capture is 45.46 s long")
