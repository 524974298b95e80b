"""A calibrated, homed virtual printer from examples/virtual-printer.cfg, for the probe tests."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from tapcell.host.gcode import GCodeError
from tapcell.host.printer import Printer

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "virtual-printer.cfg"
# The virtual cell's default 110 counts/g needs >= ~763 g to pass the calibration's 1 % rule.
CALIBRATION_G = 1000


def printer_text(scenario: str = "clean", probe_options: str = "", virtual_printer: str = "",
                 replace: dict[str, str] | None = None, sections: str = "") -> str:
    """The example config for `scenario`; `replace`: lines of the example to change (old -> new);
    `probe_options`: lines added to [load_cell_probe]; `sections`: whole sections added at the end."""
    # The extra [virtual_printer] lines go after the example's own (scenario, seed): later values win.
    text = EXAMPLE.read_text().replace("scenario: clean\nseed: 1\n", f"scenario: {scenario}\nseed: 1\n{virtual_printer}\n")
    # These tests measure probing after a plain G28 (Z homed where X and Y homed, no z_hop): the
    # example's [safe_z_home] (Z homed mid-bed, 5 mm hop) is for users and is tested on its own.
    text = re.sub(r"(?ms)^\[safe_z_home\]\n.*?(?=^\[)", "", text)
    assert "[safe_z_home]" not in text
    for old, new in (replace or {}).items():
        assert old in text, old
        text = text.replace(old, new)
    if scenario == "slow-adc":
        text = text.replace("sensor_type: hx717", "sensor_type: hx711").replace("sample_rate: 320", "sample_rate: 80")
        # At 80 sps a sensor that sticks at contact is stopped only after 7 samples (87.5 ms): the
        # force guard lets the measured bed (3.26 g/um x1.25) be met at 5 mm/s at most; 2 mm/s keeps
        # the tests' taps well inside that (an unmeasured bed, 100 g/um: 0.2 mm/s).
        text = text.replace("\nspeed: 5\n", "\nspeed: 2\n", 1)
    # The probe options go after [load_cell_probe]'s `samples: 1`; a changed example must fail here.
    assert "samples: 1\n" in text, "examples/virtual-printer.cfg: [load_cell_probe] lost its 'samples: 1' line"
    return text.replace("samples: 1\n", f"samples: 1\n{probe_options}\n", 1) + sections


def make_printer(tmp_path: Path, scenario: str = "clean", probe_options: str = "", virtual_printer: str = "",
                 calibrate: bool = True, home: bool = True, replace: dict[str, str] | None = None,
                 sections: str = "") -> tuple[Printer, list[str]]:
    path = tmp_path / f"{scenario}.cfg"
    path.write_text(printer_text(scenario, probe_options, virtual_printer, replace, sections))
    responses: list[str] = []
    printer = Printer.from_config(str(path), responses=responses)
    if calibrate:
        printer.gcode.run_script(f"LOAD_CELL_CALIBRATE\nTARE\nSIM_PLACE_WEIGHT GRAMS={CALIBRATION_G}\n"
                                 f"CALIBRATE GRAMS={CALIBRATION_G}\nACCEPT\nSIM_REMOVE_WEIGHT")
    if home:
        printer.gcode.run_script("G28\nG1 X110 Y110 F6000")
    printer.homed_at_s = printer.backend.now_s  # probing starts here (after the calibration weight)
    return printer, responses


def true_contact_z(printer: Printer) -> float:
    """The bed's true contact height under the nozzle, in toolhead coordinates (tests only)."""
    vp = printer.backend
    x, y, _ = vp.position
    return float(vp.truth.contact_z_at(x, y)) + printer.lookup_object("toolhead").frame_offset_mm["z"]


def true_peak_force_g(printer: Printer, since_s: float | None = None) -> float:
    """The largest true force on the cell (simulator truth, noise-free: corrupted frames do not
    count) from `since_s` to now; by default since homing (the calibration weight came before)."""
    start_s = printer.homed_at_s if since_s is None else since_s
    _, force_g = printer.backend.truth.force_g(start_s, printer.backend.now_s)
    return float(np.max(np.abs(force_g)))


def run_measured(printer: Printer, script: str) -> tuple[str | None, float, float]:
    """(error or None, true peak force in g, nozzle clearance in mm after it) of `script`."""
    truth = printer.backend.truth
    truth.take_peak_force_g()
    try:
        printer.gcode.run_script(script)
        error = None
    except GCodeError as exc:
        error = str(exc)
    return error, truth.take_peak_force_g(), truth.nozzle_clearance_mm
