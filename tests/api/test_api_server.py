"""`tapcell serve` on its socket, as any Klipper API client sees it: framing and ids, objects
with Klipper's types, subscriptions, answers while a script runs, streams, bad input,
emergency stop and restart. Needs nothing but tapcell."""

from __future__ import annotations

import time

import pytest

from conftest import printer_config, start_serve, stop
from klippy_client import KlippyClient


@pytest.fixture
def client(served):
    connection = KlippyClient(served)
    yield connection
    connection.close()


def test_ids_are_echoed_exactly_and_may_be_reused(client):
    for request_id in (140285261356816, 140285261356816, "abc", 1.5, None):
        client.send({"id": request_id, "method": "info", "params": {}})
        reply = client.reply_to(request_id)
        assert reply["id"] == request_id and type(reply["id"]) is type(request_id)
        assert reply["result"]["state"] == "ready"


def test_objects_have_klippers_names_and_types(client):
    names = client.call("objects/list")["result"]["objects"]
    for required in ("webhooks", "print_stats", "configfile", "heaters", "extruder", "heater_bed", "toolhead",
                     "gcode_move", "virtual_sdcard", "display_status", "pause_resume", "load_cell_probe", "probe",
                     "bed_mesh"):
        assert required in names
    status = client.call("objects/query", objects={name: None for name in names})["result"]["status"]
    assert isinstance(status["extruder"]["temperature"], float) and isinstance(status["extruder"]["power"], float)
    assert status["heater_bed"]["target"] == 0.0 and status["heater_bed"]["temperature"] == 25.0
    assert status["heaters"]["available_heaters"] == ["heater_bed", "extruder"]
    assert status["toolhead"]["extruder"] == "extruder" and isinstance(status["toolhead"]["homed_axes"], str)
    assert len(status["toolhead"]["position"]) == 4 and len(status["gcode_move"]["gcode_position"]) == 4
    assert status["print_stats"]["state"] == "standby" and status["print_stats"]["info"]["current_layer"] is None
    assert status["pause_resume"] == {"is_paused": False}
    assert status["probe"]["last_probe_position"] == [0.0, 0.0, 0.0]
    assert status["bed_mesh"]["probed_matrix"] == [[]] and status["bed_mesh"]["profiles"] == {}
    settings = status["configfile"]["settings"]
    assert settings["bed_mesh"]["probe_count"] == [7, 7] and settings["load_cell_probe"]["trigger_force"] == 75
    assert status["configfile"]["config"]["load_cell_probe"]["sensor_type"] == "hx717"
    assert status["webhooks"] == {"state": "ready", "state_message": "Printer is ready"}
    unknown = client.call("objects/query", objects={"no_such_object": None, "toolhead": ["no_such_field"]})
    assert unknown["result"]["status"] == {"no_such_object": {}, "toolhead": {}}


def test_subscription_pushes_only_changed_fields_with_eventtime(served, client):
    reply = client.call("objects/subscribe", objects={"toolhead": ["position", "homed_axes"], "webhooks": None},
                        response_template={"method": "process_status_update"})
    first = reply["result"]
    assert isinstance(first["eventtime"], float) and first["status"]["webhooks"]["state"] == "ready"
    mover = KlippyClient(served)
    try:
        assert mover.call("gcode/script", script="G28\nG1 X42 Y17 Z5 F6000")["result"] == {}
    finally:
        mover.close()
    push = client.push(lambda m: m.get("method") == "process_status_update"
                       and m["params"]["status"].get("toolhead", {}).get("position", [None])[0] == pytest.approx(42.0))
    assert set(push["params"]) == {"eventtime", "status"}
    assert set(push["params"]["status"]) == {"toolhead"}  # webhooks did not change
    assert push["params"]["status"]["toolhead"]["position"][:3] == pytest.approx([42.0, 17.0, 5.0])


def test_api_answers_while_a_script_runs(served):
    # Ordered by events on one connection, not by the clock (a sleep-based version failed on a
    # faster machine): the query is sent once the script has printed its first probe, and its
    # reply must come before the script's, with more of the script's output after it.
    worker = KlippyClient(served)
    try:
        worker.send({"id": "out", "method": "gcode/subscribe_output",
                     "params": {"response_template": {"method": "output"}}})
        assert "result" in worker.reply_to("out")
        worker.send({"id": "mesh", "method": "gcode/script",
                     "params": {"script": "G28\nPROBE_ACCURACY SAMPLES=20\nPROBE_ACCURACY SAMPLES=20"}})
        while not any("probe at" in push["params"]["response"] for push in worker.pushes):
            message = worker.receive()
            assert message is not None and message.get("id") != "mesh", message
            worker.pushes.append(message)
        worker.send({"id": "query", "method": "objects/query", "params": {"objects": {"webhooks": None}}})
        order = []
        while "mesh" not in order:
            message = worker.receive(timeout_s=120.0)
            assert message is not None
            order.append(message.get("id") or "output")
            if message.get("id") == "query":
                assert message["result"]["status"]["webhooks"]["state"] == "ready"
            if message.get("id") == "mesh":
                assert message["result"] == {}
    finally:
        worker.close()
    # The query was answered while the script ran: its reply, then more output, then the script's reply.
    assert order.index("query") < len(order) - 1 and "output" in order[order.index("query") + 1:-1]


def test_gcode_errors_reply_and_echo_like_klipper(client):
    assert client.call("gcode/subscribe_output", response_template={"method": "out"})["result"] == {}
    reply = client.call("gcode/script", script="G28\nG1 X999")
    assert reply["error"]["error"] == "WebRequestError"
    assert reply["error"]["message"].startswith("Move out of range")
    lines = [m["params"]["response"] for m in client.pushes if m.get("method") == "out"]
    assert lines[-1] == "!! " + reply["error"]["message"].split("\n")[0]
    helped = client.call("gcode/help")["result"]
    assert "PROBE" in helped and "FIRMWARE_RESTART" in helped and "PAUSE" in helped


def test_pause_resume_and_display_message(client):
    assert client.call("pause_resume/pause")["result"] == {}
    assert client.call("objects/query", objects={"pause_resume": None})["result"]["status"]["pause_resume"] == {
        "is_paused": True}
    assert client.call("pause_resume/resume")["result"] == {}
    assert client.call("gcode/script", script="M117 Probing the bed")["result"] == {}
    status = client.call("objects/query", objects={"pause_resume": None, "display_status": ["message"]})
    assert status["result"]["status"] == {"pause_resume": {"is_paused": False},
                                          "display_status": {"message": "Probing the bed"}}


def test_dump_force_header_then_batches_of_rows(client):
    reply = client.call("load_cell/dump_force", load_cell="load_cell_probe", response_template={"method": "force"})
    assert reply["result"] == {"header": ["time", "force (g)", "counts", "tare_counts"]}
    batches = [client.push(lambda m: m.get("method") == "force")["params"] for _ in range(3)]
    rows = [row for batch in batches for row in batch["data"]]
    assert all(set(batch) == {"data", "errors", "overflows"} for batch in batches)
    assert all(len(row) == 4 for row in rows) and len(rows) > 10
    times = [row[0] for row in rows]
    assert all(b > a for a, b in zip(times, times[1:]))
    # The nozzle rests in the air: a calibrated cell reads near 0 g.
    assert max(abs(row[1]) for row in rows) < 20.0
    wrong = client.call("load_cell/dump_force", load_cell="nope")
    assert "not valid for load_cell" in wrong["error"]["message"]
    missing = client.call("load_cell_probe/dump_taps")
    assert missing["error"]["message"] == "Missing Argument [load_cell_probe]"


def test_bad_input_gets_an_error_or_a_closed_connection_and_others_are_served(served, client):
    client.send_raw(b"{not json\x03")
    assert "not JSON" in client.receive()["error"]["message"]
    assert client.call("no/such/method")["error"]["message"] == "No registered callback for path 'no/such/method'"
    assert client.call("gcode/script", script=5)["error"]["message"] == "Invalid Argument Type [script]"
    assert "Invalid Argument Type" in client.call("objects/query", objects=[])["error"]["message"]
    client.send_raw(b"[1, 2]\x03")
    assert "expected a JSON object" in client.receive()["error"]["message"]
    # A client that vanishes in the middle of a stream.
    vanishing = KlippyClient(served)
    vanishing.call("load_cell/dump_force", load_cell="load_cell_probe")
    vanishing.sock.close()
    # A message past the size limit closes only its own connection.
    flooding = KlippyClient(served)
    try:
        flooding.send_raw(b"[" + b" " * (9 * 1024 * 1024))
        assert "Message too long" in flooding.receive()["error"]["message"]
        assert flooding.receive() is None
    except (BrokenPipeError, ConnectionResetError):
        pass  # closed while we were still sending: also a closed connection
    finally:
        flooding.close()
    time.sleep(0.3)
    assert client.call("info")["result"]["state"] == "ready"


def test_emergency_stop_shuts_down_and_firmware_restart_closes_connections(tmp_path):
    socket_path = tmp_path / "klippy.sock"
    process = start_serve(printer_config(tmp_path), socket_path, tmp_path / "serve.log")
    try:
        watcher, other = KlippyClient(socket_path), KlippyClient(socket_path)
        watcher.call("objects/subscribe", objects={"webhooks": None}, response_template={"method": "status"})
        assert watcher.call("emergency_stop")["result"] == {}
        push = watcher.push(lambda m: m.get("method") == "status")
        assert push["params"]["status"]["webhooks"]["state"] == "shutdown"
        assert push["params"]["status"]["webhooks"]["state_message"].startswith("Shutdown due to webhooks request")
        refused = other.call("gcode/script", script="G28")
        assert refused["error"]["message"].startswith("Shutdown due to webhooks request")
        assert other.call("info")["result"]["state"] == "shutdown"
        # FIRMWARE_RESTART closes every connection without a reply, as Klipper does.
        assert other.call("gcode/firmware_restart", timeout_s=60.0) is None
        while watcher.receive(timeout_s=10.0) is not None:  # pushes sent before the close may come first
            pass
        again = KlippyClient(socket_path)
        assert again.call("info")["result"]["state"] == "ready"
        assert again.call("gcode/script", script="M112")["result"] == {}
        assert again.call("info")["result"]["state_message"].startswith("Shutdown due to M112 command")
        again.close()
    finally:
        stop(process)
