"""Contact-onset calibration, hum removal and the dwell on the virtual printer."""

from __future__ import annotations

import numpy as np
import pytest

from probe_vprinter import make_printer, true_contact_z
from tapcell.host.config import ConfigError
from tapcell.host.gcode import GCodeError
from tapcell.extras.load_cell_probe.device import LoadCellProbe
from tapcell.extras.load_cell_probe.calibration import _parabola_minimum, fit_pooled_contact_onset
from tapcell.tap import AnalysisOptions
from tapcell.sim.taps import SimTapSpec, record_sim_tap


def accuracy_bias_um(printer, extra: str = "") -> tuple[float, float]:
    """(bias of the PROBE_ACCURACY average against the true bed, its standard deviation) in µm."""
    printer.gcode.run_script(f"PROBE_ACCURACY SAMPLES=5 SAMPLE_RETRACT_DIST=0.4 {extra}")
    stats = printer.lookup_object("probe").last_accuracy
    return (stats.average_mm - true_contact_z(printer)) * 1000, stats.standard_deviation_mm * 1000


def test_parabola_minimum():
    assert _parabola_minimum(np.array([1.0, 2.0, 4.0]), (np.array([1.0, 2.0, 4.0]) - 2.5) ** 2) == pytest.approx(2.5)
    # Not a valley: the middle point.
    assert _parabola_minimum(np.array([0.0, 1.0, 2.0]), np.array([0.0, 1.0, 2.0])) == 1.0


def test_pooled_onset_of_soft_sheet_taps():
    taps = [record_sim_tap(SimTapSpec("soft-sheet", 5.0, seed, pullback_distance_mm=0.15, dwell_samples=8))
            for seed in range(1, 5)]
    found = fit_pooled_contact_onset(taps, AnalysisOptions())
    # The sheet's onset is 25 µm; hysteresis and relaxation pull the pooled fit a little short.
    assert 21.0 < found.onset_um < 26.0
    assert found.taps == 4
    assert found.z_shift_um == pytest.approx(9.9, abs=1.0)
    assert np.argmin(found.misfit_g2) == 12  # the 22 µm grid point


def test_pooled_onset_needs_three_taps():
    tap = record_sim_tap(SimTapSpec("clean", 5.0, 1, pullback_distance_mm=0.15, dwell_samples=8))
    with pytest.raises(ValueError, match="only 2 taps could be analysed at every onset width; at least 3"):
        fit_pooled_contact_onset([tap, tap], AnalysisOptions())


def test_calibrate_contact_onset_on_a_soft_sheet(tmp_path):
    printer, responses = make_printer(tmp_path, "soft-sheet")
    printer.gcode.run_script("PROBE HOME=Z\nG1 Z0.4")
    before_um, _ = accuracy_bias_um(printer)
    responses.clear()
    printer.gcode.run_script("LOAD_CELL_PROBE_CALIBRATE CALIBRATION=CONTACT_ONSET SAMPLES=5 SAMPLE_RETRACT_DIST=0.4")
    device = printer.lookup_object("load_cell_probe")
    onset_um = device.options.analysis.contact_onset_um
    assert 21.0 < onset_um < 26.0
    assert printer.config.pending_changes()["load_cell_probe"]["contact_onset_um"] == f"{onset_um:.2f}"
    assert f"contact_onset_um: {onset_um:.2f}" in "\n".join(responses)
    assert "The SAVE_CONFIG command will update the printer config file" in "\n".join(responses)
    assert "A calibrated onset selects the sharp contact model with this onset" in "\n".join(responses)
    after_um, sigma_um = accuracy_bias_um(printer)
    # Uncalibrated, the toe model (widths up to 16 µm) reads the 25 µm onset -6.8 µm low (a sharp
    # contact: about half the onset, -12 µm); calibrated (the sharp model with that onset), within
    # ~2.5 µm: measured (seeds 1-4) -2.0 to -3.4 µm (onsets 21.7-24.6 µm) since G28 Z's first tap
    # runs at 0.8 mm/s, -2.6 to -2.7 µm (23.2-23.7 µm) when it ran at 5 mm/s.
    assert -9.0 < before_um < -4.5
    assert device.config_settings.analysis.uses_toe_model is False
    assert -3.8 < after_um < -1.0
    assert sigma_um < 0.5


def test_calibrate_rejects_unknown_calibration(tmp_path):
    printer, _ = make_printer(tmp_path)
    with pytest.raises(GCodeError, match=r"^Error on 'LOAD_CELL_PROBE_CALIBRATE CALIBRATION=STIFFNESS': CALIBRATION must "
                                         r"be one of CONTACT_ONSET, PULLBACK_DISTANCE, DECOMPRESSION_ANGLE, not 'STIFFNESS'$"):
        printer.gcode.run_script("LOAD_CELL_PROBE_CALIBRATE CALIBRATION=STIFFNESS")
    with pytest.raises(GCodeError, match=r"^Error on 'LOAD_CELL_PROBE_CALIBRATE CALIBRATION=CONTACT_ONSET SAMPLES=2': "
                                         r"SAMPLES must have minimum of 3 \(allowed: 3 to 50\)$"):
        printer.gcode.run_script("LOAD_CELL_PROBE_CALIBRATE CALIBRATION=CONTACT_ONSET SAMPLES=2")


def test_contact_onset_option_reaches_the_analysis_and_is_range_checked(tmp_path):
    printer, _ = make_printer(tmp_path, probe_options="contact_onset_um: 2.5", calibrate=False, home=False)
    device = printer.lookup_object("load_cell_probe")
    assert device.config_settings.analysis.contact_onset_um == 2.5
    with pytest.raises(ConfigError, match="contact_onset_um"):
        make_printer(tmp_path, probe_options="contact_onset_um: 150", calibrate=False, home=False)


def test_contact_model_option_reaches_the_analysis_and_is_checked(tmp_path):
    printer, _ = make_printer(tmp_path, calibrate=False, home=False)
    analysis = printer.lookup_object("load_cell_probe").config_settings.analysis
    assert analysis.contact_model == "toe" and analysis.contact_onset_um is None and analysis.uses_toe_model
    printer, _ = make_printer(tmp_path, probe_options="contact_model: sharp", calibrate=False, home=False)
    assert printer.lookup_object("load_cell_probe").config_settings.analysis.contact_model == "sharp"
    with pytest.raises(ConfigError, match=r"clean\.cfg: \[load_cell_probe\] contact_model = hertz: "
                                          r"must be one of: sharp, toe$"):
        make_printer(tmp_path, probe_options="contact_model: hertz", calibrate=False, home=False)


def test_noisy_mains_probe_removes_hum(tmp_path):
    printer, _ = make_printer(tmp_path, "noisy-mains")
    printer.gcode.run_script("PROBE HOME=Z\nG1 Z0.4")
    bias_um, sigma_um = accuracy_bias_um(printer, "PROBE_SPEED=10")
    taps = printer.lookup_object("load_cell_probe").last_taps
    assert all(t.valid for t in list(taps)[-5:])
    assert all(t.analysis.hum["frequencies_hz"] == [50.0] for t in list(taps)[-5:])
    assert taps[-1].tap.meta["mains_hz"] == "auto"
    # Measured: bias -0.25 µm, sigma 0.61 µm (the toe model; 0.26-0.46 µm per tap on clean taps).
    assert abs(bias_um) < 1.0 and sigma_um < 1.0


def test_notch_frequencies_name_the_hum(tmp_path):
    printer, _ = make_printer(tmp_path, "noisy-mains", probe_options="notch_filter_frequencies: 50",
                              calibrate=False, home=False)
    device: LoadCellProbe = printer.lookup_object("load_cell_probe")
    assert device.config_settings.analysis.mains_hz == (50.0,)


def test_dwell_rule():
    from tapcell.extras.load_cell_probe.options import dwell_sample_count
    assert [dwell_sample_count(rate) for rate in (10, 80, 320, 660, 2000)] == [4, 4, 10, 21, 62]


def test_soft_sheet_taps_are_valid_at_10mm_s_with_the_dwell(tmp_path):
    printer, _ = make_printer(tmp_path, "soft-sheet")
    # The first tap at 5 mm/s measures the bed: until then the force guard allows no more.
    printer.gcode.run_script("PROBE HOME=Z PROBE_SPEED=5\nG1 Z0.4\n"
                             "PROBE_ACCURACY SAMPLES=5 PROBE_SPEED=10 SAMPLE_RETRACT_DIST=0.4")
    taps = list(printer.lookup_object("load_cell_probe").last_taps)[-5:]
    assert all(t.valid for t in taps)
    events = taps[-1].tap.events
    assert events["pullback_start_time"] - events["home_end_time"] == pytest.approx(10 / 320, abs=1e-6)
