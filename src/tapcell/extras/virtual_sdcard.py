"""`[virtual_sdcard]`: print a G-code file from a folder (Moonraker's gcodes folder).

Mainsail's and Fluidd's Print button sends `SDCARD_PRINT_FILE FILENAME=<name>`; the file's
lines then run one after another while the API keeps answering, with `virtual_sdcard`
(file_path, progress, is_active, file_position, file_size) and `print_stats` (made here) for
the progress bars and Moonraker's job history. PAUSE/RESUME/CANCEL_PRINT (of [pause_resume] or
tapcell serve's stand-ins) pause, resume and cancel the file; a G-code error stops the print with
`print_stats.state` "error" and runs `on_error_gcode`. An unknown command in a file is reported
and skipped, as Klipper does (slicers write commands for other firmwares).

Behind `tapcell serve` the printer thread feeds the file while its moves play in real time (at
most FEED_AHEAD_S ahead, like Klipper's lookahead); without a live server (`tapcell run`, the
console) SDCARD_PRINT_FILE runs the whole file before it returns.

`tapcell serve --gcodes-dir DIR` gives a config without a [virtual_sdcard] section one at DIR.

Commands: SDCARD_PRINT_FILE FILENAME=, SDCARD_RESET_FILE, M20 (list), M21, M23 <file> (select),
M24 (start/resume), M25 (pause), M26 S<byte> (set the position), M27 (report).
"""

from __future__ import annotations

import os

from tapcell.extras import print_stats as print_stats_module
from tapcell.host.config import ConfigSection
from tapcell.host.gcode import GCodeCommand, GCodeError, UnknownCommandError
from tapcell.host.print_clock import FEED_AHEAD_S
from tapcell.host.templates import GCodeTemplate, StatusView, compile_template

SECTION = "virtual_sdcard"
MAX_LINES_PER_FEED = 500  # then the printer thread serves the API again
GCODE_EXTENSIONS = (".gcode", ".g", ".gco")


class VirtualSDCard:
    def __init__(self, printer, folder: str, on_error: GCodeTemplate | None):
        self.printer = printer
        self.folder = os.path.normpath(os.path.expanduser(folder))
        self.on_error = on_error
        self.stats = print_stats_module.attach(printer)
        self.file = None  # the selected file, open in binary mode
        self.file_path: str | None = None
        self.file_size = 0
        self.position = 0
        self.printing = False  # feeding lines (not paused, not finished)

    # -- files ----------------------------------------------------------------------------
    def _resolve(self, gcmd: GCodeCommand, name: str) -> str:
        """The file's path inside the folder; a name that leaves it or does not exist is an error."""
        name = name.strip().strip('"').lstrip("/")
        path = os.path.normpath(os.path.join(self.folder, name))
        if os.path.commonpath([path, self.folder]) != self.folder or not os.path.isfile(path):
            raise gcmd.error(f"Unable to open file '{name}' in {self.folder}")
        return path

    def select(self, gcmd: GCodeCommand, name: str) -> None:
        if self.printing:
            raise gcmd.error("SD busy: a file is printing (PAUSE or CANCEL_PRINT it first)")
        path = self._resolve(gcmd, name)
        self.reset_file()
        self.file = open(path, "rb")  # noqa: SIM115 (kept open while the print runs)
        self.file_path = path
        self.file_size = os.path.getsize(path)
        self.position = 0
        gcmd.respond_raw(f"File opened:{name.strip().strip(chr(34)).lstrip('/')} Size:{self.file_size}")
        gcmd.respond_raw("File selected")

    def close(self) -> None:
        """Close the file; its size and the position reached stay in the status (a finished print
        shows progress 1.0) until another file is selected or SDCARD_RESET_FILE."""
        if self.file is not None:
            self.file.close()
        self.file, self.file_path = None, None

    def reset_file(self) -> None:
        self.close()
        self.file_size, self.position = 0, 0

    def is_active(self) -> bool:
        return self.printing

    # -- the print ------------------------------------------------------------------------
    def start(self) -> None:
        """Start or resume the selected file."""
        self.printing = True
        self.stats.note_start(os.path.relpath(self.file_path, self.folder))
        if self.printer.print_clock is None:  # no live server: the whole file now
            self.feed(until_done=True)

    def pause(self) -> None:
        if self.printing:
            self.printing = False
            self.stats.note_pause()

    def resume(self) -> None:
        """RESUME: a paused file prints on (nothing happens when no file was paused)."""
        if self.file is not None and self.stats.state == "paused":
            self.start()

    def stop_on_shutdown(self) -> None:
        if self.printing or self.stats.state == "paused":
            self.printing = False
            self.stats.note_error("Printer shut down")
            self.close()

    def cancel(self) -> None:
        if self.printing or self.stats.state == "paused":
            self.printing = False
            self.stats.note_cancel()
            self.close()

    def feed(self, until_done: bool = False) -> None:
        """Run the file's next lines: while the queued moves are less than FEED_AHEAD_S ahead (or all
        of them, `until_done`). PAUSE from inside the file stops the feed after its line."""
        clock = self.printer.print_clock
        lines = 0
        while self.printing and (until_done or (lines < MAX_LINES_PER_FEED
                                               and (clock is None or clock.lead_s() < FEED_AHEAD_S))):
            raw = self.file.readline()
            if not raw:
                self.printing = False
                self.stats.note_complete()
                self.close()
                return
            self.position += len(raw)
            lines += 1
            self._run_line(raw.decode("utf-8", errors="replace").rstrip("\r\n"))
            self.stats.update()

    def _run_line(self, line: str) -> None:
        gcode = self.printer.gcode
        try:
            gcode.run_line(line)
        except UnknownCommandError as exc:
            gcode.respond_info(str(exc))
        except GCodeError as exc:
            self.printing = False
            gcode.respond_error(str(exc))
            self.stats.note_error(str(exc))
            self.close()
            if self.on_error is not None:
                try:
                    gcode.run_script(self.on_error.render({"printer": StatusView(self.printer)}))
                except GCodeError as error:
                    gcode.respond_error(f"on_error_gcode failed: {error}")

    # -- commands -------------------------------------------------------------------------
    def cmd_SDCARD_PRINT_FILE(self, gcmd: GCodeCommand) -> None:
        self.select(gcmd, gcmd.get("FILENAME"))
        self.start()

    def cmd_SDCARD_RESET_FILE(self, gcmd: GCodeCommand) -> None:
        if self.printing:
            raise gcmd.error("SDCARD_RESET_FILE cannot be run from the sdcard (a file is printing)")
        self.reset_file()
        self.stats.reset()

    def cmd_M20(self, gcmd: GCodeCommand) -> None:
        names = []
        for root, _, files in os.walk(self.folder):
            names += [os.path.relpath(os.path.join(root, f), self.folder) for f in files
                      if f.lower().endswith(GCODE_EXTENSIONS)]
        lines = ["Begin file list"]
        lines += [f"{name} {os.path.getsize(os.path.join(self.folder, name))}" for name in sorted(names)]
        lines.append("End file list")
        gcmd.respond_raw("\n".join(lines))

    def cmd_M21(self, gcmd: GCodeCommand) -> None:
        gcmd.respond_raw("SD card ok")

    def cmd_M23(self, gcmd: GCodeCommand) -> None:
        self.select(gcmd, gcmd.rawparams)

    def cmd_M24(self, gcmd: GCodeCommand) -> None:
        if self.file is None:
            raise gcmd.error("No file selected (M23 <file> or SDCARD_PRINT_FILE FILENAME=<file>)")
        if not self.printing:
            self.start()

    def cmd_M25(self, gcmd: GCodeCommand) -> None:
        self.pause()

    def cmd_M26(self, gcmd: GCodeCommand) -> None:
        if self.printing:
            raise gcmd.error("SD busy: a file is printing")
        if self.file is None:
            raise gcmd.error("No file selected")
        position = gcmd.get_int("S", minval=0, maxval=self.file_size)
        self.file.seek(position)
        self.position = position

    def cmd_M27(self, gcmd: GCodeCommand) -> None:
        if self.file is None:
            gcmd.respond_raw("Not SD printing.")
        else:
            gcmd.respond_raw(f"SD printing byte {self.position}/{self.file_size}")

    def get_status(self, eventtime=None) -> dict:
        return {"file_path": self.file_path,
                "progress": self.position / self.file_size if self.file_size else 0.0,
                "is_active": self.printing, "file_position": self.position, "file_size": self.file_size}


COMMANDS = {
    "SDCARD_PRINT_FILE": "Print a file from the gcodes folder: FILENAME=<name>",
    "SDCARD_RESET_FILE": "Forget the selected file and the print's stats",
    "M20": "List the G-code files", "M21": "Initialise the card (nothing to do)",
    "M23": "Select a file: M23 <name>", "M24": "Start or resume the selected file",
    "M25": "Pause the file", "M26": "Set the file position: M26 S<byte>", "M27": "Report the print's byte position",
}


def load_config(section: ConfigSection, printer) -> VirtualSDCard:
    folder = section.get("path", printer.gcodes_dir if not section.config.has_section(SECTION) else None)
    if folder is None:
        raise section.error("path", "must be given: the folder the G-code files are printed from")
    on_error = compile_template(section, "on_error_gcode", "virtual_sdcard on_error_gcode") \
        if section.has_option("on_error_gcode") else None
    sdcard = VirtualSDCard(printer, folder, on_error)
    for name, desc in COMMANDS.items():
        printer.gcode.register_command(name, getattr(sdcard, f"cmd_{name}"), desc=desc)
    printer.register_background(sdcard.feed)
    printer.register_event_handler("pause_resume:pause", sdcard.pause)
    printer.register_event_handler("pause_resume:resume", sdcard.resume)
    printer.register_event_handler("pause_resume:cancel", sdcard.cancel)
    printer.register_event_handler("printer:shutdown", sdcard.stop_on_shutdown)
    return sdcard
