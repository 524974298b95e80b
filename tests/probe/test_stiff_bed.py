"""A bed stiffer than the force guard assumes (issue 19): the guard learns it from the first bad
tap and refuses the speed with the safe one, and a config may declare the stiffest bed."""

from __future__ import annotations

import numpy as np
import pytest

from probe_vprinter import make_printer
from tapcell.extras.load_cell_probe import safety
from tapcell.host.gcode import GCodeError

STIFF = "frame_stiffness_g_um: 150\ncell_stiffness_g_um: 150\n"   # 75 g/um in series


def test_decompression_stiffness_ignores_a_corrupted_frame():
    t = np.arange(20) / 320.0
    z_at = lambda t_s: 0.001 * 320.0 * t_s          # rising 1 um per sample
    force = np.clip(600.0 - 50.0 * np.arange(20), 0.0, None)   # 50 g per um
    force[5] += 30000.0                               # a flipped bit
    assert safety.decompression_stiffness_g_um(t, force, z_at, 0.0, 1.0) == pytest.approx(50.0)
    assert safety.decompression_stiffness_g_um(t[:3], force[:3], z_at, 0.0, 1.0) is None   # too few samples


UNMEASURED_NOTE = ("// Probing at 0.8 mm/s, not {} mm/s, until a tap measures the bed: up to 100 g/um is assumed "
                   "before that (max_bed_stiffness)")


def test_the_issue_reproducer_is_probed_at_the_speed_safe_on_the_stiffest_bed(tmp_path):
    """Issue 19: this bed (75 g/um, too stiff for G28 Z's backoffs to read), a sensor stuck at contact,
    PROBE PROBE_SPEED=8 pressed 7,029 g when 10 g/um was assumed. With max_bed_stiffness 100 g/um the
    unmeasured bed is met at 0.8 mm/s (said once) and the firmware stops the stuck sensor at 721 g."""
    printer, responses = make_printer(tmp_path, virtual_printer=STIFF)
    assert printer.lookup_object("load_cell_probe").speed_guard.assumed_stiffness_g_um() == (100.0, False)
    assert UNMEASURED_NOTE.format(5) in responses   # G28 Z's first tap
    truth = printer.backend.truth
    truth.take_peak_force_g()
    responses.clear()
    with pytest.raises(GCodeError, match="sensor stuck!"):
        printer.gcode.run_script("SIM_FAULT NAME=stuck WHEN=contact\nPROBE PROBE_SPEED=8")
    assert responses.count(UNMEASURED_NOTE.format(8)) == 1
    assert 600.0 < truth.take_peak_force_g() < 800.0   # 721 g measured; force_safety_limit 2000 g


def test_a_fresh_printer_homes_a_stiff_bed_with_a_stuck_sensor_within_the_limit(tmp_path):
    """G28 on the same bed and sensor: homing's first tap goes at 0.8 mm/s, not the configured 5."""
    printer, responses = make_printer(tmp_path, virtual_printer=STIFF, home=False)
    truth = printer.backend.truth
    truth.take_peak_force_g()
    with pytest.raises(GCodeError, match="sensor stuck!"):
        printer.gcode.run_script("SIM_FAULT NAME=stuck WHEN=contact\nG28")
    assert UNMEASURED_NOTE.format(5) in responses
    assert 600.0 < truth.take_peak_force_g() < 800.0   # 721 g measured


def test_a_measured_bed_too_stiff_for_the_speed_is_refused_with_the_safe_speed(tmp_path):
    """A 20 g/um bed: G28 Z's backoffs read 17.3 g/um (x1.25: 21.6), so 8 mm/s is refused before
    moving with the safe speed, and at that speed a sensor stuck at contact stays below the limit."""
    printer, _ = make_printer(tmp_path, virtual_printer="frame_stiffness_g_um: 40\ncell_stiffness_g_um: 40\n")
    stiffness_g_um, measured = printer.lookup_object("load_cell_probe").speed_guard.assumed_stiffness_g_um()
    assert measured and 20.0 < stiffness_g_um < 23.0
    truth = printer.backend.truth
    truth.take_peak_force_g()
    with pytest.raises(GCodeError, match=r"^Load Cell Probe Error: probing at 8 mm/s refused: it could press the bed "
                                         r"with up to 4\d{3}g, .* into a bed of up to 21\.6 g/um \(measured by the "
                                         r"taps, with a margin\), .*; probe at 3 mm/s or slower$"):
        printer.gcode.run_script("PROBE PROBE_SPEED=8")
    assert truth.take_peak_force_g() == 0.0
    with pytest.raises(GCodeError, match="sensor stuck!"):
        printer.gcode.run_script("SIM_FAULT NAME=stuck WHEN=contact\nPROBE PROBE_SPEED=3")
    assert 0.0 < truth.take_peak_force_g() < 2000.0


def test_a_bed_stiffer_than_declared_is_refused_with_the_safe_speed_not_endless_bad_taps(tmp_path):
    """max_bed_stiffness: 10 declared on the 75 g/um bed: every tap at 5 mm/s is
    TAP_BREAK_CONTACT_TOO_EARLY. The pullbacks of the first two bad taps show the bed (about 48 g/um,
    agreeing) and the next try is refused with the speed that is safe on it."""
    printer, responses = make_printer(tmp_path, virtual_printer=STIFF, probe_options="max_bed_stiffness: 10")
    truth = printer.backend.truth
    truth.take_peak_force_g()
    with pytest.raises(GCodeError) as error:
        printer.gcode.run_script("PROBE")
    message = str(error.value)
    assert message.startswith("Load Cell Probe Error: probing at 5 mm/s refused: ")
    assert "(measured by the taps, with a margin)" in message and message.endswith("mm/s or slower")
    assert sum("Bad probe detected: TAP_BREAK_CONTACT_TOO_EARLY" in line for line in responses) == 2
    assert 30.0 < printer.lookup_object("load_cell_probe").bad_tap_stiffness_g_um < 75.0
    assert truth.take_peak_force_g() < 2000.0


def test_a_bad_taps_low_reading_never_lowers_the_stiffest_bed_assumed(tmp_path):
    """A bad tap's pullback reads this 75 g/um bed low (36 g/um at 0.5 mm/s with a 0.05 mm pullback):
    it must not replace max_bed_stiffness (100 g/um), which would let 1.5 mm/s through (a stuck sensor:
    2.6 kg predicted on the real bed). The taps stay at the speed safe on 100 g/um."""
    printer, responses = make_printer(tmp_path, virtual_printer=STIFF,
                                      replace={"pullback_distance: 0.15": "pullback_distance: 0.05"})
    device = printer.lookup_object("load_cell_probe")
    printer.gcode.run_script("PROBE PROBE_SPEED=0.5 BAD_PROBE_STRATEGY=ignore\nG1 Z0.4")
    with pytest.raises(GCodeError, match=r"^Probing failed after 7 bad probes \(last: TAP_"):
        printer.gcode.run_script("PROBE PROBE_SPEED=5")
    assert sum("Bad probe detected: TAP_BREAK_CONTACT_TOO_EARLY" in line for line in responses) >= 2
    assert 30.0 < device.bad_tap_stiffness_g_um < 60.0
    assert device.speed_guard.assumed_stiffness_g_um() == (100.0, False)
    assert [t.tap.probe["speed"] for t in device.last_taps][-7:] == [0.8] * 7
