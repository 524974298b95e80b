"""`tapcell demo` (`make demo`): the main job on the virtual printer, explained.

The main job is a first layer that sticks everywhere. The demo starts the virtual printer
with a warped bed (examples/virtual-printer.cfg), checks and calibrates the load cell with a
known weight, heats the nozzle to the probing temperature, homes, measures the probe's
repeatability (PROBE_ACCURACY), plots the last tap with its five lines and six points into
`out/last-tap.png`, cleans the nozzle (NOZZLE_CLEANUP), probes a 7 x 7 mesh (BED_MESH_CALIBRATE, with a progress bar), prints the
mesh and how far it is from the true bed (which only the simulator knows), writes heat maps
of the mesh and of its error into `out/`, shows a first-layer move following the bed, and saves the
calibrated printer in `out/printer.cfg`, ending with the command to go on from it in the console.
Every G-code line is printed with the printer's responses and a short explanation, so a
newcomer can follow and repeat it in `tapcell console`.

With `--config` a config without a probe runs the load-cell (scale) steps only. Each step
is a `DemoStep` (an explanation, G-code lines, and optionally something the runner shows after).
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from tapcell.extras.bed_mesh import PROGRESS_EVENT
from tapcell.host.config import ConfigError
from tapcell.tools.frontend import DEFAULT_CONFIG as EXAMPLE_CONFIG
from tapcell.host.gcode import GCodeError
from tapcell.mesh.report import mesh_error, render_mesh_error, write_mesh_png
from tapcell.host.printer import Printer
from tapcell.tap.plot import plot_tap
from tapcell.tools.workspace import with_scenario

DEMO_SCENARIO = "warped-bed"
CALIBRATION_WEIGHT_G = 1000.0
TEST_WEIGHT_G = 250.0
PROBING_TEMPERATURE_C = 140  # the guide: below any filament's ooze point
MESH_CENTER_XY_MM = (117.5, 117.5)
# While the mesh is probed these per-tap lines feed the progress bar instead of the screen.
PER_TAP_LINE = re.compile(r"^// (probe at |Tap Quality)")
ACCURACY_SAMPLES = 10


@dataclass(frozen=True)
class DemoStep:
    title: str
    explanation: str
    gcode: tuple[str, ...]
    progress: bool = False  # show a progress bar (BED_MESH_CALIBRATE) instead of per-tap lines
    show: Callable[[DemoRunner], None] | None = None  # what the runner shows after the G-code


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


PROBE_STEPS = (
    DemoStep(
        "Heat the nozzle to the probing temperature",
        f"A hot nozzle is longer than a cold one, so home and probe at one temperature. "
        f"{PROBING_TEMPERATURE_C} C is below every filament's ooze point (the guide's advice): a "
        "drop of molten plastic under the nozzle is the main source of probing error.",
        (f"M109 S{PROBING_TEMPERATURE_C}",),
    ),
    DemoStep(
        "Home, then set Z exactly with one tap",
        "G28 homes X and Y on their switches, then ([safe_z_home]) goes to the middle of the bed and "
        "homes Z by pressing the nozzle on the bed until the load cell reads {trigger_force_g:g} g. Z = 0 "
        "is where the nozzle stopped: already pressed a few hundredths of a mm into the bed (the force "
        "over the bed's stiffness, plus the travel until the halt), so the PROBE below first reads the "
        "bed that much above 0 (z=0.03 or so). PROBE HOME=Z analyses its tap to find where the nozzle "
        "really touched (break contact) and makes that point Z = 0.",
        ("G28", f"G1 X{MESH_CENTER_XY_MM[0]:g} Y{MESH_CENTER_XY_MM[1]:g} Z3 F6000", "PROBE HOME=Z"),
    ),
    DemoStep(
        "How repeatable is the probe? PROBE_ACCURACY",
        f"PROBE_ACCURACY taps {ACCURACY_SAMPLES} times at the same place from 0.4 mm above the bed and "
        "reports the spread. Each tap: press until the load cell reads {trigger_force_g:g} g, stop, wait "
        "{dwell_samples} samples ({dwell_ms:.0f} ms at {sample_rate_sps:g} samples/s), pull back "
        "{pullback_mm:g} mm at 1 um per sample while watching the force fall, and find in those samples "
        "the height where the nozzle left the bed. A standard deviation well below 1 um is what a load "
        "cell can do; every tap must pass its checks, or the command stops and says why.",
        ("G1 Z0.4", f"PROBE_ACCURACY SAMPLES={ACCURACY_SAMPLES} SAMPLE_RETRACT_DIST=0.4"),
    ),
    DemoStep(
        "Look at the last tap",
        "The plot shows the force during the last tap: the five fitted lines (approach, compression, "
        "dwell, decompression, departure) and the six points where they meet (P0..P5). The probe's "
        "answer is the height at P4, break contact: the moment the nozzle left the bed. The taps are "
        "also written as a tap file that `tapcell analyze` reads.",
        (),
        show=lambda runner: runner.plot_last_tap(),
    ),
)


MESH_STEPS = (
    DemoStep(
        "Clean the nozzle",
        "NOZZLE_CLEANUP taps a small zig-zag outside the print area until 3 taps in a row are good: "
        "proof that nothing sticks to the nozzle before the mesh.",
        ("G1 X10 Y10 Z2 F6000", "NOZZLE_CLEANUP"),
    ),
    DemoStep(
        "Probe the bed: a 7 x 7 mesh",
        "BED_MESH_CALIBRATE taps 49 points in a zig-zag (serpentine) order. Between points the nozzle "
        "lifts only 0.4 mm above the last touch (horizontal_z_clearance), so it follows the bed and "
        "travels little. BAD_PROBE_STRATEGY=CIRCLE: a tap spoiled by ooze is retried a little to the "
        "side instead of in the same fouled spot. Two clocks: the printer's (in what the printer says, "
        "the time a real printer would take) and this computer's (the virtual printer runs faster than "
        "real time); the progress line labels both.",
        ("BED_MESH_CALIBRATE BAD_PROBE_STRATEGY=CIRCLE",),
        progress=True,
    ),
    DemoStep(
        "Look at the mesh",
        "BED_MESH_OUTPUT prints the mesh as Klipper does: the probed heights (front row first), then "
        "the mesh moves follow, interpolated (bicubic) between the points into a smooth surface, with "
        "its average and range (back row first, as seen from above).",
        ("BED_MESH_OUTPUT",),
    ),
    DemoStep(
        "A first-layer move follows the bed",
        "With a mesh active every G1 is cut into short pieces (every 3 mm where the bed changes by "
        "10 um or more) and each piece is raised or lowered by the bed height there. M114 still reports "
        "the G-code position: Z 0.2 above the bed, wherever the bed is (to the nearest Z motor step, 2.5 um).",
        ("G1 X30 Y30 Z0.2 F6000", "G1 X200 Y200", "M114"),
    ),
)


KEEP_STEP = DemoStep(
    "Keep it",
    "SAVE_CONFIG writes what is still pending (the mesh profile 'default') into the printer config; "
    "at the next start the mesh is loaded by itself.",
    ("SAVE_CONFIG",),
)


class DemoRunner:
    """Runs G-code on a printer, printing each line with its responses."""

    def __init__(self, config_path: Path, console: Console, out_dir: Path = Path("out")):
        self.console = console
        self.out_dir = out_dir
        self.responses: list[str] = []
        self.hidden_lines = 0
        self._progress: Progress | None = None
        self.printer = Printer.from_config(str(config_path), responses=self._show_response)

    def _show_response(self, line: str) -> None:
        self.responses.append(line)
        if self._progress is not None and PER_TAP_LINE.match(line):
            self.hidden_lines += 1
            return
        self.print_exact(f"    {line}", "red" if line.startswith("!!") else "green")

    def print_exact(self, text: str, style: str | None = None) -> None:
        """Print as is: never wrapped (a response cut at 80 columns loses its `// ` prefix and breaks
        numbers; the terminal may still fold a long line, a file or pipe keeps it whole)."""
        self.console.print(text, style=style, markup=False, highlight=False, soft_wrap=True)

    def can_probe_a_mesh(self) -> bool:
        return self.printer.lookup_object("bed_mesh", None) is not None and \
            self.printer.lookup_object("probe", None) is not None

    def probe_facts(self) -> dict[str, float]:
        """The probe's numbers the explanations quote, from the printer's own settings."""
        device = self.printer.lookup_object("load_cell_probe")
        options = device.options
        return {"trigger_force_g": options.trigger_force_g, "dwell_samples": device.dwell_samples,
                "dwell_ms": 1000.0 * device.dwell_samples / device.sample_rate_sps,
                "sample_rate_sps": device.sample_rate_sps, "pullback_mm": options.pullback_distance_mm}

    def run_step(self, number: int, step: DemoStep) -> None:
        self.console.rule(f"[bold]Step {number}: {step.title}")
        explanation = step.explanation.format_map(self.probe_facts()) if "{" in step.explanation \
            else step.explanation
        self.console.print(explanation, style="dim", markup=False, highlight=False)
        for line in step.gcode:
            self.print_exact(f"> {line}", "bold cyan")
            if step.progress:
                self._run_with_progress(line)
            else:
                self.printer.gcode.run_line(line)
        if step.show is not None:
            step.show(self)

    def plot_last_tap(self) -> None:
        """The last tap as a PNG (five lines, six points) and the kept taps as a tap file."""
        device = self.printer.lookup_object("load_cell_probe")
        last = device.last_taps[-1]
        self.out_dir.mkdir(parents=True, exist_ok=True)
        png = self.out_dir / "last-tap.png"
        plot_tap(last.tap, last.analysis, png, title="Last tap of PROBE_ACCURACY")
        taps = self.out_dir / "last-taps.jsonl"
        count = device.write_last_taps(taps)
        for name, (t_s, force_g) in zip(("P0", "P1", "P2", "P3", "P4", "P5"), last.analysis.points):
            self.print_exact(f"    {name}  t = {t_s - last.tap.time_s[0]:6.3f} s  force = {force_g:7.1f} g")
        self.print_exact(f"Tap plot: {png}; the last {count} taps: {taps} (tapcell analyze {taps})")

    def _run_with_progress(self, line: str) -> None:
        columns = (TextColumn("    probing"), BarColumn(), MofNCompleteColumn(), TextColumn("points,"),
                   TextColumn("printer time {task.fields[printer_s]:.1f} s, this computer's"), TimeElapsedColumn())
        start_s = self.printer.get_time()
        with Progress(*columns, console=self.console, transient=False) as progress:
            task = progress.add_task("mesh", total=None, printer_s=0.0)

            def advance(done: int, total: int) -> None:
                progress.update(task, completed=done, total=total, printer_s=self.printer.get_time() - start_s)

            self.printer.register_event_handler(PROGRESS_EVENT, advance)
            self._progress = progress
            try:
                self.printer.gcode.run_line(line)
            finally:
                self._progress = None
        self.console.print(f"    ({self.hidden_lines} per-tap lines not shown: 'probe at X,Y is z=...' and "
                           "'Tap Quality')", style="dim", markup=False)

    def compare_with_truth(self, out_dir: Path) -> None:
        """What only a simulator can show: the mesh against the bed it really has."""
        printer = self.printer
        mesh = printer.lookup_object("bed_mesh").mesh
        truth = printer.backend.truth
        frame_z_mm = printer.lookup_object("toolhead").frame_offset_mm["z"]

        def true_bed_mm(x_mm, y_mm):
            # Where the nozzle touches, in the printer's Z (homing put Z = 0 at the centre touch).
            return truth.contact_z_at(x_mm, y_mm) + frame_z_mm

        self.console.rule("[bold]The mesh against the true bed")
        self.console.print(
            "The virtual printer knows its bed exactly (a real printer does not). The probed points "
            "show how well each tap measured; between them, what the interpolation misses.",
            style="dim", markup=False)
        self.print_exact(render_mesh_error(mesh_error(mesh, true_bed_mm)))
        out_dir.mkdir(parents=True, exist_ok=True)
        mesh_png = write_mesh_png(out_dir / "bed-mesh.png", mesh)
        error_png = write_mesh_png(out_dir / "bed-mesh-error.png", mesh, true_bed_mm)
        self.print_exact(f"Heat maps: {mesh_png} (the mesh) and {error_png} (mesh and mesh - true bed)")


def console_command(config_path: Path) -> str:
    """The exact command that opens the console on `config_path` from here (this Python's tapcell)."""
    script = Path(sys.executable).with_name("tapcell")
    if not script.exists():
        return f"{sys.executable} -m tapcell console --config {config_path}"
    found = shutil.which("tapcell")
    if found and Path(found).resolve() == script.resolve():
        return f"tapcell console --config {config_path}"
    relative = os.path.relpath(script)
    return f"{relative if not relative.startswith('..') else script} console --config {config_path}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="tapcell demo", description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", type=Path, default=None,
                        help="printer config to start from (copied: the demo never changes it); "
                             f"default: {EXAMPLE_CONFIG.name} with the '{DEMO_SCENARIO}' scenario")
    parser.add_argument("--out", type=Path, default=Path("out"),
                        help="where the printer config, the PNGs and the tap file go (default: out)")
    args = parser.parse_args(argv)
    console = Console(highlight=False)
    # The demo's printer config lives in the output folder: calibrated by the demo, it is where
    # the user continues from (never the tracked example).
    args.out.mkdir(parents=True, exist_ok=True)
    config_path = args.out / "printer.cfg"
    if args.config is None:
        config_path.write_text(with_scenario(EXAMPLE_CONFIG.read_text(encoding="utf-8"), DEMO_SCENARIO),
                               encoding="utf-8")
        console.print(f"Starting the virtual printer from {EXAMPLE_CONFIG.name} with a warped bed "
                      f"(scenario '{DEMO_SCENARIO}'; the demo works on {config_path}).")
    else:
        shutil.copyfile(args.config, config_path)
        console.print(f"Starting the virtual printer from {args.config} (the demo works on a copy: {config_path}).")
    try:
        runner = DemoRunner(config_path, console, args.out)
    except ConfigError as exc:
        console.print(f"The printer did not start: {exc}", style="bold red", markup=False)
        return 1
    try:
        steps = SCALE_STEPS + (PROBE_STEPS + MESH_STEPS if runner.can_probe_a_mesh() else ())
        for number, step in enumerate(steps, start=1):
            runner.run_step(number, step)
        if runner.can_probe_a_mesh():
            runner.compare_with_truth(args.out)
            runner.run_step(len(steps) + 1, KEEP_STEP)
    except GCodeError as exc:
        console.print(f"!! {exc}", style="bold red", markup=False)
        return 1
    console.rule("[bold]Done")
    console.print(f"The calibrated printer is in {config_path}. Continue from it:", markup=False)
    runner.print_exact(f"    {console_command(config_path)}")
    return 0
