"""`tapcell serve` behind the real Moonraker (pinned, own venv), on 127.0.0.1 with a free port.

What a Moonraker user sees: Klippy ready, our objects over HTTP, G-code with its output as
websocket notifications, the taps through the /klippysocket bridge, RESTART reconnecting,
and `tapcell monitor` logging a tap with both results.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
import urllib.parse

import pytest
from websockets.sync.client import connect

from conftest import wait_for

WS_TIMEOUT_S = 30.0


def ws_messages(websocket, until, timeout_s: float = WS_TIMEOUT_S) -> list[dict]:
    """Messages from the websocket until until(message) is true (fails after timeout_s)."""
    seen = []
    deadline = time.monotonic() + timeout_s
    while True:
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            pytest.fail(f"no awaited message within {timeout_s:g} s; got {[str(m)[:120] for m in seen]}")
        message = json.loads(websocket.recv(timeout=remaining))
        seen.append(message)
        if until(message):
            return seen


def script(stack, text: str) -> tuple[int, dict]:
    return stack.get("/printer/gcode/script?script=" + urllib.parse.quote(text), timeout_s=120.0)


def test_moonraker_reaches_ready_with_no_missing_requirements(stack):
    status, body = stack.get("/server/info")
    assert status == 200
    info = body["result"]
    assert info["klippy_connected"] is True and info["klippy_state"] == "ready"
    assert info["missing_klippy_requirements"] == []
    status, body = stack.get("/printer/info")
    assert status == 200
    assert body["result"]["state"] == "ready"
    assert body["result"]["software_version"].startswith("tapcell ")


def test_objects_query_returns_our_load_cell_probe_fields(stack):
    status, body = stack.get("/printer/objects/query?load_cell_probe&probe=name,last_z_result&heaters")
    assert status == 200
    objects = body["result"]["status"]
    probe_cell = objects["load_cell_probe"]
    assert probe_cell["is_calibrated"] is True
    assert probe_cell["counts_per_gram"] == 110.0
    assert probe_cell["reference_tare_counts"] == -38000
    assert probe_cell["trigger_force"] == 75.0
    assert isinstance(probe_cell["force_g"], float)
    assert objects["probe"] == {"name": "load_cell_probe", "last_z_result": 0.0}
    assert objects["heaters"]["available_sensors"] == ["heater_bed", "extruder"]


def test_gcode_script_returns_and_its_lines_arrive_as_notify_gcode_response(stack):
    with connect(f"ws://127.0.0.1:{stack.port}/websocket", open_timeout=10) as websocket:
        websocket.send(json.dumps({"jsonrpc": "2.0", "id": 1, "method": "server.connection.identify",
                                   "params": {"client_name": "tapcell-test", "version": "0", "type": "web",
                                              "url": "http://localhost"}}))
        ws_messages(websocket, lambda m: m.get("id") == 1)
        status, body = script(stack, "G28\nPROBE")
        assert status == 200 and body["result"] == "ok"
        lines = [m["params"][0] for m in ws_messages(
            websocket, lambda m: m.get("method") == "notify_gcode_response" and "Result is z=" in m["params"][0])
            if m.get("method") == "notify_gcode_response"]
    probe_line = next(line for line in lines if line.startswith("// probe at"))
    z_printed = float(probe_line.rsplit("z=", 1)[1])
    _, body = stack.get("/printer/objects/query?probe=last_z_result")
    assert body["result"]["status"]["probe"]["last_z_result"] == pytest.approx(z_printed, abs=1e-6)
    # The bed is at Z 0 within the virtual printer's tilt and the probe's accuracy.
    assert abs(z_printed) < 0.2


def test_gcode_error_is_http_400_with_klippers_message(stack):
    status, body = script(stack, "NO_SUCH_COMMAND")
    assert status == 400
    assert body["error"]["message"] == 'Unknown command:"NO_SUCH_COMMAND"'


def test_klippysocket_bridge_receives_the_tap_of_the_next_probe(stack):
    with connect(f"ws://127.0.0.1:{stack.port}/klippysocket", open_timeout=10) as bridge:
        bridge.send(json.dumps({"id": 7, "method": "load_cell_probe/dump_taps",
                                "params": {"load_cell_probe": "load_cell_probe", "response_template": {}}}))
        header = ws_messages(bridge, lambda m: m.get("id") == 7)[-1]
        assert header["result"] == {"header": ["probe_tap_event"]}
        status, _ = script(stack, "G28\nG1 X60 Y80 F6000\nPROBE")
        assert status == 200
        event = ws_messages(bridge, lambda m: "tap" in m.get("params", {}))[-1]["params"]["tap"]
    _, body = stack.get("/printer/objects/query?probe=last_z_result")
    assert event["is_valid"] is True and event["error"] is None
    assert event["tap_pos"][:2] == pytest.approx([60.0, 80.0], abs=1e-6)
    assert event["tap_pos"][2] == pytest.approx(body["result"]["status"]["probe"]["last_z_result"], abs=1e-9)
    assert event["time"][0] == 0.0 and len(event["time"]) == len(event["force"]) > 100
    assert len(event["tap_points"]) == 6 and len(event["tap_lines"]) == 5
    assert 0 < event["home_end_time"] < event["pullback_start_time"] < event["pullback_end_time"]
    assert {"print_time", "move_t", "start_v", "accel", "start_z", "z_r", "x_r"} <= set(event["moves"][0])


def test_monitor_logs_the_next_tap_with_both_z_values(stack, tmp_path):
    log, said = tmp_path / "taps.jsonl", tmp_path / "monitor.stderr"
    with said.open("w") as stderr:
        monitor = subprocess.Popen(
            [sys.executable, "-m", "tapcell", "monitor", "--moonraker", stack.url, "--count", "1", "--log", str(log),
             "--plot-dir", str(tmp_path / "plots")], stdout=subprocess.PIPE, stderr=stderr, text=True)
    try:
        wait_for(lambda: "waiting for taps" in said.read_text(), 60.0, "the monitor to subscribe", monitor)
        status, _ = script(stack, "G28\nG1 X150 Y120 F6000\nPROBE")
        assert status == 200
        out, _ = monitor.communicate(timeout=60.0)
    finally:
        if monitor.poll() is None:
            monitor.kill()
            monitor.wait(timeout=10)
    assert monitor.returncode == 0, said.read_text()
    lines = log.read_text().splitlines()
    assert len(lines) == 1
    entry = json.loads(lines[0])
    _, body = stack.get("/printer/objects/query?probe=last_z_result")
    printer_z = body["result"]["status"]["probe"]["last_z_result"]
    assert entry["format"] == "tapcell.tap.v1"
    assert entry["printer"]["z"] == pytest.approx(printer_z, abs=1e-9)
    assert entry["printer"]["is_valid"] is True and entry["analysis"]["valid"] is True
    # Same samples, same engine, the printer's own settings: the same Z.
    assert entry["analysis"]["z"] == pytest.approx(printer_z, abs=1e-6)
    table_row = out.strip().splitlines()[-1].split("\t")
    assert table_row[0] == "1" and table_row[6] == "valid/valid"
    assert (tmp_path / "plots" / "tap-0001.png").stat().st_size > 10_000


def test_restart_makes_moonraker_reconnect(stack):
    with connect(f"ws://127.0.0.1:{stack.port}/websocket", open_timeout=10) as websocket:
        status, body = stack.get("/printer/restart", method="POST")  # Moonraker sends RESTART; the host closes the socket
        assert status == 200, body
        events = ws_messages(websocket, lambda m: m.get("method") == "notify_klippy_ready")
    methods = [m.get("method") for m in events]
    assert "notify_klippy_disconnected" in methods
    assert methods.index("notify_klippy_disconnected") < methods.index("notify_klippy_ready")
    stack.wait_ready()


def test_monitor_says_so_and_reconnects_when_the_printer_restarts(stack, tmp_path):
    log, said = tmp_path / "taps.jsonl", tmp_path / "monitor.stderr"
    with said.open("w") as stderr:
        monitor = subprocess.Popen(
            [sys.executable, "-m", "tapcell", "monitor", "--moonraker", stack.url, "--count", "2", "--log", str(log)],
            stdout=subprocess.DEVNULL, stderr=stderr)
    try:
        wait_for(lambda: said.read_text().count("waiting for taps") == 1, 60.0, "the monitor to subscribe", monitor)
        assert script(stack, "G28\nPROBE")[0] == 200
        wait_for(log.exists, 30.0, "the first tap in the log", monitor)
        assert stack.get("/printer/restart", method="POST")[0] == 200
        stack.wait_ready()
        wait_for(lambda: said.read_text().count("waiting for taps") == 2, 60.0, "the monitor to reconnect", monitor)
        assert script(stack, "G28\nPROBE")[0] == 200
        assert monitor.wait(timeout=60.0) == 0
    finally:
        if monitor.poll() is None:
            monitor.kill()
            monitor.wait(timeout=10)
    assert "lost or refused" in said.read_text() and "reconnecting" in said.read_text()
    assert [json.loads(line)["analysis"]["valid"] for line in log.read_text().splitlines()] == [True, True]


def test_m112_from_mainsail_through_moonraker_stops_a_running_mesh(stack):
    """Mainsail's console sends M112 over Moonraker's websocket (printer.gcode.script) while
    BED_MESH_CALIBRATE runs (issue 19: it used to wait behind the mesh, which was then applied
    and answered "ok")."""
    def rpc(request_id: int, method: str, **params) -> None:
        websocket.send(json.dumps({"jsonrpc": "2.0", "id": request_id, "method": method, "params": params}))

    with connect(f"ws://127.0.0.1:{stack.port}/websocket", open_timeout=10) as websocket:
        rpc(1, "server.connection.identify", client_name="tapcell-test", version="0", type="web",
            url="http://localhost")
        ws_messages(websocket, lambda m: m.get("id") == 1)
        rpc(2, "printer.gcode.script", script="G28\nBED_MESH_CALIBRATE")
        probed = []
        ws_messages(websocket, lambda m: m.get("method") == "notify_gcode_response"
                    and m["params"][0].startswith("// probe at") and probed.append(m) is None and len(probed) == 3,
                    timeout_s=120.0)
        rpc(3, "printer.gcode.script", script="M112")
        replies = {}
        ws_messages(websocket, lambda m: m.get("id") in (2, 3) and replies.update({m["id"]: m}) is None
                    and len(replies) == 2, timeout_s=120.0)
    assert replies[3]["result"] == "ok"
    assert replies[2]["error"]["message"].startswith("Shutdown due to M112 command")
    _, query = stack.get("/printer/objects/query?bed_mesh=profile_name")
    assert query["result"]["status"]["bed_mesh"]["profile_name"] == ""
    wait_for(lambda: stack.klippy_state() == "shutdown", 30.0, "Moonraker to see the shutdown", stack.moonraker)
    assert stack.get("/printer/firmware_restart", method="POST")[0] == 200
    stack.wait_ready()
