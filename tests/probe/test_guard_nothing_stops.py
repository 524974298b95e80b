"""The force guard's "nothing stops the move" branch (issue 19): with every limit off and a drift
filter that hides a slow tap, no sample ever stops the nozzle; the guard must refuse that speed,
whatever force it would reach (its prediction gives up: there is no peak to compare)."""

from __future__ import annotations

import math

import pytest

from probe_vprinter import make_printer
from tapcell.extras.load_cell_probe import safety
from tapcell.filters import FilterOptions, design_firmware_filter
from tapcell.host.gcode import GCodeError
from tapcell.mcu.trigger import TriggerParams

OFF = "force_safety_limit: 0\ndrift_safety_limit: 0\nstuck_sensor_samples: 0"


def hiding_params() -> TriggerParams:
    sos = design_firmware_filter(FilterOptions(sample_rate_sps=320, drift_filter_cutoff_frequency=20.0))
    return TriggerParams(counts_per_gram=110.0, reference_tare_counts=-38000, trigger_force_g=75.0,
                         sample_rate_sps=320.0, force_safety_limit_g=0.0, drift_safety_limit_g=0.0, sos=sos,
                         stuck_samples=0)


def test_nothing_stopping_the_move_exceeds_any_limit():
    timing = safety.stop_timing("hx717", 320, "mcu", "mcu")
    prediction = safety.worst_stop(hiding_params(), timing, 1.0, 10.0)
    assert prediction.stopped_by is None and math.isinf(prediction.peak_force_g)
    # force_safety_limit 0: the force clause cannot say "unsafe"; only the nothing-stops clause does.
    assert safety.exceeds_limit(prediction, 0.0)
    assert safety.safe_speed_mm_s(hiding_params(), timing, 5.0, 10.0) is None
    refusal = safety.speed_refusal(hiding_params(), timing, 1.0, prediction, 10.0, False, None)
    assert refusal.startswith("probing at 1 mm/s refused: nothing would stop the nozzle")
    assert refusal.endswith("no slower speed is safe: lower drift_filter_cutoff_frequency or set a drift_safety_limit")


def test_probe_refuses_a_move_nothing_would_stop(tmp_path):
    printer, responses = make_printer(tmp_path, probe_options=OFF)
    vp = printer.backend
    vp.truth.take_peak_force_g()
    z_before = vp.position[2]
    with pytest.raises(GCodeError) as error:
        printer.gcode.run_script("PROBE DRIFT_FILTER_CUTOFF_FREQUENCY=20 PROBE_SPEED=1")
    assert "probing at 1 mm/s refused: nothing would stop the nozzle" in str(error.value)
    assert vp.position[2] >= z_before and vp.truth.take_peak_force_g() == 0.0
    # The config that turned the checks off is warned about at the command, too.
    assert any("Warning: [load_cell_probe] force_safety_limit is 0" in line for line in responses)
