"""`tapcell demo` (`make demo`): the main job on the virtual printer, explained.

For now: start the virtual printer, check the load cell with LOAD_CELL_DIAGNOSTIC,
calibrate it with a known weight, and weigh something. Every G-code line is printed
with the printer's responses and a short explanation, so a newcomer can follow and
repeat it in `tapcell console`.

Later features add steps: each step is a `DemoStep` (an explanation and G-code lines).
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

from rich.console import Console

from tapcell.config import ConfigError
from tapcell.gcode import GCodeError
from tapcell.printer import Printer

# The scale steps need only the virtual printer and its load cell. Steps that probe
# will start from examples/virtual-printer.cfg (with [load_cell_probe]) instead.
SCALE_CONFIG = """\
# The demo's printer: the virtual printer (scenario 'clean': HX717 at 320 sps) and
# its load cell used as a scale.
[virtual_printer]
scenario: clean
seed: 1

[load_cell]
sensor_type: hx717
sclk_pin: PA5
dout_pin: PA4
sample_rate: 320
"""
CALIBRATION_WEIGHT_G = 1000.0
TEST_WEIGHT_G = 250.0


@dataclass(frozen=True)
class DemoStep:
    title: str
    explanation: str
    gcode: tuple[str, ...]


SCALE_STEPS = (
    DemoStep(
        "Check the sensor",
        "LOAD_CELL_DIAGNOSTIC listens to the load cell for 10 s. The sample rate should match the "
        "configured one, no sample should be saturated, and many different values mean a live, "
        "noisy-as-expected sensor (a single value would mean a wiring fault). Not calibrated yet, "
        "so everything is in raw counts and % of the sensor's range.",
        ("LOAD_CELL_DIAGNOSTIC",),
    ),
    DemoStep(
        "Calibrate with a known weight",
        "Calibration finds how many sensor counts one gram makes. TARE reads the cell with no "
        f"load; then a {CALIBRATION_WEIGHT_G:g} g weight goes on (SIM_PLACE_WEIGHT does that on the virtual "
        "printer; on a real one you put a weight or press on a kitchen scale) and CALIBRATE GRAMS= "
        "reads it. ACCEPT keeps the result; SAVE_CONFIG writes it into the config file.",
        ("LOAD_CELL_CALIBRATE", "TARE", f"SIM_PLACE_WEIGHT GRAMS={CALIBRATION_WEIGHT_G:g}",
         f"CALIBRATE GRAMS={CALIBRATION_WEIGHT_G:g}", "ACCEPT", "SIM_REMOVE_WEIGHT", "SAVE_CONFIG"),
    ),
    DemoStep(
        "Weigh something",
        f"With the cell calibrated, LOAD_CELL_TARE makes 'nothing' the zero, and a {TEST_WEIGHT_G:g} g "
        "object should read as such. LOAD_CELL_READ averages one second of samples.",
        ("LOAD_CELL_TARE", f"SIM_PLACE_WEIGHT GRAMS={TEST_WEIGHT_G:g}", "LOAD_CELL_READ"),
    ),
    DemoStep(
        "The diagnostic again, now in grams",
        "Calibrated, the diagnostic also shows the spread of the samples in grams: the noise of "
        "this load cell while the weight rests on it.",
        ("LOAD_CELL_DIAGNOSTIC", "SIM_REMOVE_WEIGHT"),
    ),
)


class DemoRunner:
    """Runs G-code on a printer, printing each line with its responses."""

    def __init__(self, config_path: Path, console: Console):
        self.console = console
        self.responses: list[str] = []
        self.printer = Printer.from_config(str(config_path), responses=self._show_response)

    def _show_response(self, line: str) -> None:
        self.responses.append(line)
        style = "red" if line.startswith("!!") else "green"
        self.console.print(f"    {line}", style=style, markup=False, highlight=False)

    def run_step(self, number: int, step: DemoStep) -> None:
        self.console.rule(f"[bold]Step {number}: {step.title}")
        self.console.print(step.explanation, style="dim", markup=False, highlight=False)
        for line in step.gcode:
            self.console.print(f"> {line}", style="bold cyan", markup=False, highlight=False)
            self.printer.gcode.run_line(line)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="tapcell demo", description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", type=Path, default=None,
                        help="printer config to start from (copied: the demo never changes it); "
                             "default: a virtual printer with one [load_cell]")
    args = parser.parse_args(argv)
    console = Console(highlight=False)
    with tempfile.TemporaryDirectory(prefix="tapcell-demo-") as workdir:
        config_path = Path(workdir) / "printer.cfg"
        if args.config is None:
            config_path.write_text(SCALE_CONFIG)
            console.print(f"Starting the virtual printer with one load cell (config: {config_path}).")
        else:
            shutil.copyfile(args.config, config_path)
            console.print(f"Starting the virtual printer from {args.config} (a copy in {config_path}).")
        try:
            runner = DemoRunner(config_path, console)
        except ConfigError as exc:
            console.print(f"The printer did not start: {exc}", style="bold red", markup=False)
            return 1
        try:
            for number, step in enumerate(SCALE_STEPS, start=1):
                runner.run_step(number, step)
        except GCodeError as exc:
            console.print(f"!! {exc}", style="bold red", markup=False)
            return 1
        console.rule("[bold]Done")
        console.print("Try it yourself: tapcell console  (HELP lists the commands)", markup=False)
    return 0
