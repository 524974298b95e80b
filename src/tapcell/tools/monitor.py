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

Everything the server sends is checked before use (a server is not trusted to be Moonraker):
a message that is not what the protocol says is skipped with a one-line warning, a tap too
big to analyse likewise; a reply to the handshake that makes no sense, a host name that does
not resolve after NAME_RETRIES tries, or a --log / --plot-dir that cannot be written end the
monitor with a message and exit status 2.
"""

from __future__ import annotations

import argparse
import json
import math
import socket
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from tapcell.files import FileRefused, check_appendable, open_append
from tapcell.tap import AnalysisOptions, TapFileError, analyze_tap, tap_to_json_dict
from tapcell.tap.cli import options_from_settings
from tapcell.tap.model import CONFIG_OPTIONS
from tapcell.tap.readers import tap_from_object

RECONNECT_S = 1.0
RECV_POLL_S = 1.0
FORCE_REPORT_S = 2.0
TABLE_ROWS = 20
# The largest message taken from the server: `tapcell serve` drops a client with 64 MiB unsent,
# and a 20 s tap at 2000 sps is ~1.5 MB. Larger is refused by the websocket (the link is reopened).
MAX_MESSAGE_BYTES = 64 * 1024 * 1024
# A tap with more samples is skipped with a warning: 10 s at 2000 sps (a real tap is under 5 s). The
# analysis's time and memory grow faster than the samples: 20,000 took 10 s and 360 MB, 40,000 24 s and 1.1 GB.
MAX_TAP_SAMPLES = 20_000
NAME_RETRIES = 3  # tries before a host name that does not resolve is reported as a mistake
OVERSIZE_RETRIES = 3  # links lost in a row to a message over MAX_MESSAGE_BYTES before giving up
# [load_cell_probe] options of Klipper-family configs -> the analysis options they set: the printer's
# trigger force and the analysis options the config takes (under the analysis's own names).
SETTINGS_TO_OPTIONS = {"trigger_force": "trigger_force_g", **{name: name for name in CONFIG_OPTIONS}}
COLUMNS = ("#", "X", "Y", "printer Z", "tapcell Z", "diff um", "valid (printer/tapcell)", "quality", "cause")


class ApiError(Exception):
    """The printer refused a request (a wrong probe name, an unknown endpoint)."""


class ProtocolError(Exception):
    """A message from the server is not what Klipper's API sends (the message says what it is)."""


class LocalError(Exception):
    """Writing the log or a plot failed here (a full disk): the monitor's own problem, not the link's."""


def decode_message(text: str | bytes) -> dict:
    """One message from the server as a JSON object; ProtocolError says what else it is."""
    try:
        message = json.loads(text)
    except (ValueError, RecursionError) as exc:  # RecursionError: nesting deeper than Python's limit
        raise ProtocolError(f"a message that is not JSON ({type(exc).__name__}: {str(exc)[:80]})") from None
    if not isinstance(message, dict):
        raise ProtocolError(f"a message that is a JSON {type(message).__name__}, not an object")
    return message


def _object(value: Any, what: str) -> dict:
    if not isinstance(value, dict):
        raise ProtocolError(f"{what} is {type(value).__name__}, not an object")
    return value


def _finite_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def printer_result(printed: dict) -> tuple[list[float] | None, bool | None, dict | None, list[str]]:
    """The printer's own result from a dump_taps tap: (tap_pos, is_valid, error), each None when
    absent or malformed, and one warning per malformed field."""
    warnings = []
    position = printed.get("tap_pos")
    if position is not None and not (isinstance(position, list) and len(position) >= 3
                                     and all(_finite_number(v) for v in position[:3])):
        warnings.append(f"tap_pos {str(position)[:60]} is not [x, y, z] in numbers: ignored")
        position = None
    is_valid = printed.get("is_valid")
    if is_valid is not None and not isinstance(is_valid, bool):
        warnings.append(f"is_valid {str(is_valid)[:30]!r} is not true/false: ignored")
        is_valid = None
    error = printed.get("error")
    if error is not None and not isinstance(error, dict):
        warnings.append(f"error {str(error)[:30]!r} is not an object: ignored")
        error = None
    return (None if position is None else [float(v) for v in position[:3]]), is_valid, error, warnings


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


def analysis_options(settings: dict[str, Any], overrides: list[str], warn: Callable[[str], None] = print
                     ) -> AnalysisOptions:
    """The printer's [load_cell_probe] settings as analysis options; `--set` items win. A setting
    the analysis refuses (NaN, out of range) is left at its default with a warning."""
    taken = []
    for key, value in settings.items():
        if key not in SETTINGS_TO_OPTIONS or isinstance(value, bool) or not isinstance(value, int | float):
            continue
        item = f"{SETTINGS_TO_OPTIONS[key]}={value}"
        try:
            options_from_settings([item])
        except ValueError as exc:
            warn(f"tapcell monitor: the printer's {key} = {value} is not usable ({exc}): the default is used")
            continue
        taken.append(item)
    return options_from_settings(taken + list(overrides))


def analyse_event(number: int, event: dict, options: AnalysisOptions):
    """(row, tap, analysis, warnings) for one dump_taps push; TapFileError for a tap that cannot be
    analysed (malformed or over MAX_TAP_SAMPLES)."""
    printed = event.get("tap", event)
    if not isinstance(printed, dict):
        raise TapFileError("<dump_taps>", f"'tap' is {type(printed).__name__}, not an object")
    samples = printed.get("time")
    if isinstance(samples, list) and len(samples) > MAX_TAP_SAMPLES:
        raise TapFileError("<dump_taps>", f"{len(samples):,} samples, more than {MAX_TAP_SAMPLES:,} "
                                          f"(10 s at 2000 sps): not analysed")
    tap = tap_from_object(event, "<dump_taps>")
    analysis = analyze_tap(tap, options)
    position, printer_valid, error, warnings = printer_result(printed)
    causes = []
    if printer_valid is False and error is not None:
        causes.append(f"printer: {error.get('error_code')} - {error.get('message')}")
    if not analysis.valid:
        causes.append(f"tapcell: {analysis.error} - {analysis.message}")
    x_mm, y_mm = (position[0], position[1]) if position else (tap.probe.get("x"), tap.probe.get("y"))
    row = TapRow(number, x_mm, y_mm, None if not position else position[2], analysis.z_mm,
                 printer_valid, bool(analysis.valid), analysis.quality, "; ".join(causes))
    return row, tap, analysis, warnings


def log_line(tap, analysis, event: dict, source: str) -> str:
    """One tapcell.tap.v1 line with tapcell's result (`analysis`) and the printer's (`printer`)."""
    position, is_valid, error, _ = printer_result(event.get("tap", event))
    document = tap_to_json_dict(tap, analysis)
    document["printer"] = {"z": None if not position else position[2], "tap_pos": position,
                           "is_valid": is_valid, "error": error}
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
            try:
                message = decode_message(self.websocket.recv(timeout=max(deadline - time.monotonic(), 0.001)))
            except ProtocolError as exc:
                raise ProtocolError(f"the reply to {method} is {str(exc).removeprefix('a message that is ')}") from None
            if message.get("id") != request_id:
                self.pending_pushes.append(message)
                continue
            if "error" in message:
                error = message["error"]
                raise ApiError(error.get("message", str(error)) if isinstance(error, dict) else str(error))
            return message.get("result")

    def next_push(self, timeout_s: float) -> dict | None:
        """The next push (None after timeout_s); ProtocolError for a message that is not one."""
        if self.pending_pushes:
            return self.pending_pushes.pop(0)
        try:
            return decode_message(self.websocket.recv(timeout=timeout_s))
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
    failures = {"name": 0, "oversize": 0}  # in a row, by kind
    while True:
        try:
            with connect(url, open_timeout=10, close_timeout=2, max_size=MAX_MESSAGE_BYTES) as websocket:
                failures["name"] = 0
                bridge = Bridge(websocket)
                options = _handshake(bridge, args, display)
                display.say(f"tapcell monitor: connected to {url}, waiting for taps of [{args.probe}]")
                _follow(bridge, args, options, display, seen)
                return 0
        except ApiError as exc:
            display.say(f"tapcell monitor: the printer refused: {exc}")
            return 2
        except ProtocolError as exc:
            display.say(f"tapcell monitor: {url} does not answer as Klipper's API through Moonraker does: {exc}")
            return 2
        except LocalError as exc:
            display.say(f"tapcell monitor: {exc}")
            return 2
        except socket.gaierror as exc:
            if _gives_up(failures, "name", NAME_RETRIES, f"the host of {url} does not resolve ({exc.strerror})",
                         "check the name in --moonraker", display):
                return 2
        except (OSError, TimeoutError, EOFError, _websocket_errors()) as exc:
            if _message_too_big(exc):
                if _gives_up(failures, "oversize", OVERSIZE_RETRIES, f"the server sent a message over "
                             f"{MAX_MESSAGE_BYTES:,} bytes (the limit)", "giving up", display):
                    return 2
            else:
                failures["oversize"] = 0
                display.say(f"tapcell monitor: connection to {url} lost or refused ({type(exc).__name__}: "
                            f"{exc}); reconnecting in {RECONNECT_S:g} s")
        time.sleep(RECONNECT_S)


def _gives_up(failures: dict[str, int], kind: str, limit: int, problem: str, last_words: str, display) -> bool:
    """Count one more failure of `kind` in a row: say so, and whether it is the last try."""
    failures[kind] += 1
    if failures[kind] >= limit:
        display.say(f"tapcell monitor: {problem}, {limit} times in a row: {last_words}")
        return True
    display.say(f"tapcell monitor: {problem}; trying again in {RECONNECT_S:g} s")
    return False


def _handshake(bridge: Bridge, args, display: Display) -> AnalysisOptions:
    """The printer's probe settings (as analysis options), then the subscriptions."""
    result = _object(bridge.request("objects/query", {"objects": {"configfile": ["settings"]}}),
                     "the result of objects/query")
    status = _object(result.get("status"), "the status in the result of objects/query")
    settings = _object(status.get("configfile", {}), "configfile").get("settings", {})
    probe_settings = _object(settings, "configfile.settings").get(args.probe, {})
    if not isinstance(probe_settings, dict):
        display.say(f"tapcell monitor: the printer's settings of [{args.probe}] are not an object: "
                    f"the analysis uses its defaults")
        probe_settings = {}
    options = analysis_options(probe_settings, args.set, display.say)
    bridge.request("load_cell_probe/dump_taps", {"load_cell_probe": args.probe, "response_template": {}})
    if args.force:
        bridge.request("load_cell/dump_force", {"load_cell": args.probe.split()[-1], "response_template": {}})
    return options


def _message_too_big(exc: BaseException) -> bool:
    """Whether the link closed because a message was over max_size (websocket close code 1009)."""
    for side in ("rcvd", "sent"):
        frame = getattr(exc, side, None)
        if frame is not None and getattr(frame, "code", None) == 1009:
            return True
    return False


@dataclass
class TapCount:
    taps: int = 0


def _follow(bridge: Bridge, args, options: AnalysisOptions, display: Display, seen: TapCount) -> None:
    """Handle pushes until --count taps were seen (or forever); a dropped link raises."""
    force_g: list[float] = []
    last_report = time.monotonic()
    while not (args.count and seen.taps >= args.count):
        try:
            push = bridge.next_push(RECV_POLL_S)
        except ProtocolError as exc:
            display.say(f"tapcell monitor: skipped {exc}")
            continue
        params = (push or {}).get("params", {})
        if not isinstance(params, dict):
            display.say(f"tapcell monitor: skipped a push whose params are a {type(params).__name__}, not an object")
            continue
        if "tap" in params:
            seen.taps += 1
            _handle_tap(seen.taps, params, options, args, display)
        elif "data" in params and args.force:   # kept only to be reported, then emptied
            force_g += _forces(params["data"])
        if args.force and time.monotonic() - last_report >= FORCE_REPORT_S and force_g:
            display.say(f"force: {force_g[-1]:.1f} g (min {min(force_g):.1f}, max {max(force_g):.1f} "
                        f"over {len(force_g)} samples)")
            force_g, last_report = [], time.monotonic()


def _forces(rows: Any) -> list[float]:
    """The force column of dump_force rows ([time, force_g, ...]); malformed rows are left out."""
    if not isinstance(rows, list):
        return []
    return [row[1] for row in rows if isinstance(row, list) and len(row) > 1 and _finite_number(row[1])]


def _handle_tap(number: int, event: dict, options: AnalysisOptions, args, display: Display) -> None:
    try:
        row, tap, analysis, warnings = analyse_event(number, event, options)
    except TapFileError as exc:
        display.say(f"tapcell monitor: tap {number} skipped: {exc.problem}")
        return
    for warning in warnings:
        display.say(f"tapcell monitor: tap {number}: the printer's {warning}")
    display.add(row)
    if getattr(args, "record_tap", None):  # --db: tools/history.py keeps it in the store
        args.record_tap(tap, analysis, event)
    try:
        if args.log:
            with open_append(args.log) as log:
                log.write(log_line(tap, analysis, event, args.moonraker) + "\n")
        if args.plot_dir:
            from tapcell.tap.plot import plot_tap

            Path(args.plot_dir).mkdir(parents=True, exist_ok=True)
            plot_tap(tap, analysis, Path(args.plot_dir) / f"tap-{number:04d}.png",
                     title=f"tap {number}: printer Z {row.cells()[3]}, tapcell Z {row.cells()[4]}")
    except (OSError, FileRefused) as exc:
        raise LocalError(f"cannot write tap {number} to --log {args.log} or --plot-dir {args.plot_dir}: {exc}") from None


def check_outputs(log: str | None, plot_dir: str | None) -> str | None:
    """Why --log or --plot-dir cannot be written (checked before connecting), or None."""
    if log:
        problem = check_appendable(log)
        if problem is not None:
            return f"--log {log} {problem}"
    if plot_dir:
        try:
            Path(plot_dir).mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            return f"--plot-dir {plot_dir} cannot be made a folder ({exc.strerror or exc})"
    return None


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
    problem = check_outputs(args.log, args.plot_dir)
    if problem is not None:
        print(f"tapcell monitor: {problem}", file=sys.stderr)
        return 2
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
