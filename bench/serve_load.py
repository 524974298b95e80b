"""`tapcell serve` under load: does one client that reads stay served while others never read?

The load (issue 20): 50 clients, 20 of which never read (each with a 4 kB receive buffer,
subscribed to the 2,000 sps dump_force stream and to the status, and asking for the config
every 50 ms without reading the replies); 29 that read everything they get (the same
subscriptions); one well-behaved client that measures the round trip of an `objects/query`
every 0.2 s; and a BED_MESH_CALIBRATE running the whole time. The anchor is the same
client's latency and the server's RSS with nobody else connected, measured in the same run.

Printed: the latency (median, 95th percentile, worst) and the server's RSS in each phase,
its peak RSS (VmHWM), the RSS after the non-readers left, and how many clients the server
dropped. Bounded means: the peak within the idle RSS plus the server's budget for unsent
bytes (api_server.MAX_TOTAL_UNSENT_BYTES) plus 100 MB, and the loaded 95th percentile under
250 ms (a UI refresh; the idle one is about a millisecond).
"""

from __future__ import annotations

import argparse
import json
import re
import selectors
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from rich.console import Console
from rich.table import Table

from tapcell.host.api_server import MAX_TOTAL_UNSENT_BYTES

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "virtual-printer.cfg"
FAST_CELL = "sensor_type: ads1220\ncs_pin: PA4\ndata_ready_pin: PA3\nsample_rate: 2000\n"
CALIBRATION = "counts_per_gram: 110\nreference_tare_counts: -38000\n"
STATUS_OBJECTS = ("toolhead", "load_cell_probe", "bed_mesh", "webhooks", "print_stats")
LATENCY_BOUND_MS = 250.0
RSS_MARGIN_MB = 100.0
START_TIMEOUT_S = 120.0


def server_config(folder: Path) -> Path:
    """The example printer with a 2,000 sps cell, calibrated."""
    text = EXAMPLE.read_text()
    old_cell = "sensor_type: hx717\nsclk_pin: PA5\ndout_pin: PA4\nsample_rate: 320\n"
    if old_cell not in text:
        raise SystemExit("bench/serve_load: the example's [load_cell_probe] changed; update FAST_CELL")
    text = text.replace(old_cell, FAST_CELL).replace("z_offset: 0\n", "z_offset: 0\n" + CALIBRATION, 1)
    path = folder / "printer.cfg"
    path.write_text(text)
    return path


def memory_mb(pid: int) -> tuple[float, float]:
    """(VmRSS, VmHWM) of the process, in MB."""
    with open(f"/proc/{pid}/status") as status:
        text = status.read()
    return tuple(int(re.search(rf"{key}:\s+(\d+)", text).group(1)) / 1024.0 for key in ("VmRSS", "VmHWM"))


class Client:
    """A Klipper API connection (0x03-framed JSON) with bounded waits."""

    def __init__(self, path: Path, receive_buffer: int | None = None):
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        if receive_buffer is not None:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, receive_buffer)
        self.sock.settimeout(30.0)
        self.sock.connect(str(path))
        self.buffer = b""
        self.next_id = 0

    def send(self, method: str, params: dict) -> int:
        self.next_id += 1
        self.sock.sendall(json.dumps({"id": self.next_id, "method": method, "params": params}).encode() + b"\x03")
        return self.next_id

    def call(self, method: str, params: dict) -> dict:
        request_id = self.send(method, params)
        while True:
            while b"\x03" not in self.buffer:
                chunk = self.sock.recv(1 << 16)
                if not chunk:
                    raise ConnectionError("the server closed the connection")
                self.buffer += chunk
            message, _, self.buffer = self.buffer.partition(b"\x03")
            reply = json.loads(message)
            if reply.get("id") == request_id:
                return reply

    def subscribe_all(self) -> None:
        self.call("load_cell/dump_force", {"load_cell": "load_cell_probe", "response_template": {"method": "f"}})
        self.call("objects/subscribe", {"objects": {name: None for name in STATUS_OBJECTS},
                                        "response_template": {"method": "s"}})

    def close(self) -> None:
        self.sock.close()


class Drain(threading.Thread):
    """Reads everything the reading clients get, on one thread."""

    def __init__(self, clients: list[Client]):
        super().__init__(daemon=True)
        self.selector = selectors.DefaultSelector()
        for client in clients:
            client.sock.setblocking(False)
            self.selector.register(client.sock, selectors.EVENT_READ)
        self.stop = threading.Event()
        self.bytes = 0

    def run(self) -> None:
        while not self.stop.is_set():
            for key, _ in self.selector.select(timeout=0.1):
                try:
                    chunk = key.fileobj.recv(1 << 20)
                except (BlockingIOError, ConnectionError):
                    continue
                if not chunk:
                    self.selector.unregister(key.fileobj)
                self.bytes += len(chunk)


class Hog(threading.Thread):
    """The non-readers: ask for the config every `period_s` and never read a reply."""

    def __init__(self, clients: list[Client], period_s: float):
        super().__init__(daemon=True)
        self.clients, self.period_s = clients, period_s
        self.stop = threading.Event()
        self.refused = 0  # sends that failed: the server dropped that client

    def run(self) -> None:
        alive = list(self.clients)
        while alive and not self.stop.wait(self.period_s):
            for client in list(alive):
                try:
                    client.sock.setblocking(False)
                    client.send("objects/query", {"objects": {"configfile": None}})
                except (BlockingIOError, ConnectionError, OSError):
                    self.refused += 1
                    alive.remove(client)


def latencies_ms(client: Client, seconds: float, period_s: float, server_pid: int,
                 memory: list[float]) -> list[float]:
    """The round trip of objects/query every period_s for `seconds`; the server's RSS into `memory`."""
    samples = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        start = time.perf_counter()
        reply = client.call("objects/query", {"objects": {"toolhead": ["position"]}})
        samples.append((time.perf_counter() - start) * 1000.0)
        if "result" not in reply:
            raise SystemExit(f"bench/serve_load: the query failed: {reply}")
        memory.append(memory_mb(server_pid)[0])
        time.sleep(period_s)
    return samples


def summary(samples: list[float]) -> tuple[float, float, float]:
    ordered = sorted(samples)
    return statistics.median(ordered), ordered[int(0.95 * (len(ordered) - 1))], ordered[-1]


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="bench/serve_load.py", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=60.0, help="length of the loaded phase (default 60)")
    parser.add_argument("--clients", type=int, default=50, help="clients in all (default 50)")
    parser.add_argument("--non-readers", type=int, default=20, help="of which never read (default 20)")
    parser.add_argument("--hog-period", type=float, default=0.05,
                        help="seconds between a non-reader's unread config queries (default 0.05)")
    args = parser.parse_args(argv)
    readers_count = args.clients - args.non_readers - 1
    if readers_count < 0:
        parser.error("--clients must be more than --non-readers")
    console = Console()
    with tempfile.TemporaryDirectory(prefix="tapcell-serve-load-") as workdir:
        folder = Path(workdir)
        socket_path = folder / "klippy.sock"
        stderr_path = folder / "serve.stderr"
        with stderr_path.open("wb") as stderr:
            server = subprocess.Popen([sys.executable, "-m", "tapcell", "serve", "--config",
                                       str(server_config(folder)), "--socket", str(socket_path)],
                                      stdout=subprocess.DEVNULL, stderr=stderr)
        try:
            return _run(args, console, server, socket_path, stderr_path, readers_count)
        finally:
            if server.poll() is None:
                server.terminate()
                server.wait(timeout=30)


def _run(args, console, server, socket_path, stderr_path, readers_count) -> int:
    deadline = time.monotonic() + START_TIMEOUT_S
    while not socket_path.exists():
        if server.poll() is not None or time.monotonic() > deadline:
            raise SystemExit(f"bench/serve_load: tapcell serve did not start: {stderr_path.read_text()[-400:]}")
        time.sleep(0.1)
    good = Client(socket_path)
    good.call("gcode/script", {"script": "G28"})
    idle_memory: list[float] = []
    idle = latencies_ms(good, min(10.0, args.seconds / 3), 0.2, server.pid, idle_memory)
    idle_rss = statistics.median(idle_memory)

    readers = [Client(socket_path) for _ in range(readers_count)]
    hogs = [Client(socket_path, receive_buffer=4096) for _ in range(args.non_readers)]
    for client in (*readers, *hogs):
        client.subscribe_all()
    drain = Drain(readers)
    drain.start()
    hog = Hog(hogs, args.hog_period)
    hog.start()
    mesher = Client(socket_path)
    mesh_id = mesher.send("gcode/script", {"script": "BED_MESH_CALIBRATE"})
    loaded_memory: list[float] = []
    loaded = latencies_ms(good, args.seconds, 0.2, server.pid, loaded_memory)
    peak_mb = memory_mb(server.pid)[1]

    hog.stop.set()
    hog.join()
    for client in hogs:
        client.close()
    after_memory: list[float] = []
    after = latencies_ms(good, min(10.0, args.seconds / 3), 0.2, server.pid, after_memory)
    drain.stop.set()
    drain.join()
    mesher.sock.settimeout(600.0)
    mesh_reply = mesher.call("objects/query", {"objects": {"bed_mesh": ["profile_name"]}})  # after the mesh
    dropped = stderr_path.read_text().count("stopped reading")
    tracebacks = stderr_path.read_text().count("Traceback")

    table = Table(title=f"tapcell serve under load: {args.clients} clients, {args.non_readers} never read, "
                        f"dump_force at 2,000 sps, BED_MESH_CALIBRATE running")
    for column in ("phase", "query latency ms (median / p95 / worst)", "p95 vs idle", "server RSS MB (median)"):
        table.add_column(column, justify="right")
    anchor = summary(idle)[1]
    for name, samples, memory in (("idle (1 client)", idle, idle_memory), ("loaded", loaded, loaded_memory),
                                  ("non-readers gone", after, after_memory)):
        median, p95, worst = summary(samples)
        table.add_row(name, f"{median:.1f} / {p95:.1f} / {worst:.1f}", f"{p95 / anchor:.1f}x",
                      f"{statistics.median(memory):.0f}")
    console.print(table)
    bound_mb = idle_rss + MAX_TOTAL_UNSENT_BYTES / 2**20 + RSS_MARGIN_MB
    loaded_p95 = summary(loaded)[1]
    print(f"peak RSS {peak_mb:.0f} MB (bound: idle {idle_rss:.0f} + unsent budget "
          f"{MAX_TOTAL_UNSENT_BYTES / 2**20:.0f} + {RSS_MARGIN_MB:.0f} = {bound_mb:.0f} MB); RSS after the "
          f"non-readers left {statistics.median(after_memory[-5:]):.0f} MB; clients dropped by the server: "
          f"{dropped} of {args.non_readers}; readers received {drain.bytes / 2**20:.0f} MB; "
          f"tracebacks: {tracebacks}")
    print(f"mesh: {'ran' if 'result' in mesh_reply else 'FAILED'} (request {mesh_id}); "
          f"loaded p95 {loaded_p95:.1f} ms (bound {LATENCY_BOUND_MS:.0f} ms)")
    bounded = peak_mb <= bound_mb and loaded_p95 <= LATENCY_BOUND_MS and tracebacks == 0
    print("bounded: " + ("yes" if bounded else "NO"))
    good.close()
    mesher.close()
    for client in readers:
        client.close()
    return 0 if bounded else 1


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
