"""Processes for the API tests: `tapcell serve` and the real Moonraker, on loopback only.

Every process is started by pid and stopped by that pid; every wait has a deadline, so a
hung server fails its test instead of hanging the run.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest

from real_packages import ROOT, moonraker_python

EXAMPLE = ROOT / "examples" / "virtual-printer.cfg"
# The virtual cell's truth (110 counts/g, zero at -38000 counts), as LOAD_CELL_CALIBRATE finds it.
CALIBRATION = "counts_per_gram: 110\nreference_tare_counts: -38000\n"
START_TIMEOUT_S = 60.0  # scipy's import alone takes seconds on a busy 2-core machine
STOP_TIMEOUT_S = 10.0


def printer_config(folder: Path) -> Path:
    """The example printer, calibrated, in `folder`."""
    path = folder / "printer.cfg"
    path.write_text(EXAMPLE.read_text().replace("z_offset: 0\n", "z_offset: 0\n" + CALIBRATION, 1))
    return path


def wait_for(check, timeout_s: float, what: str, process: subprocess.Popen | None = None):
    """Poll `check()` until it returns something truthy; fail after timeout_s (or if the process died)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if process is not None and process.poll() is not None:
            pytest.fail(f"{what}: the process exited with {process.returncode}")
        result = check()
        if result:
            return result
        time.sleep(0.1)
    pytest.fail(f"{what}: not within {timeout_s:g} s")


def stop(process: subprocess.Popen) -> None:
    if process.poll() is None:
        process.send_signal(signal.SIGTERM)
        try:
            process.wait(timeout=STOP_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(timeout=STOP_TIMEOUT_S)


def start_serve(config: Path, socket_path: Path, log: Path) -> subprocess.Popen:
    process = subprocess.Popen(
        [sys.executable, "-m", "tapcell", "serve", "--config", str(config), "--socket", str(socket_path),
         "--gcodes-dir", str(config.parent.parent / "gcodes")],
        stdout=log.open("w"), stderr=subprocess.STDOUT)
    # The socket file appears at bind(), a moment before listen(): wait for a connection to succeed.
    wait_for(lambda: accepts(socket_path), START_TIMEOUT_S, "tapcell serve to listen", process)
    return process


def accepts(socket_path: Path) -> bool:
    """Whether a server listens on the Unix socket (a connection is made and closed at once)."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as probe:
        try:
            probe.connect(str(socket_path))
        except (FileNotFoundError, ConnectionRefusedError):
            return False
    return True


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@contextlib.contextmanager
def serving(folder: Path):
    """`tapcell serve` on a calibrated virtual printer in `folder`; yields the socket path."""
    socket_path = folder / "klippy.sock"
    process = start_serve(printer_config(folder), socket_path, folder / "serve.log")
    try:
        yield socket_path
    finally:
        stop(process)


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """`tapcell serve` on a calibrated virtual printer; yields the socket path."""
    with serving(tmp_path_factory.mktemp("served")) as socket_path:
        yield socket_path


MOONRAKER_CONF = """\
[server]
host: 127.0.0.1
port: {port}
klippy_uds_address: {socket}

[authorization]
trusted_clients:
  127.0.0.0/8

[machine]
provider: none
validate_service: False
validate_config: False

[announcements]
enable_moonlight: False
"""


class Stack:
    """tapcell serve behind the real Moonraker: HTTP helpers and the process handles."""

    def __init__(self, data: Path, port: int):
        self.data = data
        self.port = port
        self.socket = data / "comms" / "klippy.sock"
        self.serve: subprocess.Popen | None = None
        self.moonraker: subprocess.Popen | None = None

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def get(self, path: str, timeout_s: float = 30.0, method: str = "GET") -> tuple[int, dict]:
        request = urllib.request.Request(self.url + path, method=method)
        try:
            with urllib.request.urlopen(request, timeout=timeout_s) as answer:
                return answer.status, json.loads(answer.read())
        except urllib.error.HTTPError as error:
            return error.code, json.loads(error.read() or b"{}")

    def klippy_state(self) -> str | None:
        try:
            status, body = self.get("/server/info", timeout_s=5.0)
        except (urllib.error.URLError, ConnectionError, TimeoutError):
            return None
        return body["result"]["klippy_state"] if status == 200 else None

    def wait_ready(self) -> None:
        wait_for(lambda: self.klippy_state() == "ready", START_TIMEOUT_S, "Moonraker to report Klippy ready",
                 self.moonraker)


@contextlib.contextmanager
def running_stack(tmp_path_factory):
    """A calibrated virtual printer served to a real Moonraker on 127.0.0.1 (free port, tmp data)."""
    python = moonraker_python()
    data = tmp_path_factory.mktemp("printer_data")
    for folder in ("config", "comms", "gcodes", "logs"):
        (data / folder).mkdir()
    stack = Stack(data, free_port())
    (data / "config" / "moonraker.conf").write_text(MOONRAKER_CONF.format(port=stack.port, socket=stack.socket))
    config = printer_config(data / "config")
    stack.serve = start_serve(config, stack.socket, data / "logs" / "serve.log")
    environment = dict(os.environ, PYTHONPATH="")
    stack.moonraker = subprocess.Popen(
        [str(python), "-m", "moonraker", "-d", str(data), "-l", str(data / "logs" / "moonraker.log")],
        stdout=subprocess.DEVNULL, stderr=(data / "logs" / "moonraker.stderr").open("w"), env=environment)
    try:
        stack.wait_ready()
        yield stack
    finally:
        stop(stack.moonraker)
        stop(stack.serve)


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    """A calibrated virtual printer served to a real Moonraker on 127.0.0.1 (free port, tmp data)."""
    with running_stack(tmp_path_factory) as running:
        yield running
