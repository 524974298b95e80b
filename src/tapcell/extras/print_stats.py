"""`print_stats`: the state and times of the print job (Klipper's object, made by [virtual_sdcard]).

Fields as Klipper has them: `state` (standby, printing, paused, complete, cancelled, error),
`filename`, `total_duration` (since the start), `print_duration` (without pauses and without the
time before the first extrusion), `filament_used` (mm of E, net of retractions, before the
extrude factor), `message` (why it stopped with an error) and `info` (`total_layer`,
`current_layer`, set by SET_PRINT_STATS_INFO, which slicers call on each layer change).
Moonraker's job history and both UIs' progress come from here. Times are the estimated print
time (`Printer.estimated_print_time`), so behind `tapcell serve` they follow the moves as they play.
"""

from __future__ import annotations

from tapcell.host.gcode import GCodeCommand

NO_EXTRUSION_MM = 1e-7  # filament below this: the print has not extruded yet
MAX_LAYERS = 1_000_000


class PrintStats:
    def __init__(self, printer):
        self.printer = printer
        self.reset()

    def reset(self) -> None:
        self.filename = ""
        self.state = "standby"
        self.message = ""
        self.filament_used_mm = 0.0
        self.total_layer: int | None = None
        self.current_layer: int | None = None
        self._start_s: float | None = None
        self._paused_since_s: float | None = None
        self._paused_s = 0.0
        self._before_extrusion_s = 0.0
        self._last_e_mm = 0.0
        self._end_s: float | None = None

    # -- the job's life -------------------------------------------------------------------
    def note_start(self, filename: str) -> None:
        """A new print (or a resume of a paused one: then only the pause ends)."""
        now_s = self._now()
        if self.state == "paused" and self._paused_since_s is not None:
            self._paused_s += now_s - self._paused_since_s
            self._paused_since_s = None
        else:
            self.reset()
            self.filename = filename
            self._start_s = now_s
            self._last_e_mm = self._gcode_e_mm()
        self.state = "printing"

    def note_pause(self) -> None:
        if self.state == "printing":
            self._count_filament()
            self._paused_since_s = self._now()
            self.state = "paused"

    def note_complete(self) -> None:
        self._finish("complete")

    def note_cancel(self) -> None:
        self._finish("cancelled")

    def note_error(self, message: str) -> None:
        self._finish("error", message)

    def _finish(self, state: str, message: str = "") -> None:
        if self.state not in ("printing", "paused"):
            return
        now_s = self._now()
        if self._paused_since_s is not None:
            self._paused_s += now_s - self._paused_since_s
            self._paused_since_s = None
        else:
            self._count_filament()
        self._end_s = now_s
        self.state, self.message = state, message

    # -- measuring ------------------------------------------------------------------------
    def _now(self) -> float:
        return self.printer.estimated_print_time()

    def _gcode_e_mm(self) -> float:
        gcode_move = self.printer.lookup_object("gcode_move", None)
        if gcode_move is None:
            return 0.0
        status = gcode_move.get_status()
        return float(status["position"][3]) / float(status["extrude_factor"])

    def _count_filament(self) -> None:
        e_mm = self._gcode_e_mm()
        had_extruded = abs(self.filament_used_mm) >= NO_EXTRUSION_MM
        self.filament_used_mm += e_mm - self._last_e_mm
        self._last_e_mm = e_mm
        if not had_extruded and self._start_s is not None:
            # Until the first extrusion the print is warming up, homing, levelling: not printing.
            self._before_extrusion_s = self._now() - self._start_s - self._paused_s

    def update(self) -> None:
        """After each line of the file: count the filament (and the time before the first extrusion)."""
        if self.state == "printing":
            self._count_filament()

    def durations_s(self) -> tuple[float, float]:
        """(total_duration, print_duration) now."""
        if self._start_s is None:
            return 0.0, 0.0
        now_s = self._end_s if self._end_s is not None else self._now()
        paused_s = self._paused_s + (now_s - self._paused_since_s if self._paused_since_s is not None else 0.0)
        total_s = max(0.0, now_s - self._start_s)
        return total_s, max(0.0, total_s - self._before_extrusion_s - paused_s)

    # -- command and status ---------------------------------------------------------------
    def cmd_SET_PRINT_STATS_INFO(self, gcmd: GCodeCommand) -> None:
        total = gcmd.get_int("TOTAL_LAYER", None, minval=0, maxval=MAX_LAYERS)
        current = gcmd.get_int("CURRENT_LAYER", None, minval=0, maxval=MAX_LAYERS)
        if total == 0:  # as in Klipper: 0 clears both
            self.total_layer = self.current_layer = None
        elif total is not None and total != self.total_layer:
            self.total_layer, self.current_layer = total, 0
        if self.total_layer is not None and current is not None and current != self.current_layer:
            self.current_layer = min(current, self.total_layer)

    def get_status(self, eventtime=None) -> dict:
        self.update()
        total_s, print_s = self.durations_s()
        return {"filename": self.filename, "total_duration": total_s, "print_duration": print_s,
                "filament_used": self.filament_used_mm, "state": self.state, "message": self.message,
                "info": {"total_layer": self.total_layer, "current_layer": self.current_layer}}


def attach(printer) -> PrintStats:
    """The printer's print_stats, made with its command on first use."""
    stats = printer.lookup_object("print_stats", None)
    if stats is None:
        stats = PrintStats(printer)
        printer.add_object("print_stats", stats)
        printer.gcode.register_command("SET_PRINT_STATS_INFO", stats.cmd_SET_PRINT_STATS_INFO,
                                       desc="Set the print's layer count and layer: [TOTAL_LAYER=] [CURRENT_LAYER=]")
    return stats
