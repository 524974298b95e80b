"""Taps at one spot pooled on the virtual printer: PROBE_ACCURACY and PROBE SAMPLES= (issue 21 item 4).

PROBE_ACCURACY prints Klipper's result line over the pooled Zs (its format unchanged, last) and the single
taps' figures on the line before it; PROBE SAMPLES= combines the pooled Zs. A probe whose taps are not read
by the toe model (contact_model: sharp) is unchanged: one line, each tap's own Z.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from probe_vprinter import make_printer
from tapcell.extras.probe.stats import accuracy_stats, format_accuracy, format_single_tap_accuracy

# Klipper's PROBE_ACCURACY line (extras/probe.py), with tapcell's average delta after it.
KLIPPER_LINE = re.compile(r"// probe accuracy results: maximum -?\d+\.\d{6}, minimum -?\d+\.\d{6}, range \d+\.\d{6}, "
                          r"average -?\d+\.\d{6}, median -?\d+\.\d{6}, standard deviation \d+\.\d{6}, "
                          r"average delta \d+\.\d{6}$")


def accuracy(printer, responses, parameters=""):
    responses.clear()
    printer.gcode.run_script(f"PROBE_ACCURACY SAMPLES=10 SAMPLE_RETRACT_DIST=0.4 {parameters}")
    device = printer.lookup_object("load_cell_probe")
    return printer.lookup_object("probe"), [t.analysis for t in list(device.last_taps)[-10:]]


@pytest.mark.parametrize("scenario, most", [("clean", 0.5), ("soft-sheet", 0.8)])
def test_probe_accuracy_reports_the_pooled_standard_deviation(tmp_path, scenario, most):
    printer, responses = make_printer(tmp_path, scenario)
    printer.gcode.run_script("PROBE HOME=Z\nG1 Z0.4")
    probe, analyses = accuracy(printer, responses)
    assert probe.last_accuracy_pooled
    z_offset_mm = probe.options.z_offset_mm
    # Klipper's line, last and in its format, over each tap's pooled Z; the taps' own figures before it.
    pooled_z = np.array([a.z_pooled_mm for a in analyses]) - z_offset_mm
    single_z = np.array([a.z_mm for a in analyses]) - z_offset_mm
    assert probe.last_accuracy == accuracy_stats(pooled_z)
    assert probe.last_accuracy_single == accuracy_stats(single_z)
    assert KLIPPER_LINE.match(responses[-1])
    assert responses[-1] == "// " + format_accuracy(accuracy_stats(pooled_z))
    assert responses[-2] == "// " + format_single_tap_accuracy(accuracy_stats(single_z))
    assert responses[-2].startswith("// single-tap results (each tap analysed alone; the results below pool the "
                                    "10 taps): maximum ")
    # Measured (bench probe_pool, seeds 1-5): pooled/single 0.19-0.23 clean, 0.31-0.65 on the soft sheet.
    pooled_um = probe.last_accuracy.standard_deviation_mm * 1000
    single_um = probe.last_accuracy_single.standard_deviation_mm * 1000
    assert 0.0 < pooled_um < most * single_um
    assert probe.last_z_result == pytest.approx(pooled_z.mean(), abs=1e-12)
    # The tap files of the last taps carry each tap's pooled Z (tapcell analyze --pool's fields).
    assert all(a.to_json()["z_pooled"] == pytest.approx(a.z_pooled_mm, abs=1e-9) for a in analyses)


def test_probe_samples_combines_the_pooled_zs(tmp_path):
    printer, responses = make_printer(tmp_path)
    printer.gcode.run_script("PROBE HOME=Z\nG1 Z0.4")
    printer.gcode.run_script("PROBE SAMPLES=3 SAMPLES_RESULT=median SAMPLE_RETRACT_DIST=0.4")
    probe = printer.lookup_object("probe")
    result = probe.last_result
    analyses = [t.analysis for t in list(printer.lookup_object("load_cell_probe").last_taps)[-3:]]
    z_offset_mm = probe.options.z_offset_mm
    assert result.pooled
    assert result.single_z_mm == pytest.approx([a.z_mm for a in analyses], abs=1e-12)
    assert result.samples_z_mm == pytest.approx([a.z_pooled_mm for a in analyses], abs=1e-12)
    assert result.z_mm == pytest.approx(np.median([a.z_pooled_mm for a in analyses]) - z_offset_mm, abs=1e-12)
    assert result.z_mm != pytest.approx(np.median(result.single_z_mm) - z_offset_mm, abs=1e-8)
    assert responses[-1] == f"// Result is z={result.z_mm:.6f}"
    assert result.to_json()["pooled"] is True


def test_without_the_toe_model_nothing_is_pooled(tmp_path):
    printer, responses = make_printer(tmp_path, probe_options="contact_model: sharp")
    printer.gcode.run_script("PROBE HOME=Z\nG1 Z0.4")
    probe, analyses = accuracy(printer, responses, "SAMPLES=4")
    assert not probe.last_accuracy_pooled
    assert probe.last_accuracy == probe.last_accuracy_single
    assert probe.last_accuracy == accuracy_stats(np.array([a.z_mm for a in analyses[-4:]]) - probe.options.z_offset_mm)
    assert KLIPPER_LINE.match(responses[-1])
    assert not any(line.startswith("// single-tap results") for line in responses)
    assert all(a.z_pooled_mm is None for a in analyses)
    printer.gcode.run_script("G1 Z0.4\nPROBE SAMPLES=2 SAMPLE_RETRACT_DIST=0.4")
    assert not probe.last_result.pooled and probe.last_result.samples_z_mm == probe.last_result.single_z_mm
