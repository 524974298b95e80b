"""Issue 20: `tapcell serve` against hostile paths and signals: nothing deleted, no traceback."""

from __future__ import annotations

import os
import socket
import subprocess
import sys

import pytest

from conftest import STOP_TIMEOUT_S, printer_config, start_serve
from klippy_client import KlippyClient
from tapcell.host.api_server import SocketPathTaken, claim_socket_path

SERVE_TIMEOUT_S = 120.0  # a refusal comes right after the printer is built (seconds on a busy machine)


def test_a_regular_file_a_directory_and_a_link_are_left_as_they_are(tmp_path):
    config = tmp_path / "printer.cfg"
    config.write_text("[printer]\n")
    with pytest.raises(SocketPathTaken, match=r"'.*printer.cfg' is a regular file, not a socket: not replaced"):
        claim_socket_path(str(config))
    assert config.read_text() == "[printer]\n"
    with pytest.raises(SocketPathTaken, match=r"is a directory, not a socket"):
        claim_socket_path(str(tmp_path))
    link = tmp_path / "link.sock"
    link.symlink_to(config)
    with pytest.raises(SocketPathTaken, match=r"is a symbolic link, not a socket"):
        claim_socket_path(str(link))
    assert link.is_symlink() and config.read_text() == "[printer]\n"
    os.mkfifo(tmp_path / "fifo")
    with pytest.raises(SocketPathTaken, match=r"is a FIFO \(named pipe\), not a socket"):
        claim_socket_path(str(tmp_path / "fifo"))


def test_a_live_socket_is_refused_and_a_stale_one_replaced(tmp_path):
    path = tmp_path / "klippy.sock"
    listener = socket.socket(socket.AF_UNIX)
    listener.bind(str(path))
    listener.listen()
    try:
        with pytest.raises(SocketPathTaken, match=r"is the socket of a running server"):
            claim_socket_path(str(path))
        assert path.is_socket()
    finally:
        listener.close()  # nobody listens now: the socket file is stale
    assert path.is_socket()
    claim_socket_path(str(path))
    assert not path.exists()
    claim_socket_path(str(path))  # nothing there: nothing to do


def _serve(config, socket_path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "tapcell", "serve", "--config", str(config),
                           "--socket", str(socket_path)], capture_output=True, text=True, timeout=SERVE_TIMEOUT_S)


def test_serve_refuses_its_own_config_as_socket_and_a_second_server(tmp_path):
    config = printer_config(tmp_path)
    before = config.read_bytes()
    refused = _serve(config, config)
    assert refused.returncode == 2
    assert refused.stderr.splitlines()[-1] == (f"tapcell serve: --socket '{config}' is a regular file, "
                                               f"not a socket: not replaced; choose another --socket path")
    assert config.read_bytes() == before and "Traceback" not in refused.stderr

    socket_path = tmp_path / "klippy.sock"
    first = start_serve(config, socket_path, tmp_path / "first.log")
    try:
        second = _serve(config, socket_path)
        assert second.returncode == 2
        assert "is the socket of a running server" in second.stderr
        client = KlippyClient(socket_path)  # the first still serves, on the same socket file
        assert client.call("info")["result"]["state"] == "ready"
        # SIGTERM with a client connected ends it quietly: exit 0, no traceback, the socket removed.
        first.send_signal(15)
        first.wait(timeout=STOP_TIMEOUT_S)
        client.close()
    finally:
        if first.poll() is None:
            first.kill()
            first.wait(timeout=STOP_TIMEOUT_S)
    assert first.returncode == 0
    assert "Traceback" not in (tmp_path / "first.log").read_text()
    assert not socket_path.exists()
