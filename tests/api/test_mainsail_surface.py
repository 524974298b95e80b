"""What Mainsail and Fluidd read, through the real Moonraker in front of `tapcell serve`: the live
position moving during a G1 (motion_report), the Endstops button (query_endstops/status), a file
uploaded to the gcodes folder printing to `complete` (virtual_sdcard, print_stats, job history),
and the line touchscreens wait for after a mesh."""

from __future__ import annotations

import json
import time
import urllib.error
import urllib.parse
import urllib.request

import pytest
from conftest import wait_for

from test_moonraker import script

PRINT_FILE = """\
; a small job, as a slicer writes it
SET_PRINT_STATS_INFO TOTAL_LAYER=2
G28 X Y
G1 X20 Y20 F6000
SET_PRINT_STATS_INFO CURRENT_LAYER=1
G1 X120 F6000
M205 X10 ; another firmware's command: reported and skipped, as Klipper does
SET_PRINT_STATS_INFO CURRENT_LAYER=2
G1 Y120 F6000
"""
MOVE_WAIT_S = 30.0


def query(stack, *objects: str) -> dict:
    status, body = stack.get("/printer/objects/query?" + "&".join(objects))
    assert status == 200, body
    return body["result"]["status"]


def test_objects_mainsail_reads_are_listed(stack):
    status, body = stack.get("/printer/objects/list")
    assert status == 200
    names = set(body["result"]["objects"])
    assert {"motion_report", "idle_timeout", "system_stats", "query_endstops", "virtual_sdcard",
            "print_stats"} <= names
    # Mainsail's and Fluidd's warning banners look for these in the config they are served.
    settings = query(stack, "configfile")["configfile"]["settings"]
    assert {"gcode_macro pause", "gcode_macro resume", "gcode_macro cancel_print", "virtual_sdcard",
            "pause_resume", "display_status"} <= set(settings)
    assert settings["virtual_sdcard"]["path"] == str(stack.data / "gcodes")
    stats = query(stack, "system_stats", "idle_timeout")
    assert set(stats["system_stats"]) == {"sysload", "cputime", "memavail"} and stats["system_stats"]["memavail"] > 0
    assert stats["idle_timeout"]["state"] in ("Idle", "Ready", "Printing")


def test_live_position_moves_during_a_g1_and_the_endstops_button_answers(stack):
    assert script(stack, "G28\nG1 Z5 F600\nG1 X10 Y10 F6000")[0] == 200
    # Wait until the homing and the travel have played out (the machine is Ready, not moving).
    wait_for(lambda: query(stack, "idle_timeout")["idle_timeout"]["state"] == "Ready", MOVE_WAIT_S,
             "the printer to finish its moves")
    report = query(stack, "motion_report")["motion_report"]
    assert report["live_position"][:2] == pytest.approx([10.0, 10.0], abs=1e-6) and report["live_velocity"] == 0.0
    assert script(stack, "G1 X210 F3000")[0] == 200  # 200 mm at 50 mm/s: 4 s of motion
    seen = []
    deadline = time.monotonic() + MOVE_WAIT_S
    while time.monotonic() < deadline:
        status = query(stack, "motion_report", "idle_timeout")
        seen.append((status["motion_report"]["live_position"][0], status["motion_report"]["live_velocity"],
                     status["idle_timeout"]["state"]))
        if abs(seen[-1][0] - 210.0) < 1e-6 and seen[-1][1] == 0.0:
            break
        time.sleep(0.2)
    moving = [(x, v, state) for x, v, state in seen if 15.0 < x < 205.0]
    assert moving, seen
    assert all(v == pytest.approx(50.0) and state == "Printing" for _, v, state in moving[1:-1]), moving  # cruising
    xs = [x for x, _, _ in seen]
    assert xs == sorted(xs) and seen[-1][:2] == pytest.approx((210.0, 0.0), abs=1e-6)
    # Mainsail's Endstops button: GET /printer/query_endstops/status.
    status, body = stack.get("/printer/query_endstops/status")
    assert status == 200 and body["result"] == {"x": "open", "y": "open", "z": "open"}
    assert script(stack, "G28 X")[0] == 200
    status, body = stack.get("/printer/query_endstops/status")
    assert status == 200 and body["result"] == {"x": "TRIGGERED", "y": "open", "z": "open"}


def upload(stack, name: str, text: str, start: bool) -> tuple[int, dict]:
    """Mainsail's upload: a multipart POST to /server/files/upload (print=true starts it)."""
    boundary = "tapcell-test-boundary"
    parts = [f'--{boundary}\r\nContent-Disposition: form-data; name="print"\r\n\r\n{str(start).lower()}\r\n',
             f'--{boundary}\r\nContent-Disposition: form-data; name="file"; filename="{name}"\r\n'
             f"Content-Type: application/octet-stream\r\n\r\n{text}\r\n", f"--{boundary}--\r\n"]
    request = urllib.request.Request(stack.url + "/server/files/upload", data="".join(parts).encode(), method="POST",
                                     headers={"Content-Type": f"multipart/form-data; boundary={boundary}"})
    try:
        with urllib.request.urlopen(request, timeout=30.0) as answer:
            return answer.status, json.loads(answer.read())
    except urllib.error.HTTPError as error:
        return error.code, json.loads(error.read() or b"{}")


def test_a_file_uploaded_as_mainsail_does_prints_to_complete(stack):
    status, body = upload(stack, "small job.gcode", PRINT_FILE, start=True)
    assert status in (200, 201), body
    assert body["print_started"] is True and (stack.data / "gcodes" / "small job.gcode").read_text() == PRINT_FILE
    states = []

    def complete():
        stats = query(stack, "print_stats", "virtual_sdcard")
        states.append(stats["print_stats"]["state"])
        return stats if states[-1] in ("complete", "error", "cancelled") else None

    stats = wait_for(complete, MOVE_WAIT_S, "the print to end")
    assert stats["print_stats"]["state"] == "complete", stats
    assert stats["print_stats"]["filename"] == "small job.gcode"
    assert stats["print_stats"]["info"] == {"total_layer": 2, "current_layer": 2}
    assert stats["print_stats"]["total_duration"] > 1.0  # the moves played in real time
    assert stats["virtual_sdcard"]["progress"] == 1.0 and stats["virtual_sdcard"]["is_active"] is False
    assert "printing" in states

    def last_job():  # Moonraker files the job when it sees the state change (its next status push)
        status, body = stack.get("/server/history/list?limit=1")
        job = body["result"]["jobs"][0] if status == 200 and body["result"]["jobs"] else {}
        return job if job.get("status") == "completed" else None

    job = wait_for(last_job, MOVE_WAIT_S, "Moonraker's history to file the job as completed")
    assert job["filename"] == "small job.gcode"


def test_a_finished_mesh_prints_mesh_bed_leveling_complete(stack):
    assert script(stack, "G28\nBED_MESH_CALIBRATE PROBE_COUNT=3,3")[0] == 200
    status, body = stack.get("/server/gcode_store?count=100")
    assert status == 200
    messages = [entry["message"] for entry in body["result"]["gcode_store"]]
    assert "// Mesh Bed Leveling Complete" in messages
    assert messages.index("// Mesh Bed Leveling Complete") > max(
        i for i, m in enumerate(messages) if m.startswith("// Probing 9 points"))
