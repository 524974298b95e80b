"""The examples' PAUSE/RESUME/CANCEL_PRINT macros (the ones Mainsail and Fluidd look for) on a
file printing over the print clock: PAUSE parks and keeps the spot, RESUME goes back and the file
prints on to complete, CANCEL_PRINT stops it with the nozzle lifted."""

from __future__ import annotations

from pathlib import Path

import pytest

from tapcell.host.print_clock import PrintClock
from tapcell.host.printer import Printer

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
CALIBRATION = "counts_per_gram: 110\nreference_tare_counts: -38000\n"
# 15 moves of 40 mm at 20 mm/s: 30 s of printing after the homing.
JOB = "G28\nG90\nG1 Z0.3 F600\n" + "".join(f"G1 X{60 - 40 * (k % 2)} Y{20 + 5 * k} F1200\n" for k in range(15))


def printing(tmp_path):
    folder = tmp_path / "gcodes"
    folder.mkdir()
    (folder / "job.gcode").write_text(JOB)
    config = tmp_path / "printer.cfg"
    config.write_text((EXAMPLES / "virtual-printer.cfg").read_text().replace("z_offset: 0\n", "z_offset: 0\n" + CALIBRATION, 1))
    printer = Printer(str(config))
    printer.gcodes_dir = str(folder)  # as `tapcell serve --gcodes-dir`
    printer.restart()
    clock = PrintClock(printer.backend)
    printer.print_clock = clock
    printer.gcode.run_script("SDCARD_PRINT_FILE FILENAME=job.gcode")

    def play(seconds: float) -> None:
        for _ in range(round(seconds / 0.25)):
            clock.advance(0.25)
            printer.run_background()

    return printer, play


def test_pause_parks_resume_returns_and_the_file_completes(tmp_path):
    printer, play = printing(tmp_path)
    play(12.0)
    sdcard, toolhead = printer.lookup_object("virtual_sdcard"), printer.lookup_object("toolhead")
    assert sdcard.is_active() and 0.0 < sdcard.get_status()["progress"] < 1.0
    kept = toolhead.get_position()
    assert kept[2] == pytest.approx(0.3, abs=0.01)
    printer.gcode.run_script("PAUSE")
    assert toolhead.get_position() == pytest.approx((225.0, 225.0, kept[2] + 10.0), abs=0.01)
    assert printer.get_status()["print_stats"]["state"] == "paused"
    position = sdcard.position
    play(5.0)
    assert sdcard.position == position  # nothing fed while paused
    printer.gcode.run_script("RESUME")
    assert toolhead.get_position() == pytest.approx(kept, abs=0.01)
    play(40.0)
    assert printer.get_status()["print_stats"]["state"] == "complete"
    assert toolhead.get_position()[:2] == pytest.approx((60.0, 90.0), abs=0.01)


def test_cancel_print_stops_the_file_and_lifts_the_nozzle(tmp_path):
    printer, play = printing(tmp_path)
    play(12.0)
    toolhead = printer.lookup_object("toolhead")
    z_mm = toolhead.get_position()[2]
    printer.gcode.run_script("CANCEL_PRINT")
    stats = printer.get_status()["print_stats"]
    assert stats["state"] == "cancelled" and not printer.lookup_object("virtual_sdcard").is_active()
    assert toolhead.get_position()[2] == pytest.approx(z_mm + 10.0, abs=0.01)
    play(5.0)
    assert printer.get_status()["print_stats"]["state"] == "cancelled"
