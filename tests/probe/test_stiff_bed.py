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


def test_a_bed_too_stiff_for_the_speed_is_refused_with_the_safe_speed_not_endless_bad_taps(tmp_path):
    """On today's main every tap at 5 mm/s on this bed is TAP_BREAK_CONTACT_TOO_EARLY, 7 in a row,
    and the guard keeps assuming 10 g/um. Now the pullbacks of the first two bad taps show the bed
    (about 48 g/um, agreeing) and the next try is refused with the speed that is safe on it."""
    printer, responses = make_printer(tmp_path, virtual_printer=STIFF)
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


def test_a_declared_stiff_bed_makes_the_guard_refuse_the_reproducer(tmp_path):
    """Issue 19: this bed, a sensor stuck at contact, PROBE PROBE_SPEED=8: 7,029 g. With the stiffest
    bed declared (max_bed_stiffness: 100) the speed is refused before anything moves, and at the safe
    speed it names (0.8 mm/s, homing included) the stuck sensor is stopped at 721 g."""
    printer, _ = make_printer(tmp_path, virtual_printer=STIFF, probe_options="max_bed_stiffness: 100",
                              replace={"\nspeed: 5\n": "\nspeed: 0.8\n"})
    truth = printer.backend.truth
    truth.take_peak_force_g()
    with pytest.raises(GCodeError, match=r"probing at 8 mm/s refused: .* up to 100\.0 g/um \(assumed until a tap "
                                         r"measures it\).* probe at 0\.8 mm/s or slower$"):
        printer.gcode.run_script("SIM_FAULT NAME=stuck WHEN=contact\nPROBE PROBE_SPEED=8")
    assert truth.take_peak_force_g() == 0.0
    with pytest.raises(GCodeError, match="sensor stuck!"):
        printer.gcode.run_script("PROBE")
    assert 0.0 < truth.take_peak_force_g() < 2000.0
