"""An emergency stop stops (issue 19): asked for from another thread while BED_MESH_CALIBRATE,
PROBE_ACCURACY or a long move runs, the steppers stop at the next sample, the command and the
rest of its script fail with the shutdown message, and nothing it measured is applied.

The stop comes from a second thread, as from a second API connection; the thread waits on
events the running command sets (a tap recorded, a line of output), never on a clock."""

from __future__ import annotations

import signal
import threading

import pytest

from probe_vprinter import make_printer
from tapcell.host import load_cell_streams
from tapcell.host.gcode import GCodeError, ShutdownError
from tapcell.tools import frontend

REASON = "Shutdown due to webhooks request"
WAIT_S = 120.0  # a deadline for a broken stop, never a timing: every wait ends on an event


class ScriptInThread:
    """Run a script on its own thread (the printer's thread) and keep what it ended with."""

    def __init__(self, printer, script: str):
        self.error: GCodeError | None = None
        self.done = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(printer, script), daemon=True)
        self._thread.start()

    def _run(self, printer, script: str) -> None:
        try:
            printer.gcode.run_script(script)
        except GCodeError as exc:
            self.error = exc
        finally:
            self.done.set()

    def join(self) -> GCodeError | None:
        assert self.done.wait(WAIT_S), "the script still runs after the emergency stop"
        return self.error


def count_taps(printer, after_taps: int):
    """(an event set once `after_taps` taps are recorded, the list of their print times)."""
    seen, reached = [], threading.Event()
    probe = next(iter(load_cell_streams.tap_probes(printer).values()))

    def on_tap(recorded) -> None:
        seen.append(printer.backend.now_s)
        if len(seen) >= after_taps:
            reached.set()

    probe.add_tap_client(on_tap)
    return reached, seen


def stop_after_taps(printer, script: str, after_taps: int):
    reached, taps = count_taps(printer, after_taps)
    running = ScriptInThread(printer, script)
    assert reached.wait(WAIT_S)
    printer.request_emergency_stop(REASON)
    taps_when_asked = len(taps)
    error = running.join()
    return error, len(taps) - taps_when_asked


def test_emergency_stop_during_a_mesh_aborts_it_and_applies_nothing(tmp_path):
    printer, responses = make_printer(tmp_path)
    bed_mesh = printer.lookup_object("bed_mesh")
    error, taps_after = stop_after_taps(printer, "G1 Z5 F600\nBED_MESH_CALIBRATE\nG1 Z30 F600", after_taps=3)
    assert isinstance(error, ShutdownError)
    assert str(error).startswith(REASON + "\nOnce the underlying issue is corrected, use RESTART")
    # Today's main ran 76-211 more taps and applied the mesh; now at most the tap in progress ends.
    assert taps_after <= 1
    assert bed_mesh.mesh is None and bed_mesh.get_status(0.0)["profile_name"] == ""
    vp = printer.backend
    assert vp.halted_at_s is not None and vp.now_s == pytest.approx(vp.halted_at_s)
    assert vp.position[2] < 25.0  # the script's last line never ran
    # Shut down until a restart; the heaters were turned off by the thread that ran the script.
    assert printer.state == "shutdown"
    with pytest.raises(GCodeError, match=REASON):
        printer.gcode.run_script("G1 Z30")
    printer.finish_shutdown()
    printer.gcode.run_script("RESTART")
    assert printer.state == "ready"


def test_emergency_stop_during_probe_accuracy_reports_no_result(tmp_path):
    printer, _ = make_printer(tmp_path)
    probe = printer.lookup_object("probe")
    before = probe.get_status(0.0)["last_z_result"]
    error, taps_after = stop_after_taps(printer, "G1 Z3 F600\nPROBE_ACCURACY SAMPLES=60", after_taps=5)
    assert isinstance(error, ShutdownError) and str(error).startswith(REASON)
    assert taps_after <= 1
    assert probe.get_status(0.0)["last_z_result"] == before


def moving_after(printer, after_s: float) -> threading.Event:
    """An event the virtual printer sets as it makes the samples `after_s` of print time from now
    (so the move is under way when the other thread sees it)."""
    vp = printer.backend
    at_s, moving = vp.now_s + after_s, threading.Event()
    compute = vp._compute

    def compute_and_tell(k0: int, k1: int):
        if vp._timing.window_start_s(k0) > at_s:
            moving.set()
        return compute(k0, k1)

    vp._compute = compute_and_tell
    return moving


def test_emergency_stop_during_a_long_move_stops_the_steppers(tmp_path):
    printer, responses = make_printer(tmp_path)
    printer.gcode.run_script("G1 X20 Y20 Z10 F6000")
    # 200 mm at 0.1 mm/s: 2000 s of print time, seconds of wall time here; under way after 10 s.
    started_s = printer.backend.now_s
    moving = moving_after(printer, 10.0)
    running = ScriptInThread(printer, "G1 X220 F6\nG1 X100 F6000")
    assert moving.wait(WAIT_S), running.error
    printer.request_emergency_stop(REASON)
    error = running.join()
    assert isinstance(error, ShutdownError)
    vp = printer.backend
    assert 10.0 < vp.halted_at_s - started_s < 1990.0
    x_mm = vp.position[0]
    assert x_mm == pytest.approx(20.0 + 0.1 * (vp.halted_at_s - started_s), abs=0.05)
    with pytest.raises(GCodeError):
        printer.gcode.run_script("G1 X100")
    assert vp.position[0] == x_mm


def _handler_before(_signum, _frame):  # SIGINT's handler before the console: none Python would pick
    raise AssertionError("SIGINT reached the handler the console found")


def test_ctrl_c_in_the_console_is_an_emergency_stop(tmp_path, capsys):
    # A handler of the test's own before the console, so that giving back Python's default (or the
    # ignored one a test run started in a shell's background has) cannot pass for giving back this.
    previous = signal.signal(signal.SIGINT, _handler_before)
    try:
        _console_stops_and_gives_ctrl_c_back(tmp_path, capsys)
    finally:
        signal.signal(signal.SIGINT, previous)


def _console_stops_and_gives_ctrl_c_back(tmp_path, capsys):
    printer, _ = make_printer(tmp_path)
    printer.gcode.set_response_sink(frontend._print_line)

    def press_ctrl_c_then_move(gcmd):
        signal.raise_signal(signal.SIGINT)  # the user presses Ctrl-C as the move starts
        printer.lookup_object("toolhead").move_to(x=200.0, speed_mm_s=1.0)

    printer.gcode.register_command("CTRL_C_DURING_MOVE", press_ctrl_c_then_move)
    lines = iter(["CTRL_C_DURING_MOVE", "G1 X100", "exit"])
    frontend.console_loop(printer, lambda prompt: next(lines))
    out = capsys.readouterr().out.splitlines()
    assert out[0] == f"!! {frontend.CONSOLE_STOP_REASON}"
    assert out[2] == f"!! {frontend.CONSOLE_STOP_REASON}"  # G1 X100 is refused with the same message
    assert printer.backend.halted_at_s is not None and printer.backend.position[0] < 111.0
    assert signal.getsignal(signal.SIGINT) is _handler_before  # the console gives Ctrl-C back as it found it


def test_ctrl_c_during_tapcell_run_stops_the_file(tmp_path, capsys):
    printer, _ = make_printer(tmp_path)
    printer.gcode.register_command("CTRL_C", lambda gcmd: signal.raise_signal(signal.SIGINT))
    script = tmp_path / "print.gcode"
    script.write_text("G1 X20 Y20 Z10 F6000\nCTRL_C\nG1 X220 F60\nG1 X100 F6000\n")
    assert frontend.run_script_file(printer, str(script), keep_going=False, echo=False) == 1
    captured = capsys.readouterr()
    assert captured.out.splitlines()[0] == f"!! {frontend.CONSOLE_STOP_REASON}"
    assert "print.gcode:3: stopped at the first error" in captured.err
    assert printer.backend.position[0] == pytest.approx(20.0) and printer.state == "shutdown"
