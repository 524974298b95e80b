"""The last line nothing turns off (issue 19): overrides tighten, never loosen; the ADC's range
always bounds the force window; a counts_per_gram the ADC cannot serve is an error, not a crash."""

from __future__ import annotations

import numpy as np
import pytest

from probe_vprinter import make_printer
from tapcell.host.gcode import GCodeError
from tapcell.mcu.trigger import FirmwareTrigger, TriggerError, TriggerParams

RAILS = (-(1 << 23), (1 << 23) - 1)


def printer_in(folder, **options):
    folder.mkdir()
    printer, responses = make_printer(folder, **options)
    return printer, responses


def refused_before_moving(printer, script: str) -> str:
    """The error of `script`, checking that the nozzle did not go down (an error may lift it) and
    nothing pressed."""
    vp = printer.backend
    vp.truth.take_peak_force_g()
    position = vp.position
    with pytest.raises(GCodeError) as error:
        printer.gcode.run_script(script)
    assert vp.position[:2] == position[:2] and vp.position[2] >= position[2]
    assert vp.truth.take_peak_force_g() == 0.0
    return str(error.value)


def trigger(force_safety_limit_g: float, counts_per_gram: float = 110.0, counts_range=RAILS) -> FirmwareTrigger:
    return FirmwareTrigger(TriggerParams(counts_per_gram=counts_per_gram, reference_tare_counts=-38000,
                                         trigger_force_g=75.0, sample_rate_sps=320.0,
                                         force_safety_limit_g=force_safety_limit_g, drift_safety_limit_g=0.0,
                                         counts_range=counts_range))


@pytest.mark.parametrize("limit_g", [0.0, 2000.0])
def test_a_saturated_sample_stops_the_move_whatever_the_force_limit(limit_g):
    """force_safety_limit 0 (off) at 110 counts/g, or a limit the scale puts past the ADC: a sample at
    the rail is outside the force window (FORCE_SAFETY) on that very sample. (At 1.1 M counts/g the
    75 g trigger lies past the rails: only this window ends such a move.)"""
    for counts_per_gram in (110.0, 1_100_000.0):
        times = np.arange(1, 4) / 320.0
        inside = trigger(limit_g, counts_per_gram)
        inside.arm(-38000, 0.0)
        result = inside.feed(times, np.array([-38000, -37000, -37999], dtype=np.int32))
        assert result.error == TriggerError.NONE
        at_rail = trigger(limit_g, counts_per_gram)
        at_rail.arm(-38000, 0.0)
        result = at_rail.feed(times, np.array([-38000, RAILS[1], -38000], dtype=np.int32))
        assert result.error == TriggerError.FORCE_SAFETY and result.error_index == 1


def test_without_the_range_the_firmware_window_is_as_before():
    """No counts_range (the config-load checks' nominal trigger): force_safety_limit 0 is no window."""
    free = trigger(0.0, 1_100_000.0, counts_range=None)
    free.arm(-38000, 0.0)
    assert free.feed(np.array([1 / 320.0]), np.array([RAILS[1]], dtype=np.int32)).error == TriggerError.NONE


def test_counts_per_gram_past_the_adc_is_an_error_not_a_traceback(tmp_path):
    """counts_per_gram 1.1 M (inside the documented 1 .. 8388607) crashed G28 with a traceback: the
    force window did not fit int32. Now the trigger force the ADC cannot read is refused before
    anything moves."""
    printer, _ = printer_in(tmp_path / "p", calibrate=False, home=False,
                            probe_options="counts_per_gram: 1100000\nreference_tare_counts: -38012")
    printer.gcode.run_script("G28 X Y")
    error = refused_before_moving(printer, "G28 Z")
    assert "the trigger force (75g) is beyond what the load cell can read" in error
    assert "ADC's range ends 7.59g from the calibration zero" in error


@pytest.mark.parametrize("override, problem", [
    ("FORCE_SAFETY_LIMIT=0", "FORCE_SAFETY_LIMIT=0 would loosen the configured force_safety_limit (2000g)"),
    ("FORCE_SAFETY_LIMIT=3000", "FORCE_SAFETY_LIMIT=3000 would loosen"),
    ("DRIFT_SAFETY_LIMIT=0", "DRIFT_SAFETY_LIMIT=0 would loosen the configured drift_safety_limit (1000g)"),
    ("STUCK_SENSOR_SAMPLES=0", "STUCK_SENSOR_SAMPLES=0 would loosen the stuck-sensor check (7 identical"),
    ("STUCK_SENSOR_SAMPLES=20", "STUCK_SENSOR_SAMPLES=20 would loosen"),
    ("FORCE_SAFETY_LIMIT=1e-400", "FORCE_SAFETY_LIMIT '1e-400' is too small to tell from 0"),
    ("FORCE_SAFTY_LIMIT=0", "unknown parameter FORCE_SAFTY_LIMIT (did you mean FORCE_SAFETY_LIMIT?)"),
    ("STUCK_SENSOR_SAMPLE=0", "unknown parameter STUCK_SENSOR_SAMPLE (did you mean STUCK_SENSOR_SAMPLES?)"),
])
def test_overrides_may_not_loosen_a_limit(tmp_path, override, problem):
    printer, _ = printer_in(tmp_path / "p")
    for command in ("PROBE", "PROBE_ACCURACY SAMPLES=2", "BED_MESH_CALIBRATE"):
        error = refused_before_moving(printer, f"{command} {override}")
        assert problem in error, error


def test_overrides_may_tighten_a_limit(tmp_path):
    printer, responses = printer_in(tmp_path / "p")
    printer.gcode.run_script("PROBE FORCE_SAFETY_LIMIT=1500 DRIFT_SAFETY_LIMIT=800 STUCK_SENSOR_SAMPLES=5")
    assert any(line.startswith("// probe at ") for line in responses)


def test_the_one_line_that_turned_everything_off_is_refused(tmp_path):
    """`PROBE FORCE_SAFETY_LIMIT=0 DRIFT_SAFETY_LIMIT=0 STUCK_SENSOR_SAMPLES=0` with a sensor stuck at
    contact pressed 6,616 g (issue 19); now it is refused before the nozzle moves."""
    printer, _ = printer_in(tmp_path / "p")
    printer.gcode.run_script("SIM_FAULT NAME=stuck WHEN=contact")
    error = refused_before_moving(printer, "PROBE FORCE_SAFETY_LIMIT=0 DRIFT_SAFETY_LIMIT=0 STUCK_SENSOR_SAMPLES=0")
    assert "would loosen" in error


def test_a_config_that_turns_a_check_off_is_warned_at_load_and_at_each_probing_command(tmp_path):
    printer, responses = printer_in(tmp_path / "p", probe_options="stuck_sensor_samples: 0")
    warning = "[load_cell_probe] stuck_sensor_samples is 0: a sensor that stops changing is not detected"
    assert any(warning in line for line in printer.warnings)
    for command in ("PROBE", "PROBE"):
        del responses[:]
        printer.gcode.run_script(command)
        assert sum(f"// Warning: {warning}" in line for line in responses) == 1


@pytest.mark.parametrize("command, known", [
    ("PROBE SAMPLE=3", "SAMPLES"),
    ("PROBE_ACCURACY SAMPLE=3", "SAMPLES"),
    ("BED_MESH_CALIBRATE PROBE_CONT=3,3", "PROBE_COUNT"),
    ("NOZZLE_CLEANUP PATERN_X=2", "PATTERN_X"),
])
def test_an_unknown_parameter_of_a_probing_command_is_refused_before_anything_moves(tmp_path, command, known):
    printer, responses = printer_in(tmp_path / "p")
    error = refused_before_moving(printer, command)
    name = command.split()[1].split("=")[0]
    assert f"unknown parameter {name} (did you mean {known}?) for {command.split()[0]}; nothing was moved" in error
    assert not [line for line in responses if f"unknown parameter {name} ignored" in line]
