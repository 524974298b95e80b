"""[virtual_sdcard] printing a file: run to the end in the console, fed over the print clock
behind a live server, with pause, resume, cancel, errors and print_stats."""

from __future__ import annotations

import pytest

from machines import gcode_error
from tapcell.host.print_clock import PrintClock
from test_klipper_surface import HEATED, build

SDCARD = "\n[virtual_sdcard]\npath: {folder}\non_error_gcode: M117 failed\n\n[pause_resume]\n\n[display_status]\n"
PRINT = """\
; a slicer's file
M109 S210
G28 X Y
G92 E0
SET_PRINT_STATS_INFO TOTAL_LAYER=2
SET_PRINT_STATS_INFO CURRENT_LAYER=1
G1 X10 Y10 F6000
G1 X110 E5 F3000
M205 X10 ; for another firmware: reported and skipped
SET_PRINT_STATS_INFO CURRENT_LAYER=2
G1 Y110 E9 F3000
G1 E7 F1800 ; retract 2 mm
"""


def sdcard_printer(tmp_path, text: str = PRINT):
    folder = tmp_path / "gcodes"
    (folder / "sub").mkdir(parents=True)
    (folder / "sub" / "part.gcode").write_text(text)
    printer, responses = build(tmp_path, HEATED + SDCARD.format(folder=folder))
    return printer, responses, folder


def test_a_file_prints_to_complete_with_its_stats(tmp_path):
    printer, responses, folder = sdcard_printer(tmp_path)
    printer.gcode.run_script('SDCARD_PRINT_FILE FILENAME="/sub/part.gcode"')
    status = printer.get_status()
    stats = status["print_stats"]
    assert stats["state"] == "complete" and stats["filename"] == "sub/part.gcode" and stats["message"] == ""
    assert stats["filament_used"] == pytest.approx(7.0)  # 9 mm pushed, 2 retracted
    assert stats["info"] == {"total_layer": 2, "current_layer": 2}
    # print_duration starts at the first extrusion: the heating and homing before it are not in it
    assert 0.0 < stats["print_duration"] < stats["total_duration"]
    assert status["virtual_sdcard"] == {"file_path": None, "progress": 1.0, "is_active": False,
                                        "file_position": len(PRINT), "file_size": len(PRINT)}
    assert '// Unknown command:"M205"' in responses
    assert responses[:2] == ["File opened:sub/part.gcode Size:%d" % len(PRINT), "File selected"]
    printer.gcode.run_script("SDCARD_RESET_FILE")
    assert printer.get_status()["print_stats"]["state"] == "standby"
    assert printer.get_status()["virtual_sdcard"]["file_size"] == 0


def test_missing_and_escaping_files_are_refused(tmp_path):
    printer, _, folder = sdcard_printer(tmp_path)
    (tmp_path / "secret.gcode").write_text("M84\n")
    assert gcode_error(printer, "SDCARD_PRINT_FILE FILENAME=nope.gcode").startswith("Unable to open file 'nope.gcode'")
    assert "Unable to open file" in gcode_error(printer, "SDCARD_PRINT_FILE FILENAME=../secret.gcode")
    assert printer.get_status()["print_stats"]["state"] == "standby"


def test_an_error_in_the_file_stops_the_print_and_runs_on_error_gcode(tmp_path):
    printer, responses, _ = sdcard_printer(tmp_path, "G28 X Y\nG1 X10 F6000\nG1 X9999\nG1 X20\n")
    printer.gcode.run_script("SDCARD_PRINT_FILE FILENAME=sub/part.gcode")
    stats = printer.get_status()["print_stats"]
    assert stats["state"] == "error" and stats["message"].startswith("Move out of range")
    assert printer.lookup_object("toolhead").get_position()[0] == pytest.approx(10.0)  # G1 X20 never ran
    assert printer.get_status()["display_status"]["message"] == "failed"  # on_error_gcode


def test_behind_a_live_server_the_file_feeds_as_its_moves_play_and_pauses_resumes_and_cancels(tmp_path):
    moves = "".join(f"G1 X{10 + 20 * (k % 2)} F1200\n" for k in range(40))  # 40 moves of 1 s each
    printer, _, _ = sdcard_printer(tmp_path, "G28 X Y\n" + moves)
    clock = PrintClock(printer.backend)
    printer.print_clock = clock
    printer.gcode.run_script("M23 sub/part.gcode\nM24")
    sdcard = printer.lookup_object("virtual_sdcard")
    assert sdcard.is_active() and printer.get_status()["print_stats"]["state"] == "printing"
    assert sdcard.position == 0  # the server's thread feeds the file, between scripts
    printer.run_background()
    # Fed until the queued moves are a second ahead: the homing alone (3.3 s) is.
    assert sdcard.position == len("G28 X Y\n") and clock.lead_s() > 1.0
    for _ in range(7):  # 3.5 s: the homing has played, the next line's 1 s move is queued
        clock.advance(0.5)
        printer.run_background()
    assert sdcard.position == len("G28 X Y\n") + 2 * len("G1 X10 F1200\n") and 1.0 <= clock.lead_s() <= 2.0
    assert printer.get_status()["idle_timeout"]["state"] == "Printing"
    for _ in range(10):
        clock.advance(0.5)
        printer.run_background()
    progress = printer.get_status()["virtual_sdcard"]["progress"]
    assert 0.1 < progress < 0.5
    assert printer.get_status()["display_status"]["progress"] == progress  # no M73 in the file
    printer.gcode.run_script("PAUSE")
    stats = printer.get_status()["print_stats"]
    assert stats["state"] == "paused" and printer.get_status()["pause_resume"]["is_paused"] is True
    position = sdcard.position
    for _ in range(10):
        clock.advance(0.5)
        printer.run_background()
    assert sdcard.position == position
    paused = printer.get_status()["print_stats"]
    assert paused["total_duration"] - paused["print_duration"] >= 4.0  # the pause does not count
    printer.gcode.run_script("M27")
    printer.gcode.run_script("RESUME")
    printer.run_background()
    assert sdcard.position > position and printer.get_status()["print_stats"]["state"] == "printing"
    assert "SD busy" in gcode_error(printer, "SDCARD_PRINT_FILE FILENAME=sub/part.gcode")
    printer.gcode.run_script("CANCEL_PRINT")
    assert printer.get_status()["print_stats"]["state"] == "cancelled" and not sdcard.is_active()


def test_print_stats_info_clears_with_zero_and_caps_the_layer(tmp_path):
    printer, _, _ = sdcard_printer(tmp_path)
    printer.gcode.run_script("SET_PRINT_STATS_INFO TOTAL_LAYER=10 CURRENT_LAYER=12")
    assert printer.get_status()["print_stats"]["info"] == {"total_layer": 10, "current_layer": 10}
    printer.gcode.run_script("SET_PRINT_STATS_INFO TOTAL_LAYER=0")
    assert printer.get_status()["print_stats"]["info"] == {"total_layer": None, "current_layer": None}


def test_a_shutdown_stops_the_print_with_an_error(tmp_path):
    moves = "".join(f"G1 X{10 + 20 * (k % 2)} F1200\n" for k in range(20))
    printer, _, _ = sdcard_printer(tmp_path, "G28 X Y\n" + moves)
    printer.print_clock = PrintClock(printer.backend)
    printer.gcode.run_script("SDCARD_PRINT_FILE FILENAME=sub/part.gcode")
    printer.run_background()
    printer.invoke_shutdown("Shutdown due to M112 command")
    stats = printer.get_status()["print_stats"]
    assert stats["state"] == "error" and stats["message"] == "Printer shut down"
    assert not printer.lookup_object("virtual_sdcard").is_active()
