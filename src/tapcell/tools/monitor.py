"""`tapcell monitor`: analyse a printer's taps live, next to the printer's own result.

Connects to Moonraker's `/klippysocket` bridge (a raw Klipper API connection over a
websocket), so it works with any Klipper-family host: Klipper, Kalico or `tapcell serve`.
It reads the printer's `[load_cell_probe]` settings (configfile), subscribes to
`load_cell_probe/dump_taps` (and `load_cell/dump_force` with --force), and for every tap shows
a row: where, the printer's Z, tapcell's Z, the difference, validity, quality and the cause.
`--log` appends one tapcell.tap.v1 line per tap with both results (`analysis`: tapcell's,
`printer`: the printer's), `--plot-dir` writes a PNG per tap, `--count N` stops after N taps.
When Moonraker or the printer restarts the connection drops; the monitor says so and
reconnects.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from tapcell.tap import AnalysisOptions, TapFileError, analyze_tap, tap_to_json_dict
from tapcell.tap.cli import options_from_settings
from tapcell.tap.readers import tap_from_object

RECONNECT_S = 1.0
RECV_POLL_S = 1.0
FORCE_REPORT_S = 2.0
TABLE_ROWS = 20
# [load_cell_probe] options of Klipper-family configs -> the analysis options they set.
SETTINGS_TO_OPTIONS = {
    "trigger_force": "trigger_force_g",
    "min_tap_quality": "min_tap_quality",
    "decompression_angle": "decompression_angle",
    "max_approach_force": "max_approach_force",
    "max_departure_force": "max_departure_force",
    "max_baseline_force_delta": "max_baseline_force_delta",
    "max_dwell_force_drop": "max_dwell_force_drop",
}
COLUMNS = ("#", "X", "Y", "printer Z", "tapcell Z", "diff um", "valid (printer/tapcell)", "quality", "cause")


class ApiError(Exception):
    """The printer refused a request (a wrong probe name, an unknown endpoint)."""


@dataclass
class TapRow:
    """One tap as the table shows it (both results side by side)."""

    number: int
    x_mm: float | None
    y_mm: float | None
    printer_z_mm: float | None
    tapcell_z_mm: float | None
    printer_valid: bool | None
    tapcell_valid: bool
    quality: float | None
    cause: str

    @property
    def difference_um(self) -> float | None:
        if self.printer_z_mm is None or self.tapcell_z_mm is None:
            return None
        return (self.tapcell_z_mm - self.printer_z_mm) * 1000.0

    def cells(self) -> list[str]:
        def number(value, spec):
            return "-" if value is None else format(value, spec)

        def validity(value):
            return "-" if value is None else ("valid" if value else "bad")

        return [str(self.number), number(self.x_mm, ".2f"), number(self.y_mm, ".2f"),
                number(self.printer_z_mm, ".4f"), number(self.tapcell_z_mm, ".4f"),
                number(self.difference_um, "+.1f"),
                f"{validity(self.printer_valid)}/{validity(self.tapcell_valid)}",
                number(self.quality, ".1f"), self.cause]


def analysis_options(settings: dict[str, Any], overrides: list[str]) -> AnalysisOptions:
    """The printer's [load_cell_probe] settings as analysis options; `--set` items win."""
    from_printer = [f"{SETTINGS_TO_OPTIONS[key]}={value}" for key, value in settings.items()
                    if key in SETTINGS_TO_OPTIONS and isinstance(value, int | float) and not isinstance(value, bool)]
    return options_from_settings(from_printer + list(overrides))


def analyse_event(number: int, event: dict, options: AnalysisOptions):
    """(row, tap, analysis) for one dump_taps push; raises TapFileError for an unreadable tap."""
    printed = event.get("tap", event)
    tap = tap_from_object(event, "<dump_taps>")
    analysis = analyze_tap(tap, options)
    position = printed.get("tap_pos")
    error = printed.get("error")
    printer_valid = printed.get("is_valid")
    causes = []
    if printer_valid is False and isinstance(error, dict):
        causes.append(f"printer: {error.get('error_code')} - {error.get('message')}")
    if not analysis.valid:
        causes.append(f"tapcell: {analysis.error} - {analysis.message}")
    x_mm, y_mm = (position[0], position[1]) if position else (tap.probe.get("x"), tap.probe.get("y"))
    row = TapRow(number, x_mm, y_mm, None if not position else float(position[2]), analysis.z_mm,
                 printer_valid, bool(analysis.valid), analysis.quality, "; ".join(causes))
    return row, tap, analysis


def log_line(tap, analysis, event: dict, source: str) -> str:
    """One tapcell.tap.v1 line with tapcell's result (`analysis`) and the printer's (`printer`)."""
    printed = event.get("tap", event)
    document = tap_to_json_dict(tap, analysis)
    position = printed.get("tap_pos")
    document["printer"] = {"z": None if not position else position[2], "tap_pos": position,
                           "is_valid": printed.get("is_valid"), "error": printed.get("error")}
    document.setdefault("meta", {})["monitor_source"] = source
    return json.dumps(document, allow_nan=False)


class Bridge:
    """A Klipper API connection through Moonraker's /klippysocket websocket."""

    def __init__(self, websocket):
        self.websocket = websocket
        self._next_id = 1
        self.pending_pushes: list[dict] = []

    def request(self, method: str, params: dict, timeout_s: float = 30.0) -> Any:
        request_id = self._next_id
        self._next_id += 1
        self.websocket.send(json.dumps({"id": request_id, "method": method, "params": params}))
        deadline = time.monotonic() + timeout_s
        while True:
            message = json.loads(self.websocket.recv(timeout=max(deadline - time.monotonic(), 0.001)))
            if message.get("id") != request_id:
                self.pending_pushes.append(message)
                continue
            if "error" in message:
                error = message["error"]
                raise ApiError(error.get("message", str(error)) if isinstance(error, dict) else str(error))
            return message.get("result")

    def next_push(self, timeout_s: float) -> dict | None:
        if self.pending_pushes:
            return self.pending_pushes.pop(0)
        try:
            return json.loads(self.websocket.recv(timeout=timeout_s))
        except TimeoutError:
            return None


def bridge_url(moonraker_url: str) -> str:
    """http://host:7125 -> ws://host:7125/klippysocket (https -> wss)."""
    url = moonraker_url.rstrip("/")
    for plain, secure in (("http://", "ws://"), ("https://", "wss://")):
        if url.startswith(plain):
            url = secure + url[len(plain):]
    if not url.startswith(("ws://", "wss://")):
        url = "ws://" + url
    return url if url.endswith("/klippysocket") else url + "/klippysocket"


class Display:
    """The live table on a terminal (rich), else one plain line per tap."""

    def __init__(self, stream=sys.stdout):
        self.stream = stream
        self.rows: list[TapRow] = []
        self.live = None
        if stream.isatty():
            from rich.live import Live

            self.live = Live(self._table(), auto_refresh=False)
            self.live.start()
        else:
            print("\t".join(COLUMNS), file=stream, flush=True)

    def _table(self):
        from rich.table import Table

        table = Table(title="tapcell monitor: the printer's Z and tapcell's, per tap")
        for column in COLUMNS:
            table.add_column(column)
        for row in self.rows[-TABLE_ROWS:]:
            table.add_row(*row.cells())
        return table

    def add(self, row: TapRow) -> None:
        self.rows.append(row)
        if self.live is not None:
            self.live.update(self._table(), refresh=True)
        else:
            print("\t".join(row.cells()), file=self.stream, flush=True)

    def say(self, message: str) -> None:
        if self.live is not None:
            self.live.console.print(message)
        else:
            print(message, file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.live is not None:
            self.live.stop()


def monitor(args, display: Display, connect: Callable) -> int:
    """Connect, subscribe, analyse taps until --count is reached; reconnect when the link drops."""
    url = bridge_url(args.moonraker)
    seen = TapCount()  # survives reconnections
    while True:
        try:
            with connect(url, open_timeout=10, close_timeout=2) as websocket:
                bridge = Bridge(websocket)
                status = bridge.request("objects/query", {"objects": {"configfile": ["settings"]}})
                settings = status["status"].get("configfile", {}).get("settings", {}).get(args.probe, {})
                options = analysis_options(settings, args.set)
                bridge.request("load_cell_probe/dump_taps", {"load_cell_probe": args.probe, "response_template": {}})
                if args.force:
                    bridge.request("load_cell/dump_force", {"load_cell": args.probe.split()[-1],
                                                            "response_template": {}})
                display.say(f"tapcell monitor: connected to {url}, waiting for taps of [{args.probe}]")
                _follow(bridge, args, options, display, seen)
                return 0
        except ApiError as exc:
            display.say(f"tapcell monitor: the printer refused: {exc}")
            return 2
        except (OSError, TimeoutError, EOFError, _websocket_errors()) as exc:
            display.say(f"tapcell monitor: connection to {url} lost or refused ({type(exc).__name__}: {exc}); "
                        f"reconnecting in {RECONNECT_S:g} s")
        time.sleep(RECONNECT_S)


@dataclass
class TapCount:
    taps: int = 0


def _follow(bridge: Bridge, args, options: AnalysisOptions, display: Display, seen: TapCount) -> None:
    """Handle pushes until --count taps were seen (or forever); a dropped link raises."""
    force_g: list[float] = []
    last_report = time.monotonic()
    while not (args.count and seen.taps >= args.count):
        push = bridge.next_push(RECV_POLL_S)
        params = (push or {}).get("params", {})
        if "tap" in params:
            seen.taps += 1
            _handle_tap(seen.taps, params, options, args, display)
        elif "data" in params and args.force:   # kept only to be reported, then emptied
            force_g += [row[1] for row in params["data"] if row[1] is not None]
        if args.force and time.monotonic() - last_report >= FORCE_REPORT_S and force_g:
            display.say(f"force: {force_g[-1]:.1f} g (min {min(force_g):.1f}, max {max(force_g):.1f} "
                        f"over {len(force_g)} samples)")
            force_g, last_report = [], time.monotonic()


def _handle_tap(number: int, event: dict, options: AnalysisOptions, args, display: Display) -> None:
    try:
        row, tap, analysis = analyse_event(number, event, options)
    except TapFileError as exc:
        display.say(f"tap {number}: not analysable: {exc.problem}")
        return
    display.add(row)
    if getattr(args, "record_tap", None):  # --db: tools/history.py keeps it in the store
        args.record_tap(tap, analysis, event)
    if args.log:
        with open(args.log, "a", encoding="utf-8") as log:
            log.write(log_line(tap, analysis, event, args.moonraker) + "\n")
    if args.plot_dir:
        from tapcell.tap.plot import plot_tap

        Path(args.plot_dir).mkdir(parents=True, exist_ok=True)
        plot_tap(tap, analysis, Path(args.plot_dir) / f"tap-{number:04d}.png",
                 title=f"tap {number}: printer Z {row.cells()[3]}, tapcell Z {row.cells()[4]}")


def _websocket_errors():
    from websockets.exceptions import WebSocketException

    return WebSocketException


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="tapcell monitor", description="Analyse a printer's taps live "
                                     "through Moonraker, next to the printer's own result.")
    parser.add_argument("--moonraker", required=True, action="append", metavar="[NAME=]URL",
                        help="Moonraker, e.g. http://printer.local:7125; repeat it, named, for many printers "
                        "(voron=http://voron.local:7125)")
    parser.add_argument("--db", metavar="URL", help="keep every tap and mesh in a store: a path, sqlite:///PATH "
                        "or postgresql://... (see tapcell web)")
    parser.add_argument("--probe", default="load_cell_probe", help="the probe's section (default: %(default)s)")
    parser.add_argument("--log", metavar="TAPS.jsonl", help="append each tap with both results (tapcell.tap.v1)")
    parser.add_argument("--plot-dir", metavar="DIR", help="write a PNG per tap")
    parser.add_argument("--count", type=int, default=0, metavar="N", help="stop after N taps (default: run on)")
    parser.add_argument("--force", action="store_true", help="also stream the load cell's force")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="analysis option over the printer's settings, e.g. sensor_delay_s=0.002")
    args = parser.parse_args(argv)
    if args.count < 0:
        parser.error("--count must be 0 (run on) or more")
    try:
        options_from_settings(args.set)
    except ValueError as exc:
        parser.error(str(exc))
    from websockets.sync.client import connect

    display = Display()
    try:
        if args.db or len(args.moonraker) > 1:
            from tapcell.tools.history import MonitorParts, monitor_printers

            return monitor_printers(args, display, connect, MonitorParts(monitor, log_line, Bridge, bridge_url, ApiError))
        args.moonraker = args.moonraker[0]
        return monitor(args, display, connect)
    except KeyboardInterrupt:
        return 130
    finally:
        display.close()
