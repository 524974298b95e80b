"""What Mainsail and Fluidd read, through the real Moonraker in front of `tapcell serve`: the live
position moving during a G1 (motion_report), the Endstops button (query_endstops/status), a file
uploaded to the gcodes folder printing to `complete` (virtual_sdcard, print_stats, job history),
and the line touchscreens wait for after a mesh."""

from __future__ import annotations

import time
import urllib.parse

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


def test_a_file_in_the_gcodes_folder_prints_to_complete(stack):
    (stack.data / "gcodes" / "small job.gcode").write_text(PRINT_FILE)
    status, body = stack.get("/printer/print/start?filename=" + urllib.parse.quote("small job.gcode"),
                             method="POST")
    assert status == 200, body
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
