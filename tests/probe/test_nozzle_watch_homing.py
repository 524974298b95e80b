"""The nozzle watch on G28 X / G28 Y: an endstop move that starts with the nozzle low runs watched.

With Z low (after a print, after G28 Z without z_hop) homing X or Y drags the nozzle across the
bed toward the endstop. Over a 1.5 mm blob with 45-degree flanks (a clip, a part left on the bed)
the calibrated example printer without [safe_z_home] presses it with ~4.1 kg (SIM_TRUTH) and
homes as if nothing happened when the watch is off; with the watch the move stops at the first
sample over nozzle_watch_force, the nozzle is lifted, the command ends with the collision error
naming 'G28 X', and the axis is not homed. `python -m bench nozzle_watch --only G28` prints the same
cases.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from probe_vprinter import make_printer

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the bench package beside tests/
from bench.nozzle_watch import bump_csv  # noqa: E402  (after the path)
from tapcell.host.gcode import GCodeError  # noqa: E402

FORCE_SAFETY_LIMIT_G = 2000.0
WATCH_OFF = "nozzle_watch_height: 0"
COLLISION = "Load Cell Probe Error: nozzle collision at "
SAFE_Z_HOME = "\n[safe_z_home]\nhome_xy_position: 117.5, 117.5\nz_hop: 5\nz_hop_speed: 10\n"
# A blob between the nozzle (X 110, Y 110) and each endstop (0).
BLOB_XY = {"X": (60.0, 110.0), "Y": (110.0, 60.0)}


def printer_in(folder, **options):
    folder.mkdir()
    printer, _ = make_printer(folder, **options)
    return printer


def run(printer, script: str) -> tuple[str | None, float, float, float]:
    """(error or None, true peak force g, nozzle clearance mm after, printer seconds) of `script`."""
    truth = printer.backend.truth
    truth.take_peak_force_g()
    start_s = printer.backend.now_s
    try:
        printer.gcode.run_script(script)
        error = None
    except GCodeError as exc:
        error = str(exc)
    return error, truth.take_peak_force_g(), truth.nozzle_clearance_mm, printer.backend.now_s - start_s


def blob_under(tmp_path, axis: str) -> str:
    return bump_csv(tmp_path / f"blob-{axis}.csv", *BLOB_XY[axis], 1.5, 1.5)


@pytest.mark.parametrize("axis", ["X", "Y"])
def test_homing_at_low_z_over_a_blob_is_stopped_below_the_limit(tmp_path, axis):
    bed = blob_under(tmp_path, axis)
    off = printer_in(tmp_path / "off", probe_options=WATCH_OFF, virtual_printer=bed)
    error, peak_g, _, _ = run(off, f"G1 Z0.3 F600\nG28 {axis}")
    assert error is None and peak_g > 2 * FORCE_SAFETY_LIMIT_G   # 4,117 g measured, homed as if nothing happened
    on = printer_in(tmp_path / "on", virtual_printer=bed)
    toolhead = on.lookup_object("toolhead")
    error, peak_g, clearance_mm, _ = run(on, f"G1 Z0.3 F600\nG28 {axis}")
    assert error is not None and error.startswith(COLLISION), error
    assert f"during 'G28 {axis}'" in error
    # 761 g measured: a force stops the move on its second sample past 250 g, at the 40 mm/s cap
    # (484 g when one sample stopped it, at 50 mm/s).
    assert peak_g < 0.45 * FORCE_SAFETY_LIMIT_G
    assert clearance_mm > 1.5                     # lifted to nozzle_watch_height (2 mm): 1.855 mm
    where = [float(v) for v in error[len(COLLISION):].split(" ")[0].split(",")]
    index = "XY".index(axis)
    assert BLOB_XY[axis][index] < where[index] < BLOB_XY[axis][index] + 1.5   # on the blob's near flank
    assert axis.lower() not in toolhead.homed_axes and "z" in toolhead.homed_axes   # stopped: not homed
    # Homing still works once the nozzle is above the blob: X/Y at the endstop, Z untouched.
    error, peak_g, _, _ = run(on, f"G1 Z5 F600\nG28 {axis}")
    assert error is None and peak_g == 0.0 and axis.lower() in toolhead.homed_axes
    assert toolhead.get_position()[index] == 0.0


def test_homing_at_a_safe_height_costs_nothing_and_low_runs_at_the_cap(tmp_path):
    """Above nozzle_watch_height nothing is watched: the same printer time. Below it on the measured
    bed (G28 Z read it) G28 X runs at the watch's speed cap (40 mm/s, a force confirmed on two
    samples), not the homing speed (50 mm/s): 0.55 s more over the 110 mm to the endstop."""
    times = {}
    for name, options in (("off", WATCH_OFF), ("on", "")):
        printer = printer_in(tmp_path / name, probe_options=options)
        watch = printer.lookup_object("toolhead").nozzle_watch
        before = watch.watched_moves
        error, _, _, times[name, "high"] = run(printer, "G1 Z10 F600\nG28 X")
        assert error is None and watch.watched_moves == before
        error, peak_g, _, times[name, "low"] = run(printer, "G1 X110 F6000\nG1 Z0.3 F600\nG28 X")
        assert error is None and peak_g == 0.0
        assert watch.watched_moves == before + (0 if name == "off" else 2)   # the Z move down and G28 X
    assert times["on", "high"] == times["off", "high"]
    assert times["on", "low"] - times["off", "low"] == pytest.approx(110.0 / 40.0 - 110.0 / 50.0, abs=0.02)


def test_homing_after_motors_off_with_the_nozzle_low_is_watched(tmp_path):
    """Z not homed after M84 but the bed measured by G28 Z: nobody knows how low the nozzle is,
    so G28 X runs watched."""
    printer = printer_in(tmp_path / "p", virtual_printer=blob_under(tmp_path, "X"))
    error, peak_g, clearance_mm, _ = run(printer, "G1 Z0.3 F600\nM84\nG28 X")
    assert error is not None and error.startswith(COLLISION) and "during 'G28 X'" in error, error
    assert peak_g < 0.45 * FORCE_SAFETY_LIMIT_G and clearance_mm > 1.5   # 761 g measured


def test_a_fresh_printer_with_z_not_homed_homes_x_unwatched(tmp_path):
    """A bed never measured: the watch would have to crawl (3 mm/s), so [safe_z_home] z_hop is what
    guards it (docs/safety.md): G28 X runs as before."""
    printer = printer_in(tmp_path / "p", home=False)
    watch = printer.lookup_object("toolhead").nozzle_watch
    error, _, _, seconds = run(printer, "G28 X")
    assert error is None and watch.watched_moves == 0 and seconds < 3.0


def test_safe_z_home_hops_before_homing_x_so_the_blob_is_never_met(tmp_path):
    """The example's [safe_z_home] z_hop: 5 lifts Z (homed, below 5) before G28 X: no contact, no watch."""
    printer = printer_in(tmp_path / "p", virtual_printer=blob_under(tmp_path, "X"), sections=SAFE_Z_HOME)
    watch = printer.lookup_object("toolhead").nozzle_watch
    printer.gcode.run_script("G1 X110 Y110 F6000\nG1 Z0.3 F600")
    before = watch.watched_moves
    error, peak_g, clearance_mm, _ = run(printer, "G28 X")
    assert error is None and peak_g == 0.0 and clearance_mm > 4.9
    assert watch.watched_moves == before
    # Z not homed: the hop is relative (by z_hop), and 5 mm up is trusted to clear the bed.
    error, peak_g, _, _ = run(printer, "G1 X110 F6000\nG1 Z0.3 F600\nM84\nG28 X")
    assert error is None and peak_g == 0.0 and watch.watched_moves == before + 1   # only G1 Z0.3 watched
    assert printer.lookup_object("toolhead").z_lift_while_unhomed_mm == 5.0


def test_homing_after_set_kinematic_position_low_on_an_unmeasured_bed_crawls_and_stops(tmp_path):
    """SET_KINEMATIC_POSITION Z=0.3 on a fresh printer (nozzle truly 0.3 mm up): Z counts as homed and
    low, but no G28 Z measured the bed, so G28 X is watched at the speed that is safe on the stiffest
    bed assumed (2 mm/s at 320 sps), says so, and stops on the blob."""
    # The virtual printer starts at the bed's middle (117.5, 117.5): the blob in its path to X 0.
    world = bump_csv(tmp_path / "blob.csv", 60.0, 117.5, 1.5, 1.5) + "start_z_mm: 0.3\n"
    printer, responses = make_printer(tmp_path, virtual_printer=world, home=False,
                                      sections="\n[force_move]\nenable_force_move: True\n")
    printer.gcode.run_script("SET_KINEMATIC_POSITION Z=0.3")
    error, peak_g, clearance_mm, _ = run(printer, "G28 X")
    assert "Homing X at 2 mm/s, not 50 mm/s, with the nozzle watch: Z is low" in "\n".join(responses)
    assert error is not None and error.startswith(COLLISION) and "during 'G28 X'" in error, error
    assert peak_g < 1.5 * 250.0 and clearance_mm > 1.5   # 271 g measured: the 250 g trigger plus two slow samples


def test_a_g28_x_inside_homing_override_is_watched(tmp_path):
    """[homing_override]'s own G28 X runs the original homing: watched just the same."""
    override = "\n[homing_override]\ngcode:\n    G28 X\n    G28 Y\n    G28 Z\naxes: x\n"
    printer = printer_in(tmp_path / "p", virtual_printer=blob_under(tmp_path, "X"), sections=override)
    error, peak_g, clearance_mm, _ = run(printer, "G1 Z0.3 F600\nG28 X")
    assert error is not None and error.startswith(COLLISION) and "during 'G28 X'" in error, error
    assert peak_g < 0.45 * FORCE_SAFETY_LIMIT_G and clearance_mm > 1.5   # 761 g measured
