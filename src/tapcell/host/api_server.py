"""`tapcell serve`: the virtual printer behind Klipper's API on a Unix socket (for Moonraker).

The wire protocol is Klipper's: every message is one JSON object followed by the byte 0x03.
A request is `{"id": ..., "method": "...", "params": {...}}`; its reply carries the same id
(echoed as received: Moonraker reuses ids) and either `result` or
`error: {"error": "WebRequestError", "message": ...}`. Pushes (subscriptions, G-code output,
streams) are the request's `response_template` with `params` added.

Two threads:

* the printer thread owns the printer. G-code scripts run there one at a time, and while no
  script runs it advances the virtual printer's clock with the wall clock, so the load cell
  streams and temperatures live. A script starts only once the moves already queued are less
  than FEED_AHEAD_S ahead of the machine (Klipper's lookahead: a client's scripts keep pace
  with the printer, and the scripts of a client that has gone are still waiting, so they never
  run). After every script and tick it takes a snapshot of all status objects;
* the asyncio loop serves the connections. Queries and subscriptions read the latest
  snapshot, so they are answered at once, also while a long script (a bed mesh) runs.

RESTART and FIRMWARE_RESTART close every connection (Moonraker then reconnects and repeats
its handshake), as Klipper does. Bad input (malformed JSON, an unknown method, a message over
MAX_MESSAGE_BYTES, a client that stops reading) gets an error reply or loses its own
connection; the others are served on.
"""

from __future__ import annotations

import argparse
import asyncio
import collections
import concurrent.futures
import json
import math
import os
import platform
import queue
import signal
import socket
import stat
import sys
import threading
import time
import traceback
from pathlib import Path
from typing import Any, Callable

import numpy as np

from tapcell import __version__, package_files
from tapcell.files import why_missing
from tapcell.host.config import ConfigError
from tapcell.host.gcode import GCodeError, parse_line
from tapcell.host import load_cell_streams
from tapcell.host.print_clock import FEED_AHEAD_S, PrintClock
from tapcell.host.printer import WHEN_NOT_READY, Printer
from tapcell.host.webhooks import ApiObjects

MAX_MESSAGE_BYTES = 8 * 1024 * 1024  # a request longer than this closes its connection
MAX_UNSENT_BYTES = 64 * 1024 * 1024  # a client that stops reading is dropped past this
# All clients together: past this the clients holding the most unsent bytes are dropped first,
# so twenty clients that never read cost this much at most, not twenty times the limit above.
MAX_TOTAL_UNSENT_BYTES = 128 * 1024 * 1024
UNSENT_CHECK_BYTES = 1024 * 1024  # a client with less unsent is reading: no budget check
MEMORY_TRIM_DELAY_S = 1.0  # freed memory goes back to the system this long after clients leave
# Connections waiting to be accepted: asyncio's default (100) refuses a burst of clients (a farm
# dashboard reconnecting everything at once) with EAGAIN while the loop is busy.
LISTEN_BACKLOG = 1024
MAX_PENDING_REQUESTS = 100  # unanswered requests of one client before its next one is read
MAX_SUBSCRIBED_OBJECTS = 1000  # a Klipper printer has under 100 status objects
MAX_FIELDS_PER_OBJECT = 1000
IDLE_TICK_S = 0.1  # the printer thread's clock step while no script runs
MAX_TICK_S = 0.5  # at most this much virtual time per tick (after a stall)
SNAPSHOT_DURING_SCRIPT_S = 0.25  # a running script refreshes the status at most this often
SUBSCRIPTION_PERIOD_S = 0.25  # Klipper's status push period
STREAM_PERIOD_S = 0.1  # dump_force pushes (Klipper batches about this often)
RESTART_COMMANDS = {"gcode/restart": "RESTART", "gcode/firmware_restart": "FIRMWARE_RESTART"}
PAUSE_RESUME_COMMANDS = {"pause_resume/pause": "PAUSE", "pause_resume/resume": "RESUME",
                         "pause_resume/cancel": "CANCEL_PRINT"}


class SocketPathTaken(Exception):
    """`--socket` names something serve must not replace (the message says what is there)."""


def claim_socket_path(path: str) -> None:
    """Make `path` free for a new Unix socket: remove only a stale socket (no server answers on
    it). A regular file (perhaps printer.cfg), a directory, a symlink, a device or a socket a
    live server answers on is left as it is: SocketPathTaken names what is there."""
    try:
        info = os.lstat(path)
    except FileNotFoundError:
        return
    if stat.S_ISLNK(info.st_mode):
        raise SocketPathTaken(f"'{path}' is a symbolic link, not a socket: not replaced; "
                              f"give the path of the socket itself")
    if not stat.S_ISSOCK(info.st_mode):
        kind = "a regular file" if stat.S_ISREG(info.st_mode) else _file_kind(info.st_mode)
        raise SocketPathTaken(f"'{path}' is {kind}, not a socket: not replaced; choose another --socket path")
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        probe.settimeout(1.0)
        probe.connect(path)
    except (ConnectionRefusedError, FileNotFoundError):
        pass  # nobody listens: a socket left by a server that ended without removing it
    except OSError as exc:
        raise SocketPathTaken(f"'{path}' is a socket that cannot be checked ({exc.strerror or exc}): "
                              f"not replaced") from None
    else:
        raise SocketPathTaken(f"'{path}' is the socket of a running server (it accepts connections): "
                              f"stop that server first or choose another --socket path")
    finally:
        probe.close()
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass


def _file_kind(mode: int) -> str:
    for test, name in ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device")):
        if test(mode):
            return name
    return "not a socket"


def _release_socket_path(path: str, bound: os.stat_result | None) -> None:
    """Remove our socket at exit, unless the path now holds something else."""
    try:
        now = os.lstat(path)
    except FileNotFoundError:
        return
    if bound is not None and (now.st_dev, now.st_ino) == (bound.st_dev, bound.st_ino):
        os.unlink(path)


class RequestError(Exception):
    """A request that cannot be served; the message goes back in the error reply."""


def strict_json(message: dict) -> bytes:
    """The message as strict JSON plus the 0x03 terminator (NaN and infinity become null)."""
    return strict_text(message).encode("utf-8") + b"\x03"


def strict_text(value: Any) -> str:
    """Strict JSON text of a value (NaN and infinity become null)."""
    try:
        return json.dumps(value, allow_nan=False, separators=(",", ":"), default=_numpy_value)
    except ValueError:
        return json.dumps(_finite(value), allow_nan=False, separators=(",", ":"), default=_numpy_value)


def with_encoded_params(template: dict, params_text: str) -> bytes:
    """`{**template, "params": <params_text>}` as a message, with params already JSON text: a push
    many clients get (the 2,000 sps force stream) is encoded once, not once per client."""
    head = strict_text({key: value for key, value in template.items() if key != "params"})
    return f'{head[:-1]}{"," if len(head) > 2 else ""}"params":{params_text}}}'.encode("utf-8") + b"\x03"


def _numpy_value(value: Any) -> Any:
    if isinstance(value, np.generic | np.ndarray):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON data")


def _finite(value: Any) -> Any:
    if isinstance(value, np.generic | np.ndarray):
        value = value.tolist()
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {key: _finite(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(item) for item in value]
    return value


def changed_fields(new: dict[str, dict], old: dict[str, dict]) -> dict[str, dict]:
    """The objects and fields of `new` that differ from `old`."""
    diff = {}
    for name, fields in new.items():
        before = old.get(name, {})
        changed = {key: value for key, value in fields.items() if key not in before or before[key] != value}
        if changed:
            diff[name] = changed
    return diff


def select_fields(status: dict[str, dict], wanted: dict[str, list[str] | None]) -> dict[str, dict]:
    """The requested objects and fields (None: all fields; an unknown object: {})."""
    selected = {}
    for name, fields in wanted.items():
        available = status.get(name, {})
        selected[name] = dict(available) if fields is None else {f: available[f] for f in fields if f in available}
    return selected


def _param(params: dict, name: str, kind: type | tuple, default: Any = ...) -> Any:
    if name not in params:
        if default is ...:
            raise RequestError(f"Missing Argument [{name}]")
        return default
    value = params[name]
    if not isinstance(value, kind) or isinstance(value, bool) and kind is not bool:
        raise RequestError(f"Invalid Argument Type [{name}]")
    return value


def _objects_param(params: dict) -> dict[str, list[str] | None]:
    objects = _param(params, "objects", dict)
    for name, fields in objects.items():
        if fields is not None and not (isinstance(fields, list) and all(isinstance(f, str) for f in fields)):
            raise RequestError(f"Invalid Argument Type [objects]: '{name}' must map to null or a list of field names")
    _check_objects_size(objects)
    return objects


def _check_objects_size(objects: dict[str, list[str] | None]) -> None:
    """Refuse a query or subscription too large to be real: each push walks every name in it
    (200,000 made-up names cost a CPU core and 70 MB a client)."""
    if len(objects) > MAX_SUBSCRIBED_OBJECTS:
        raise RequestError(f"Invalid Argument [objects]: {len(objects):,} objects requested "
                           f"(at most {MAX_SUBSCRIBED_OBJECTS:,})")
    for name, fields in objects.items():
        if fields is not None and len(fields) > MAX_FIELDS_PER_OBJECT:
            raise RequestError(f"Invalid Argument [objects]: {len(fields):,} fields requested of "
                               f"'{name[:40]}' (at most {MAX_FIELDS_PER_OBJECT:,})")


def _template(params: dict) -> dict:
    return dict(_param(params, "response_template", dict))


# ---------------------------------------------------------------------------------------------
# The printer thread


class PrinterThread:
    """Runs every call into the printer on one thread; ticks the virtual clock while idle."""

    def __init__(self, printer, gcodes_dir: str | None, post: Callable[..., None]):
        self.printer = printer
        self.gcodes_dir = gcodes_dir
        self._post = post  # runs a function on the asyncio loop (thread-safe)
        self._jobs: queue.Queue = queue.Queue()  # (function, future, is_script)
        self._scripts: collections.deque = collections.deque()  # scripts waiting for the machine
        self._stop = threading.Event()
        self._restarted = False
        self._last_tick = time.monotonic()
        self._last_snapshot = 0.0
        self.objects: ApiObjects  # made by _attach, anew for every printer build
        self._thread = threading.Thread(target=self._run, name="tapcell-printer", daemon=True)
        self.on_snapshot: Callable[[dict], None] = lambda status: None
        self.on_output: Callable[[str], None] = lambda line: None
        self.on_restart: Callable[[], None] = lambda: None
        self.on_tap: Callable[[str, dict], None] = lambda name, event: None
        self.help: dict[str, str] = {}

    def start(self) -> None:
        """Attach to the printer and start the thread (the first snapshot is there at once)."""
        self.printer.gcode.set_response_sink(self._output)
        self._attach()
        self.on_snapshot(self.objects.status())
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)

    def submit(self, function: Callable[[], Any], is_script: bool = False) -> concurrent.futures.Future:
        """Run `function` on the printer thread; a script (G-code that moves the printer) waits
        until the machine has caught up with the moves queued before it."""
        future: concurrent.futures.Future = concurrent.futures.Future()
        self._jobs.put((function, future, is_script))
        return future

    # -- the loop -------------------------------------------------------------------------

    def _run(self) -> None:
        while not self._stop.is_set():
            if self._scripts and self._machine_caught_up():
                self._run_job(*self._scripts.popleft())
                continue
            try:
                function, future, is_script = self._jobs.get(timeout=IDLE_TICK_S)
            except queue.Empty:
                self._guarded(self._tick)
                continue
            if is_script:
                self._scripts.append((function, future))
            else:
                self._run_job(function, future)

    def _machine_caught_up(self) -> bool:
        """Whether the next script may start: the queued moves are less than FEED_AHEAD_S ahead of
        the machine (its clock is ticked here, as it is while idle)."""
        clock = self.printer.print_clock
        if clock is None or self.objects.state()[0] != "ready" or clock.lead_s() < FEED_AHEAD_S:
            return True
        self._guarded(self._tick)
        return clock.lead_s() < FEED_AHEAD_S

    def _run_job(self, function, future) -> None:
        if not future.set_running_or_notify_cancel():
            return  # its client went away before it ran (a vanished client's queued scripts never run)
        try:
            result = function()
        except RequestError as exc:
            outcome = ("error", str(exc))
        except Exception as exc:  # a bug in the printer: reported to the client and in the log
            traceback.print_exc()
            outcome = ("error", f"Internal error: {type(exc).__name__}: {exc}")
        else:
            outcome = ("result", result)
        self._guarded(self._after_job)
        self._post(_resolve, future, outcome)
        self._last_tick = time.monotonic()  # a script's own time is not idle time

    def _guarded(self, step: Callable[[], None]) -> None:
        """Run a step of the loop; a failure is logged and the printer keeps serving."""
        try:
            step()
        except Exception:
            traceback.print_exc()

    def _tick(self) -> None:
        now = time.monotonic()
        elapsed_s, self._last_tick = now - self._last_tick, now
        self.printer.finish_shutdown()
        state, _ = self.objects.state()
        clock = self.printer.print_clock
        if state == "ready" and clock is not None:
            clock.advance(min(elapsed_s, MAX_TICK_S))  # queued moves play; an idle printer's time passes
            self.printer.run_background()  # a file printing, the idle timeout
        self._snapshot()

    def _after_job(self) -> None:
        self.printer.finish_shutdown()  # an emergency stop from another connection: heaters off now
        if self._restarted:
            self._restarted = False
            self._attach()
            self._snapshot()
            self._post(self.on_restart)
        else:
            self._snapshot()

    def _snapshot(self) -> None:
        self._last_snapshot = time.monotonic()
        self._post(self.on_snapshot, self.objects.status())

    def _output(self, line: str) -> None:
        self._post(self.on_output, line)
        if time.monotonic() - self._last_snapshot >= SNAPSHOT_DURING_SCRIPT_S:
            self._snapshot()

    def _attach(self) -> None:
        """Hook into a fresh printer build: restart event, API commands, tap clients, help."""
        printer = self.printer
        self.objects = ApiObjects(printer, self.gcodes_dir)
        backend = printer.backend
        printer.print_clock = PrintClock(backend) if backend is not None and hasattr(backend, "dwell") else None
        printer.register_event_handler("printer:restart", self._note_restart)
        if printer.state == "ready":
            self.objects.register_commands(printer.gcode)
        for name, probe in load_cell_streams.tap_probes(printer).items():
            probe.add_tap_client(
                lambda recorded, name=name: self._post(self.on_tap, name, load_cell_streams.tap_event(recorded)))
        self.help = printer.gcode.get_command_help()

    def _note_restart(self) -> None:
        self._restarted = True

    # -- jobs (run on this thread) --------------------------------------------------------

    def run_script(self, script: str) -> dict:
        """Each line in turn; the first error is echoed as `!! message` and fails the request."""
        gcode = self.printer.gcode
        try:
            for line in script.split("\n"):
                self._check_ready(line)
                gcode.run_line(line)
        except GCodeError as exc:
            gcode.respond_error(str(exc))
            raise RequestError(str(exc)) from None
        return {}

    def call_endpoint(self, path: str, params: dict) -> dict:
        """A module's endpoint (query_endstops/status), refused like G-code unless the printer is ready."""
        state, message = self.objects.state()
        callback = self.printer.endpoints.get(path)
        if state != "ready" or callback is None:
            raise RequestError(message if state != "ready" else f"No registered callback for path '{path}'")
        return callback(params)

    def _check_ready(self, line: str) -> None:
        """Webhooks refuse G-code in every state but ready (startup, error, shutdown) with their state
        message, as Klipper answers Moonraker. Not the G-code layer's refusal: that one is set only
        by a shutdown and says the printer's own message (a webhooks emergency_stop says Klipper's
        FIRMWARE_RESTART advice), and after a broken config the console still answers "Unknown
        command" (tests/test_printer.py), where the API answers with the config error."""
        state, message = self.objects.state()
        if state == "ready":
            return
        parsed = parse_line(line)
        if parsed is not None and parsed.command not in WHEN_NOT_READY:
            raise GCodeError(message)


def _asks_emergency_stop(script: str) -> bool:
    """Whether a line of the script is M112 (a line that does not parse is left to the printer)."""
    for line in script.split("\n"):
        try:
            parsed = parse_line(line)
        except GCodeError:
            continue
        if parsed is not None and parsed.command == "M112":
            return True
    return False


def _resolve(future: concurrent.futures.Future, outcome: tuple[str, Any]) -> None:
    kind, value = outcome
    if future.cancelled():  # its client is gone
        return
    if kind == "result":
        future.set_result(value)
    else:
        future.set_exception(RequestError(value))


# ---------------------------------------------------------------------------------------------
# Connections


class Connection:
    """One client: its subscription, G-code output template, streams and remote methods."""

    def __init__(self, server: ApiServer, reader: asyncio.StreamReader, writer: asyncio.StreamWriter):
        self.server = server
        self.reader = reader
        self.writer = writer
        self.subscription: dict[str, list[str] | None] = {}
        self.subscription_template: dict | None = None
        self.sent_status: dict[str, dict] = {}
        self.output_template: dict | None = None
        self.force_streams: dict[str, ForceStream] = {}  # by cell name
        self.tap_templates: dict[str, dict] = {}  # probe name -> template
        self.tasks: set[asyncio.Task] = set()
        self.closed = False

    def send(self, message: dict) -> None:
        if self.closed:
            return
        self.send_bytes(strict_json(message))

    def send_bytes(self, data: bytes) -> None:
        """Send an encoded message (see strict_json, with_encoded_params)."""
        if self.closed:
            return
        self.writer.write(data)
        if self.unsent_bytes() > UNSENT_CHECK_BYTES:
            self.server.bound_unsent(self)

    def unsent_bytes(self) -> int:
        return 0 if self.closed else self.writer.transport.get_write_buffer_size()

    def drop(self, reason: str) -> None:
        """Close now, throwing away what it has not read (close() would keep it until sent)."""
        if self.closed:
            return
        print(f"tapcell serve: {reason}: closing it", file=sys.stderr)
        self.closed = True
        self.server.forget(self)
        self.writer.transport.abort()

    def push(self, template: dict, params: dict) -> None:
        self.send({**template, "params": params})

    def close(self) -> None:
        if self.closed:
            return
        if self.unsent_bytes() > UNSENT_CHECK_BYTES:  # a client gone without reading: free it now
            self.drop("a client left with unread messages")
            _return_freed_memory()
            return
        self.closed = True
        self.server.forget(self)
        self.writer.close()

    async def serve(self) -> None:
        try:
            while not self.closed:
                try:
                    data = await self.reader.readuntil(b"\x03")
                except asyncio.LimitOverrunError:
                    self.send({"id": None, "error": _error(f"Message too long (limit {MAX_MESSAGE_BYTES} bytes)")})
                    break
                except (asyncio.IncompleteReadError, ConnectionError):
                    break
                self._handle(data[:-1])
                await self._wait_for_the_client()
        finally:
            self.close()

    async def _wait_for_the_client(self) -> None:
        """Backpressure: read no further request from a client that leaves its replies unread or
        has MAX_PENDING_REQUESTS unanswered, so one client cannot queue unbounded work and memory
        (its own writes then block); the other clients are served meanwhile."""
        while not self.closed:
            if self.unsent_bytes() > UNSENT_CHECK_BYTES:
                try:
                    await self.writer.drain()
                except ConnectionError:
                    return
            elif len(self.tasks) >= MAX_PENDING_REQUESTS:
                await asyncio.wait(set(self.tasks), return_when=asyncio.FIRST_COMPLETED)
            else:
                return

    def _handle(self, data: bytes) -> None:
        try:
            request = json.loads(data)
        except (ValueError, UnicodeDecodeError) as exc:
            self.send({"id": None, "error": _error(f"Malformed request: not JSON ({exc})")})
            return
        except RecursionError:
            self.send({"id": None, "error": _error("Malformed request: nested deeper than the JSON reader allows")})
            return
        if not isinstance(request, dict):
            self.send({"id": None, "error": _error("Malformed request: expected a JSON object")})
            return
        request_id = request.get("id")
        method, params = request.get("method"), request.get("params", {})
        if not isinstance(method, str) or not isinstance(params, dict):
            self.send({"id": request_id, "error": _error("Malformed request: 'method' must be a string and "
                                                          "'params' an object")})
            return
        task = asyncio.ensure_future(self._answer(request_id, method, params))
        self.tasks.add(task)
        task.add_done_callback(self.tasks.discard)

    async def _answer(self, request_id: Any, method: str, params: dict) -> None:
        # A connection closed meanwhile (a RESTART closes them all) cancels this: no reply, as in Klipper.
        try:
            result = await self.server.call(self, method, params)
        except RequestError as exc:
            reply = {"id": request_id, "error": _error(str(exc))}
        else:
            reply = {"id": request_id, "result": result}
        self.send(reply)


class ForceStream:
    """One connection's dump_force stream: its template and the rows not pushed yet, each row
    already JSON text (encoded once for every connection streaming the cell)."""

    def __init__(self, template: dict):
        self.template = template
        self.rows: list[str] = []
        self.errors = 0
        self.overflows = 0

    def add(self, rows: list[str], errors: int, overflows: int) -> None:
        self.rows.extend(rows)
        self.errors += errors
        self.overflows += overflows

    def pushes(self) -> list[bytes]:
        """The unsent rows as messages of at most MAX_ROWS_PER_PUSH rows each."""
        limit = load_cell_streams.MAX_ROWS_PER_PUSH
        messages = []
        for k in range(0, len(self.rows), limit):
            errors, overflows = (self.errors, self.overflows) if k == 0 else (0, 0)
            params = f'{{"data":[{",".join(self.rows[k:k + limit])}],"errors":{errors},"overflows":{overflows}}}'
            messages.append(with_encoded_params(self.template, params))
        if messages:
            self.rows, self.errors, self.overflows = [], 0, 0
        return messages


def _error(message: str) -> dict:
    return {"error": "WebRequestError", "message": message}


# ---------------------------------------------------------------------------------------------
# The server


class ApiServer:
    """Klipper's API for one printer on a Unix socket."""

    def __init__(self, printer, socket_path: str, *, log_file: str = "", gcodes_dir: str | None = None):
        self.socket_path = str(socket_path)
        self.log_file = log_file
        self.config_file = os.path.abspath(printer.config_path)
        self.connections: set[Connection] = set()
        self.status: dict[str, dict] = {}
        self.loop: asyncio.AbstractEventLoop | None = None
        self.printer_thread = PrinterThread(printer, gcodes_dir, self._post)
        self.printer_thread.on_snapshot = self._on_snapshot
        self.printer_thread.on_output = self._on_output
        self.printer_thread.on_restart = self._on_restart
        self.printer_thread.on_tap = self._on_tap
        # One sample client per streamed cell, shared by the connections: cell name -> the
        # future of its ClientHandle (added on the printer thread).
        self._force_clients: dict[str, asyncio.Future] = {}
        self._trim_scheduled = False
        self._endpoints: dict[str, Callable] = {
            "info": self._info,
            "list_endpoints": self._list_endpoints,
            "objects/list": self._objects_list,
            "objects/query": self._objects_query,
            "objects/subscribe": self._objects_subscribe,
            "gcode/script": self._gcode_script,
            "gcode/help": self._gcode_help,
            "gcode/subscribe_output": self._gcode_subscribe_output,
            "register_remote_method": self._register_remote_method,
            "emergency_stop": self._emergency_stop,
            "load_cell/dump_force": self._dump_force,
            "load_cell_probe/dump_taps": self._dump_taps,
            **{name: self._gcode_command for name in (*RESTART_COMMANDS, *PAUSE_RESUME_COMMANDS)},
        }

    # -- running --------------------------------------------------------------------------

    async def serve_forever(self, ready: Callable[[], None] | None = None) -> None:
        self.loop = asyncio.get_running_loop()
        stop = asyncio.Event()
        for sig in (signal.SIGINT, signal.SIGTERM):
            self.loop.add_signal_handler(sig, stop.set)
        claim_socket_path(self.socket_path)  # SocketPathTaken: nothing was started or removed
        server = await asyncio.start_unix_server(self._accept, path=self.socket_path, limit=MAX_MESSAGE_BYTES,
                                                 backlog=LISTEN_BACKLOG)
        bound = os.lstat(self.socket_path)
        self.printer_thread.start()
        periodic = [asyncio.ensure_future(self._every(SUBSCRIPTION_PERIOD_S, self._push_subscriptions)),
                    asyncio.ensure_future(self._every(STREAM_PERIOD_S, self._push_force))]
        if ready is not None:
            ready()
        try:
            await stop.wait()
        finally:
            for task in periodic:
                task.cancel()
            server.close()
            for connection in list(self.connections):
                connection.close()
            self.printer_thread.stop()
            _release_socket_path(self.socket_path, bound)

    async def _accept(self, reader, writer) -> None:
        connection = Connection(self, reader, writer)
        self.connections.add(connection)
        try:
            await connection.serve()
        except asyncio.CancelledError:
            # The loop ends (SIGTERM) while the client is connected: asyncio's stream callback
            # would print the cancellation as a traceback. The connection is closed already.
            pass

    async def _every(self, period_s: float, step: Callable[[], None]) -> None:
        while True:
            await asyncio.sleep(period_s)
            step()

    def _post(self, function, *args) -> None:
        """From the printer thread: run function(*args) on the loop (in order)."""
        if self.loop is not None and not self.loop.is_closed():
            self.loop.call_soon_threadsafe(function, *args)

    def forget(self, connection: Connection) -> None:
        self.connections.discard(connection)
        self._schedule_memory_trim()
        for task in connection.tasks:
            task.cancel()
        for name in connection.force_streams:
            self._release_force_client(name)

    def _schedule_memory_trim(self) -> None:
        """After clients go, hand their freed buffers (up to 8 MiB of a request each) back to the
        system, at most once a second however many leave."""
        if self.loop is None or self._trim_scheduled:
            return
        self._trim_scheduled = True

        def trim() -> None:
            self._trim_scheduled = False
            _return_freed_memory()

        self.loop.call_later(MEMORY_TRIM_DELAY_S, trim)

    def bound_unsent(self, connection: Connection) -> None:
        """Keep what clients have not read within MAX_UNSENT_BYTES each and MAX_TOTAL_UNSENT_BYTES
        together: past the total, the clients holding the most are dropped first."""
        unsent = connection.unsent_bytes()
        if unsent > MAX_UNSENT_BYTES:
            connection.drop(f"a client stopped reading ({unsent:,} bytes unsent, at most {MAX_UNSENT_BYTES:,})")
            _return_freed_memory()
            return
        holders = sorted(((c.unsent_bytes(), id(c), c) for c in self.connections), reverse=True)
        total = sum(size for size, _, _ in holders)
        if total <= MAX_TOTAL_UNSENT_BYTES:
            return
        for size, _, holder in holders:
            if total <= MAX_TOTAL_UNSENT_BYTES:
                break
            holder.drop(f"a client stopped reading: clients hold {total:,} bytes unsent (at most "
                        f"{MAX_TOTAL_UNSENT_BYTES:,} together) and this one the most ({size:,})")
            total -= size
        _return_freed_memory()

    async def call(self, connection: Connection, method: str, params: dict) -> Any:
        endpoint = self._endpoints.get(method)
        if endpoint is None and method in self.printer_thread.printer.endpoints:
            return await self._on_printer(lambda: self.printer_thread.call_endpoint(method, params))
        if endpoint is None:
            raise RequestError(f"No registered callback for path '{method}'")
        result = endpoint(connection, method, params)
        if asyncio.iscoroutine(result):
            result = await result
        return result

    async def _on_printer(self, function: Callable[[], Any], is_script: bool = False) -> Any:
        future = self.printer_thread.submit(function, is_script)
        return await asyncio.wrap_future(future)

    # -- from the printer thread ----------------------------------------------------------

    def _on_snapshot(self, status: dict) -> None:
        self.status = status

    def _on_output(self, line: str) -> None:
        for connection in list(self.connections):
            if connection.output_template is not None:
                connection.push(connection.output_template, {"response": line})

    def _on_restart(self) -> None:
        """Like Klipper: every connection closes; clients reconnect to the new printer."""
        for connection in list(self.connections):
            connection.close()
        self._force_clients.clear()  # their cells belonged to the old printer

    def _on_tap(self, probe_name: str, event: dict) -> None:
        for connection in list(self.connections):
            template = connection.tap_templates.get(probe_name)
            if template is not None:
                connection.push(template, event)

    # -- periodic pushes ------------------------------------------------------------------

    def _push_subscriptions(self) -> None:
        eventtime = time.monotonic()
        for connection in list(self.connections):
            if connection.subscription_template is None:
                continue
            current = select_fields(self.status, connection.subscription)
            diff = changed_fields(current, connection.sent_status)
            if diff:
                connection.sent_status = current
                connection.push(connection.subscription_template, {"eventtime": eventtime, "status": diff})

    def _push_force(self) -> None:
        for connection in list(self.connections):
            for stream in connection.force_streams.values():
                for message in stream.pushes():
                    connection.send_bytes(message)

    # -- endpoints ------------------------------------------------------------------------

    def _info(self, connection, method, params) -> dict:
        state, message = self.printer_thread.objects.state()
        return {
            "state": state,
            "state_message": message,
            "hostname": socket.gethostname(),
            "klipper_path": str(_software_root()),
            "python_path": sys.executable,
            "log_file": self.log_file,
            "config_file": self.config_file,
            "software_version": f"tapcell {__version__}",
            "cpu_info": f"{os.cpu_count()} core {platform.machine()}".strip(),
            "process_id": os.getpid(),
            "user_id": os.getuid(),
            "group_id": os.getgid(),
        }

    def _list_endpoints(self, connection, method, params) -> dict:
        return {"endpoints": sorted([*self._endpoints, *self.printer_thread.printer.endpoints])}

    def _objects_list(self, connection, method, params) -> dict:
        return {"objects": list(self.status)}

    def _objects_query(self, connection, method, params) -> dict:
        return {"eventtime": time.monotonic(), "status": select_fields(self.status, _objects_param(params))}

    def _objects_subscribe(self, connection, method, params) -> dict:
        objects = _objects_param(params)
        template = _template(params)
        current = select_fields(self.status, objects)
        connection.subscription, connection.subscription_template = objects, template
        connection.sent_status = current
        return {"eventtime": time.monotonic(), "status": current}

    async def _gcode_script(self, connection, method, params) -> dict:
        script = _param(params, "script", str)
        if _asks_emergency_stop(script):
            # Not queued behind the running script (a mesh would finish first): M112 acts at once,
            # as Klipper acts on an M112 it reads from its serial input before the queued lines.
            self._shut_down("Shutdown due to M112 command")
            return {}
        return await self._run_gcode(script)

    async def _gcode_command(self, connection, method, params) -> dict:
        command = RESTART_COMMANDS.get(method) or PAUSE_RESUME_COMMANDS[method]
        return await self._run_gcode(command)

    async def _run_gcode(self, script: str) -> dict:
        return await self._on_printer(lambda: self.printer_thread.run_script(script), is_script=True)

    def _gcode_help(self, connection, method, params) -> dict:
        return dict(self.printer_thread.help)

    def _gcode_subscribe_output(self, connection, method, params) -> dict:
        connection.output_template = _template(params)
        return {}

    def _register_remote_method(self, connection, method, params) -> dict:
        # Accepted (Moonraker registers its methods at every handshake); tapcell's G-code
        # never calls a remote method, so nothing more is kept.
        _param(params, "remote_method", str)
        _template(params)
        return {}

    def _emergency_stop(self, connection, method, params) -> dict:
        self._shut_down("Shutdown due to webhooks request")
        return {}

    def _shut_down(self, reason: str) -> None:
        """At once, on this thread: the steppers stop at the next sample, the running script fails
        with the shutdown message (its command and the rest of it), queued scripts are refused."""
        self.printer_thread.objects.shutdown(reason)
        self._on_output(f"!! {reason}")
        self.status = {**self.status, "webhooks": dict(zip(("state", "state_message"),
                                                          self.printer_thread.objects.state()))}

    async def _dump_force(self, connection, method, params) -> dict:
        name = _param(params, "load_cell", str)
        template = _template(params) if "response_template" in params else {}
        if name not in self._force_clients:
            self._force_clients[name] = asyncio.ensure_future(self._on_printer(lambda: self._add_force_client(name)))
        try:
            await asyncio.shield(self._force_clients[name])
        except RequestError:
            self._force_clients.pop(name, None)
            raise
        connection.force_streams.setdefault(name, ForceStream(template))
        return {"header": list(load_cell_streams.FORCE_HEADER)}

    def _add_force_client(self, name: str):
        """On the printer thread: a sample client for the cell, feeding every connection's stream."""
        cells = load_cell_streams.load_cells(self.printer_thread.printer)
        if name not in cells:
            raise RequestError(f"The value '{name}' is not valid for load_cell "
                               f"(one of: {', '.join(sorted(cells)) or 'none configured'})")
        cell = cells[name]
        return cell.add_client(lambda batch: self._post(
            self._queue_force_rows, name, load_cell_streams.force_rows(cell, batch), batch.errors, batch.overflows))

    def _queue_force_rows(self, name: str, rows: list, errors: int, overflows: int) -> None:
        streams = [c.force_streams[name] for c in self.connections if name in c.force_streams]
        encoded = [strict_text(row) for row in rows] if streams else []
        for stream in streams:
            stream.add(encoded, errors, overflows)

    def _release_force_client(self, name: str) -> None:
        """When no connection streams the cell any more, its sample client goes."""
        client = self._force_clients.get(name)
        if client is None or any(name in c.force_streams for c in self.connections):
            return
        del self._force_clients[name]
        if client.done() and client.exception() is None:
            self.printer_thread.submit(client.result().remove)

    async def _dump_taps(self, connection, method, params) -> dict:
        name = _param(params, "load_cell_probe", str)
        template = _template(params) if "response_template" in params else {}
        probes = await self._on_printer(lambda: sorted(load_cell_streams.tap_probes(self.printer_thread.printer)))
        if name not in probes:
            raise RequestError(f"The value '{name}' is not valid for load_cell_probe "
                               f"(one of: {', '.join(probes) or 'none configured'})")
        connection.tap_templates[name] = template
        return {"header": list(load_cell_streams.TAP_HEADER)}


def _return_freed_memory() -> None:
    """Give the heap freed by dropped clients back to the system (glibc keeps freed blocks
    under 32 MB for reuse, so without this the RSS stays at its peak after they go)."""
    try:
        import ctypes

        ctypes.CDLL(None).malloc_trim(0)
    except (OSError, AttributeError):
        pass  # not glibc: nothing to trim


def _software_root() -> Path:
    """Where tapcell's files are: the checkout (with docs/ and examples/) or the installed package."""
    return package_files.software_root()


# ---------------------------------------------------------------------------------------------
# The command


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="tapcell serve", description="Serve the virtual printer through "
                                     "Klipper's API on a Unix socket, for Moonraker and its web UIs.")
    parser.add_argument("--config", required=True, help="printer config file")
    parser.add_argument("--socket", required=True, help="Unix socket path (Moonraker's klippy_uds_address)")
    parser.add_argument("--log-file", default="", help="the log file named to clients (info.log_file)")
    parser.add_argument("--gcodes-dir", default=None,
                        help="the folder Moonraker serves G-code files from (configfile virtual_sdcard.path)")
    args = parser.parse_args(argv)
    if not os.path.isfile(args.config):
        print(f"tapcell serve: config file '{args.config}' {why_missing(args.config)}", file=sys.stderr)
        return 2
    printer = Printer(args.config)
    printer.gcodes_dir = args.gcodes_dir
    try:
        printer.restart()  # builds it; a broken config leaves it in the "error" state, served as such
    except ConfigError as exc:
        print(f"tapcell serve: config error (serving the error state): {exc}", file=sys.stderr)
    server = ApiServer(printer, args.socket, log_file=args.log_file, gcodes_dir=args.gcodes_dir)
    try:
        asyncio.run(server.serve_forever(
            ready=lambda: print(f"tapcell serve: {printer.state_message}; listening on {args.socket}", flush=True)))
    except SocketPathTaken as exc:
        print(f"tapcell serve: --socket {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # bind: a missing folder, no permission, a path too long for a socket
        print(f"tapcell serve: cannot listen on '{args.socket}': {exc.strerror or exc}", file=sys.stderr)
        return 2
    return 0
