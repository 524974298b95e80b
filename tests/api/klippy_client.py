"""A minimal client of Klipper's API socket for the tests: 0x03-framed JSON, every read bounded."""

from __future__ import annotations

import json
import socket
import time

TIMEOUT_S = 30.0


def strict_loads(text: bytes):
    """json.loads that refuses NaN and infinity (as msgspec, Moonraker's parser, does)."""
    def refuse(name):
        raise ValueError(f"non-strict JSON constant {name}")
    return json.loads(text, parse_constant=refuse)


class KlippyClient:
    def __init__(self, path, timeout_s: float = TIMEOUT_S):
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.sock.settimeout(timeout_s)
        self.sock.connect(str(path))
        self.buffer = b""
        self.pushes: list[dict] = []
        self.next_id = 1

    def close(self) -> None:
        self.sock.close()

    def send_raw(self, data: bytes) -> None:
        self.sock.sendall(data)

    def send(self, message: dict) -> None:
        self.send_raw(json.dumps(message).encode() + b"\x03")

    def receive(self, timeout_s: float = TIMEOUT_S) -> dict | None:
        """The next message; None when the server closed the connection."""
        deadline = time.monotonic() + timeout_s
        while b"\x03" not in self.buffer:
            self.sock.settimeout(max(deadline - time.monotonic(), 0.001))
            chunk = self.sock.recv(1 << 20)
            if not chunk:
                return None
            self.buffer += chunk
        message, _, self.buffer = self.buffer.partition(b"\x03")
        return strict_loads(message)

    def reply_to(self, request_id, timeout_s: float = TIMEOUT_S) -> dict | None:
        """The reply with this id (pushes met meanwhile are kept in .pushes); None if closed."""
        while True:
            message = self.receive(timeout_s)
            if message is None or ("id" in message and message["id"] == request_id
                                   and ("result" in message or "error" in message)):
                return message
            self.pushes.append(message)

    def call(self, method: str, timeout_s: float = TIMEOUT_S, **params) -> dict | None:
        request_id = self.next_id
        self.next_id += 1
        self.send({"id": request_id, "method": method, "params": params})
        return self.reply_to(request_id, timeout_s)

    def push(self, until, timeout_s: float = TIMEOUT_S) -> dict:
        """The first push (kept or new) for which until(push) is true."""
        for index, message in enumerate(self.pushes):
            if until(message):
                return self.pushes.pop(index)
        deadline = time.monotonic() + timeout_s
        while True:
            message = self.receive(max(deadline - time.monotonic(), 0.001))
            if message is None:
                raise ConnectionError("the server closed the connection")
            if until(message):
                return message
            self.pushes.append(message)
