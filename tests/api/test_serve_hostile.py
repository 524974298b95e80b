"""Issue 20: `tapcell serve` against hostile paths and signals: nothing deleted, no traceback."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys

import pytest

from conftest import STOP_TIMEOUT_S, printer_config, start_serve
from klippy_client import KlippyClient
from tapcell.host import api_server
from tapcell.host.api_server import (RequestError, SocketPathTaken, _objects_param, claim_socket_path, strict_json,
                                     strict_text, with_encoded_params)

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


# -- memory and work bounded as a whole --------------------------------------------------------

MIB = 1024 * 1024


class FakeConnection:
    def __init__(self, unsent_mib: float):
        self.unsent = int(unsent_mib * MIB)
        self.closed = False
        self.reason = None

    def unsent_bytes(self) -> int:
        return 0 if self.closed else self.unsent

    def drop(self, reason: str) -> None:
        self.closed, self.reason = True, reason
        FakeServer.current.connections.discard(self)


class FakeServer:
    current = None

    def __init__(self, *sizes_mib):
        self.connections = {FakeConnection(size) for size in sizes_mib}
        FakeServer.current = self


def bound(*sizes_mib) -> dict[float, str | None]:
    """{unsent MiB: why dropped or None} after the server's check for the connection of the first size."""
    server = FakeServer(*sizes_mib)
    everyone = list(server.connections)
    checked = next(c for c in everyone if c.unsent == int(sizes_mib[0] * MIB))
    api_server.ApiServer.bound_unsent(server, checked)
    return {c.unsent / MIB: c.reason for c in everyone}


def test_the_clients_holding_the_most_unsent_bytes_are_dropped_first():
    assert api_server.MAX_TOTAL_UNSENT_BYTES == 128 * MIB and api_server.MAX_UNSENT_BYTES == 64 * MIB
    # 2 + 50 + 40 + 45 = 137 MiB together: the 50 MiB client goes, the rest stay (87 MiB).
    result = bound(2, 50, 40, 45)
    assert [size for size, reason in result.items() if reason] == [50]
    assert result[50] == ("a client stopped reading: clients hold 143,654,912 bytes unsent (at most 134,217,728 "
                          "together) and this one the most (52,428,800)")
    # Under the total nobody goes; one client over its own limit goes alone.
    assert not any(bound(2, 50, 40, 30).values())
    result = bound(65, 1, 2)
    assert result[65].startswith("a client stopped reading (68,157,440 bytes unsent, at most 67,108,864)")
    assert result[1] is None and result[2] is None


def test_a_subscription_too_large_to_be_real_is_refused():
    objects = {f"made_up_{k}": None for k in range(api_server.MAX_SUBSCRIBED_OBJECTS + 1)}
    with pytest.raises(RequestError, match=r"^Invalid Argument \[objects\]: 1,001 objects requested \(at most 1,000\)$"):
        _objects_param({"objects": objects})
    fields = [f"f{k}" for k in range(api_server.MAX_FIELDS_PER_OBJECT + 1)]
    with pytest.raises(RequestError, match=r"^Invalid Argument \[objects\]: 1,001 fields requested of 'toolhead' "
                                           r"\(at most 1,000\)$"):
        _objects_param({"objects": {"toolhead": fields}})
    assert _objects_param({"objects": {"toolhead": ["position"], "webhooks": None}}) == \
        {"toolhead": ["position"], "webhooks": None}


@pytest.mark.parametrize("template", [{}, {"method": "f"}, {"method": "f", "params": {"old": 1}},
                                      {"id": 7, "nested": {"a": [1, 2]}}])
def test_a_push_encoded_once_is_the_message_encoded_per_client(template):
    params = {"data": [[1.5, float("nan"), 3], [2.0, 1e-9, None]], "errors": 0, "overflows": 0}
    assert with_encoded_params(template, strict_text(params)) == strict_json({**template, "params": params})


def test_json_nested_too_deep_gets_an_error_reply_not_a_traceback():
    sent = []
    connection = api_server.Connection.__new__(api_server.Connection)
    connection.send = sent.append
    for data in (b'{"id":1,"method":"info","params":' + b'{"a":' * 100000 + b"1" + b"}" * 100001,
                 b"[" * 200000 + b"]" * 200000):
        connection._handle(data)
    assert sent == [{"id": None, "error": {"error": "WebRequestError", "message": "Malformed request: nested "
                                                                                  "deeper than the JSON reader allows"}}] * 2


def test_a_burst_of_clients_is_queued_while_the_server_is_busy(tmp_path):
    # The server stopped (SIGSTOP) stands for a busy loop: every connection waits in the listen
    # backlog. asyncio's default backlog (100) refused the 101st with EAGAIN.
    socket_path = tmp_path / "klippy.sock"
    server = start_serve(printer_config(tmp_path), socket_path, tmp_path / "serve.log")
    clients, refused = [], 0
    try:
        os.kill(server.pid, signal.SIGSTOP)
        try:
            for _ in range(300):
                client = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
                client.setblocking(False)
                try:
                    client.connect(str(socket_path))
                    clients.append(client)
                except BlockingIOError:
                    refused += 1
                    client.close()
        finally:
            os.kill(server.pid, signal.SIGCONT)
        assert (len(clients), refused) == (300, 0)
        answered = KlippyClient(socket_path)
        assert answered.call("info")["result"]["state"] == "ready"
        answered.close()
    finally:
        for client in clients:
            client.close()
        server.send_signal(signal.SIGTERM)
        server.wait(timeout=STOP_TIMEOUT_S)
