"""A one-line progress bar for `tapcell run` on a terminal (stderr), and the closing summary.

The bar is redrawn in place with a carriage return; before a response line is printed the
bar is wiped, so responses (on stdout) are never mixed into it. Off a terminal nothing is
drawn but the summary.
"""

from __future__ import annotations

import sys
import time

BAR_WIDTH = 30
REDRAW_EVERY_S = 0.1


def format_duration(seconds: float) -> str:
    minutes, seconds = divmod(int(round(seconds)), 60)
    hours, minutes = divmod(minutes, 60)
    return f"{hours}:{minutes:02d}:{seconds:02d}"


class InPlaceLine:
    """One line on a terminal stream, redrawn in place (carriage return, erase to the end) and
    wiped before other output goes to the same terminal."""

    def __init__(self, stream):
        self.stream = stream
        self.drawn = False

    def show(self, text: str) -> None:
        self.stream.write(f"\r\033[K{text}")
        self.stream.flush()
        self.drawn = True

    def wipe(self) -> bool:
        """Erase the line if it is drawn; True if it was."""
        if not self.drawn:
            return False
        self.stream.write("\r\033[K")
        self.stream.flush()
        self.drawn = False
        return True


class ProgressBar:
    def __init__(self, total_lines: int, stream=None, enabled: bool | None = None, clock=time.monotonic):
        self.total = max(total_lines, 1)
        self.stream = sys.stderr if stream is None else stream
        self.enabled = self.stream.isatty() if enabled is None else enabled
        self.clock = clock
        self.started_s = clock()
        self._last_draw_s = -float("inf")
        self._line = InPlaceLine(self.stream)

    def update(self, done_lines: int, printer_time_s: float) -> None:
        now = self.clock()
        if not self.enabled or (now - self._last_draw_s < REDRAW_EVERY_S and done_lines < self.total):
            return
        self._last_draw_s = now
        share = min(done_lines / self.total, 1.0)
        filled = int(round(share * BAR_WIDTH))
        self._line.show(f"[{'#' * filled}{'.' * (BAR_WIDTH - filled)}] {share:4.0%} line {done_lines}/"
                        f"{self.total}, printer time {format_duration(printer_time_s)}")

    def clear(self) -> None:
        """Wipe the bar (before a response line goes to the same terminal)."""
        if self._line.wipe():
            self._last_draw_s = -float("inf")

    def summary(self, lines: int, printer_time_s: float) -> str:
        wall_s = self.clock() - self.started_s
        return (f"tapcell run: {lines} lines, {format_duration(printer_time_s)} of printer time "
                f"in {wall_s:.1f} s")
