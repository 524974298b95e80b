"""Klipper's two clocks for a printer served live: print time and estimated print time.

The virtual printer runs every move to its end at once: after `G1 X200` its clock (`now_s`,
Klipper's *print time*, where the queued moves end) is already past the move. A real printer
is still moving, and UIs show that through `motion_report` and `idle_timeout`, which Klipper
computes at the *estimated print time*: what the machine is doing now. `PrintClock` keeps that
second clock for `tapcell serve`, advanced by the wall clock:

* while the estimated time is behind the print time, the queued moves are playing: it catches
  up at wall speed and the virtual printer is not advanced (nothing new is queued);
* once caught up, both advance together with the wall clock (the printer idles in real time).

The estimated time never trails by more than MAX_LAG_S (a long mesh or a dwell then shows only
its last seconds as motion), so the load-cell streams and temperatures pause at most that long.
Without a live loop (`tapcell run`, the console, the tests of the printer itself) there is no
PrintClock and the estimated time is the print time.
"""

from __future__ import annotations

MAX_LAG_S = 5.0
# Klipper's lookahead: the queued moves may run this far ahead of the machine before the next
# line of a file (virtual_sdcard) or the next client script (`tapcell serve`) is taken.
FEED_AHEAD_S = 1.0
BUSY_LEAD_S = 1e-6  # queued moves this far ahead of the machine: it is still moving


class PrintClock:
    def __init__(self, backend, max_lag_s: float = MAX_LAG_S):
        self.backend = backend
        self.max_lag_s = max_lag_s
        self.estimated_s = float(backend.now_s)
        # The current stretch of queued moves: when the machine started on it (None: idle), and
        # the print time at which the last stretch ends (None: nothing ran yet).
        self.busy_since_s: float | None = None
        self.last_busy_end_s: float | None = None

    def lead_s(self) -> float:
        """How far the queued moves run ahead of the machine (0 when it is idle)."""
        return max(0.0, float(self.backend.now_s) - self.estimated_s)

    def is_busy(self) -> bool:
        return self.lead_s() > BUSY_LEAD_S

    def advance(self, wall_elapsed_s: float) -> None:
        """Let `wall_elapsed_s` of real time pass; idle the virtual printer for the part of it not
        covered by moves already queued."""
        now_s = float(self.backend.now_s)
        if self.is_busy():
            if self.busy_since_s is None:
                self.busy_since_s = self.estimated_s
            self.last_busy_end_s = now_s
        self.estimated_s = max(self.estimated_s + wall_elapsed_s, now_s - self.max_lag_s)
        if self.estimated_s >= now_s:
            self.busy_since_s = None
        if self.estimated_s > now_s:
            self.backend.dwell(self.estimated_s - now_s)
