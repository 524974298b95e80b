"""Tap history from the command line: `tapcell monitor --db` for many printers, and
`tapcell import` for tap files and monitor logs.

The monitor's own loop (tools/monitor.py) follows one printer's taps; here each named printer
gets its own thread running that loop, so a printer that goes away is retried without holding
up the others. Each tap is written to the store as the monitor's log line (the tap with both
results). A second thread per printer polls its `bed_mesh` and probe settings over another
/klippysocket connection and keeps every new mesh.
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
import threading
import time
import urllib.parse
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

MESH_POLL_S = 1.0
RECONNECT_S = 1.0
MESH_FIELDS = ["profile_name", "mesh_min", "mesh_max", "probed_matrix"]


@dataclass(frozen=True)
class MonitorParts:
    """What tools/monitor.py lends (passed in, so that this module does not import it back)."""

    follow: Callable  # follow(args, display, connect) -> exit code: one printer's tap loop
    log_line: Callable  # log_line(tap, analysis, event, source) -> the tap with both results
    bridge: type  # Bridge(websocket): a Klipper API connection
    bridge_url: Callable  # Moonraker URL -> its /klippysocket
    api_error: type  # what Bridge.request raises when the printer refuses


@dataclass
class PrinterSpec:
    name: str
    url: str


def printer_specs(values: list[str]) -> list[PrinterSpec]:
    """`--moonraker` values, NAME=URL or URL (named by its host:port); names must differ."""
    specs = []
    for value in values:
        name, separator, url = value.partition("=")
        if not separator or "://" in name or not name.strip():
            url = value
            parsed = urllib.parse.urlsplit(url if "://" in url else "http://" + url)
            name = parsed.netloc or url
        specs.append(PrinterSpec(name.strip(), url.strip()))
    names = [spec.name for spec in specs]
    duplicates = sorted({name for name in names if names.count(name) > 1})
    if duplicates:
        raise ValueError(f"--moonraker: printer name {duplicates[0]!r} is given twice; name them NAME=URL")
    for spec in specs:
        if len(spec.name) > 100:
            raise ValueError(f"--moonraker: printer name {spec.name[:20]!r}...: at most 100 characters")
    return specs


class LockedDisplay:
    """The monitor's display shared by the printers' threads; each message says which printer."""

    def __init__(self, display):
        self.display = display
        self.lock = threading.Lock()

    def add(self, row) -> None:
        with self.lock:
            self.display.add(row)

    def say(self, message: str) -> None:
        with self.lock:
            self.display.say(message)


class PrinterDisplay:
    def __init__(self, shared: LockedDisplay, name: str):
        self.shared, self.name = shared, name

    def add(self, row) -> None:
        row.cause = f"[{self.name}] {row.cause}".rstrip()
        self.shared.add(row)

    def say(self, message: str) -> None:
        self.shared.say(f"[{self.name}] {message}")


@dataclass
class PrinterState:
    """What the mesh thread learned that the tap writer stores with each tap."""

    settings: dict | None = None
    stop: threading.Event = field(default_factory=threading.Event)


def tap_recorder(store, spec: PrinterSpec, state: PrinterState, display, parts: MonitorParts):
    """The monitor's per-tap hook: the tap with both results, into the store."""
    from sqlalchemy.exc import SQLAlchemyError

    from tapcell.store import StoreError

    def record(tap, analysis, event) -> None:
        document = json.loads(parts.log_line(tap, analysis, event, spec.url))
        document["meta"]["recorded_s"] = time.time()
        try:
            added = store.add_tap(spec.name, document, settings=state.settings, printer_url=spec.url)
        except (StoreError, SQLAlchemyError) as exc:
            display.say(f"store: this tap was not kept: {type(exc).__name__}: {str(exc).splitlines()[0]}")
            return
        if not added.new:
            display.say(f"store: tap already kept (id {added.id}): another monitor watches this printer")

    return record


def watch_meshes(store, spec: PrinterSpec, probe: str, state: PrinterState, display, connect,
                 parts: MonitorParts) -> None:
    """Poll the printer's loaded mesh and probe settings; keep each new mesh. Reconnects.

    A mesh is written only when it differs from the last one seen, so an idle farm polls its
    printers, not its database."""
    from sqlalchemy.exc import SQLAlchemyError
    from websockets.exceptions import WebSocketException

    from tapcell.store import RecordError, StoreError
    from tapcell.store.records import mesh_record

    link_errors = (OSError, TimeoutError, EOFError, WebSocketException)
    url = parts.bridge_url(spec.url)
    last_key = last_problem = None
    while not state.stop.is_set():
        try:
            with connect(url, open_timeout=10, close_timeout=2) as websocket:
                bridge = parts.bridge(websocket)
                status = bridge.request("objects/query", {"objects": {"configfile": ["settings"]}})
                settings = status["status"].get("configfile", {}).get("settings", {}).get(probe)
                state.settings = settings if isinstance(settings, dict) else None
                while not state.stop.is_set():
                    status = bridge.request("objects/query", {"objects": {"bed_mesh": MESH_FIELDS}})
                    bridge.pending_pushes.clear()  # this connection subscribes to nothing
                    mesh = status["status"].get("bed_mesh")
                    try:
                        record = mesh_record(mesh, time.time()) if isinstance(mesh, dict) else None
                    except RecordError as exc:  # said once, not every poll
                        if str(exc) != last_problem:
                            display.say(f"bed mesh not kept: {exc}")
                        last_problem, record = str(exc), None
                    if record is not None and record.mesh_key != last_key:
                        store.add_mesh_record(spec.name, record, printer_url=spec.url)
                        last_key = record.mesh_key
                    state.stop.wait(MESH_POLL_S)
        except link_errors:
            pass  # the printer is away: the tap loop says so; try again
        except (parts.api_error, StoreError, SQLAlchemyError, KeyError, TypeError, AttributeError) as exc:
            display.say(f"bed mesh not kept: {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}")
        state.stop.wait(RECONNECT_S)


def _follow_one(parts: MonitorParts, args, display, connect, codes: list[int]) -> None:
    """One printer's tap loop; an error it did not expect ends this printer only, and says so."""
    try:
        codes.append(parts.follow(args, display, connect))
    except Exception as exc:  # the other printers go on; the exit code tells
        display.say(f"tapcell monitor: stopped following this printer: {type(exc).__name__}: {exc}")
        codes.append(1)


def monitor_printers(args, display, connect, parts: MonitorParts) -> int:
    """Run the monitor's loop for each printer, in threads, recording taps (and meshes) into
    args.db when given. Returns the worst exit code."""
    from tapcell.store import Store, StoreError

    try:
        specs = printer_specs(args.moonraker)
        store = Store(args.db) if args.db else None
    except (ValueError, StoreError) as exc:
        display.say(f"tapcell monitor: {exc}")
        return 2
    shared = LockedDisplay(display)
    codes: list[int] = []
    threads = []
    states = []
    for spec in specs:
        printer_display = PrinterDisplay(shared, spec.name) if len(specs) > 1 else shared
        state = PrinterState()
        states.append(state)
        printer_args = copy.copy(args)
        printer_args.moonraker = spec.url
        printer_args.record_tap = tap_recorder(store, spec, state, printer_display, parts) if store else None
        threads.append(threading.Thread(target=_follow_one, args=(parts, printer_args, printer_display, connect, codes),
                                        name=f"taps {spec.name}", daemon=True))
        if store is not None:
            threads.append(threading.Thread(target=watch_meshes, args=(store, spec, args.probe, state,
                                                                      printer_display, connect, parts),
                                            name=f"meshes {spec.name}", daemon=True))
    for thread in threads:
        thread.start()
    try:
        for thread in threads:
            if thread.name.startswith("taps "):
                thread.join()
    finally:
        for state in states:
            state.stop.set()
        if store is not None:
            store.close()
    return max(codes, default=0)


# -- tapcell import -------------------------------------------------------------------------------
def _documents(path: Path, options) -> list[tuple[dict, str]]:
    """(document with analysis, printer name found in it) per tap of a file; TapFileError if unreadable."""
    from tapcell.tap import TapFileError, analyze_tap, tap_to_json_dict
    from tapcell.tap.readers import read_tap_file, tap_from_object

    found = []
    if path.suffix.lower() in (".json", ".jsonl"):
        try:
            text = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise TapFileError(str(path), f"cannot be read: {exc}") from None
        lines = [text] if path.suffix.lower() == ".json" else text.splitlines()
        for number, line in enumerate(lines, 1):
            if not line.strip():
                continue
            where = f"line {number}" if path.suffix.lower() == ".jsonl" else ""
            try:
                obj = json.loads(line)
            except json.JSONDecodeError as exc:
                raise TapFileError(str(path), f"{where + ': ' if where else ''}not JSON ({exc.msg})") from None
            tap = tap_from_object(obj, str(path), where)  # checks the samples, whatever else it holds
            analysis = obj.get("analysis") if isinstance(obj, dict) else None
            if isinstance(analysis, dict) and "valid" in analysis and isinstance(obj.get("time"), list):
                document = obj  # a monitor's log line: keep the results it logged
            else:
                document = tap_to_json_dict(tap, analyze_tap(tap, options))
                if isinstance(obj, dict) and isinstance(obj.get("tap"), dict):  # a dump_taps event
                    printed = obj["tap"]
                    position = printed.get("tap_pos")
                    document["printer"] = {"z": position[2] if position else None, "tap_pos": position,
                                           "is_valid": printed.get("is_valid"), "error": printed.get("error")}
            source = (document.get("meta") or {}).get("monitor_source") if isinstance(document.get("meta"), dict) else None
            found.append((document, source))
    else:
        for tap in read_tap_file(path):
            found.append((tap_to_json_dict(tap, analyze_tap(tap, options)), None))
    return found


def import_main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="tapcell import", description="Load tap files (.json, .jsonl, .csv) "
                                     "and tapcell monitor logs into a tap store.")
    parser.add_argument("files", nargs="+", metavar="FILE")
    parser.add_argument("--db", metavar="URL", help="the store: a path, sqlite:///PATH or postgresql://... "
                        "(default: ~/.local/share/tapcell/taps.db)")
    parser.add_argument("--printer", metavar="NAME", help="the printer the taps belong to (default: the log's "
                        "monitor source, else 'imported')")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="analysis option for taps that carry no result, e.g. sensor_delay_s=0.002")
    args = parser.parse_args(argv)
    from tapcell.store import RecordError, Store, StoreError
    from tapcell.tap import TapFileError
    from tapcell.tap.cli import options_from_settings

    try:
        options = options_from_settings(args.set)
    except ValueError as exc:
        parser.error(str(exc))
    try:
        store = Store(args.db)
    except StoreError as exc:
        print(f"tapcell import: {exc}", file=sys.stderr)
        return 2
    problems = 0
    with store:
        for name in args.files:
            path = Path(name)
            try:
                documents = _documents(path, options)
            except TapFileError as exc:
                print(f"tapcell import: {exc}", file=sys.stderr)
                problems += 1
                continue
            by_printer: dict[str, list[dict]] = {}
            for document, source in documents:
                by_printer.setdefault(args.printer or source or "imported", []).append(document)
            for printer, group in by_printer.items():
                try:
                    added = store.add_taps(printer, group, recorded_s=path.stat().st_mtime)
                except RecordError as exc:
                    print(f"tapcell import: {path}: {exc}", file=sys.stderr)
                    problems += 1
                    continue
                new = sum(a.new for a in added)
                print(f"{path}: {new} taps added to printer '{printer}'"
                      + (f", {len(added) - new} already stored" if new < len(added) else ""))
    return 1 if problems else 0


main = import_main
