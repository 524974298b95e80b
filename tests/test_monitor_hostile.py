"""Issue 20: `tapcell monitor` against a server that sends what it should not. Each bad message is
skipped with one line, the valid tap after it is still logged; a mistyped host gives up; the
outputs are checked before connecting. A fake websocket replaces Moonraker (in-process)."""

from __future__ import annotations

import argparse
import copy
import json
import socket
from pathlib import Path

import pytest

from tapcell.tap import tap_to_json_dict
from tapcell.tap.synth import synth_tap
from tapcell.tools import monitor as monitor_module
from tapcell.tools.monitor import MAX_TAP_SAMPLES, monitor

SETTINGS = {"load_cell_probe": {"trigger_force": 75, "pullback_distance": 0.15}}


def tap_event() -> dict:
    """A dump_taps push as Klipper-family hosts send it: the tap with the printer's result."""
    tap = tap_to_json_dict(synth_tap())
    tap.update(tap_pos=[110.0, 110.0, 0.012], is_valid=True, error=None)
    return {"tap": tap}


class FakeSocket:
    """Answers the handshake, then sends `pushes` (texts) one per recv; then times out."""

    def __init__(self, pushes: list[str], query_result=None):
        self.pushes = list(pushes)
        self.replies: list[str] = []
        self.query_result = {"status": {"configfile": {"settings": SETTINGS}}} if query_result is None \
            else query_result

    def send(self, text: str) -> None:
        request = json.loads(text)
        result = self.query_result if request["method"] == "objects/query" else {"header": ["probe_tap_event"]}
        self.replies.append(json.dumps({"id": request["id"], "result": result}))

    def recv(self, timeout: float):
        if self.replies:
            return self.replies.pop(0)
        if self.pushes:
            return self.pushes.pop(0)
        raise TimeoutError

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


class Said:
    def __init__(self):
        self.lines: list[str] = []
        self.rows = []

    def say(self, message: str) -> None:
        self.lines.append(message)

    def add(self, row) -> None:
        self.rows.append(row)


def run(tmp_path, pushes, query_result=None, count=1):
    log = tmp_path / "taps.jsonl"
    args = argparse.Namespace(moonraker="http://printer:7125", probe="load_cell_probe", log=str(log),
                              plot_dir=None, count=count, force=False, set=[])
    said = Said()
    connections = []

    def connect(url, **kwargs):
        connections.append(kwargs)
        return FakeSocket(pushes, query_result)

    status = monitor(args, said, connect)
    lines = log.read_text().splitlines() if log.exists() else []
    return status, said, lines, connections


def push(event) -> str:
    return json.dumps({"params": event}, allow_nan=True)


def bad_taps() -> dict[str, tuple[str, str]]:
    """mode -> (the push text, the start of the one line the monitor says)."""
    def changed(**fields):
        event = tap_event()
        event["tap"].update(fields)
        return push(event)

    n = len(tap_event()["tap"]["force"])
    return {
        "not_json": ("this is not json {", "tapcell monitor: skipped a message that is not JSON"),
        "array": ("[1, 2]", "tapcell monitor: skipped a message that is a JSON list, not an object"),
        "params_list": (json.dumps({"params": [1, 2]}), "tapcell monitor: skipped a push whose params are a list"),
        "tap_not_object": (json.dumps({"params": {"tap": 5}}), "tapcell monitor: tap 1 skipped: 'tap' is int"),
        "deep": ('{"params":{"tap":' + "[" * 100000 + "]" * 100000 + "}}",
                 "tapcell monitor: skipped a message that is not JSON (RecursionError"),
        "nan_force": (changed(force=[float("nan")] * n), "tapcell monitor: tap 1 skipped: "),
        "string_force": (changed(force=["x"] * n), "tapcell monitor: tap 1 skipped: "),
        "moves_garbage": (changed(moves=[{"print_time": "x"}] * 5), "tapcell monitor: tap 1 skipped: "),
        "too_many_samples": (changed(time=[k * 1e-4 for k in range(MAX_TAP_SAMPLES + 1)]),
                             f"tapcell monitor: tap 1 skipped: {MAX_TAP_SAMPLES + 1:,} samples, more than"),
    }


@pytest.mark.parametrize("mode", list(bad_taps()))
def test_a_bad_message_is_skipped_with_one_line_and_the_next_tap_is_logged(tmp_path, mode):
    text, said_first = bad_taps()[mode]
    good = push(tap_event())
    status, said, lines, connections = run(tmp_path, [text, good, good], count=2)
    assert status == 0 and len(connections) == 1
    assert said.lines[0].startswith("tapcell monitor: connected to")
    assert said.lines[1].startswith(said_first), said.lines
    assert len([line for line in said.lines if "skipped" in line]) == 1
    logged = [json.loads(line) for line in lines]
    assert [entry["printer"]["z"] for entry in logged] == [0.012] * (len(logged))
    assert len(logged) in (1, 2)  # the bad one counted as a tap (then skipped) or not a tap at all


@pytest.mark.parametrize("field, value, warning", [
    ("tap_pos", [float("nan"), 1.0, float("nan")], "tap_pos [nan, 1.0, nan] is not [x, y, z] in numbers"),
    ("tap_pos", ["a", "b", "c"], "tap_pos ['a', 'b', 'c'] is not [x, y, z] in numbers"),
    ("tap_pos", [1.0], "tap_pos [1.0] is not [x, y, z] in numbers"),
    ("is_valid", "yes", "is_valid 'yes' is not true/false"),
    ("error", "not a dict", "error 'not a dict' is not an object"),
])
def test_a_malformed_printer_result_is_ignored_and_tapcells_is_kept(tmp_path, field, value, warning):
    event = tap_event()
    event["tap"][field] = value
    status, said, lines, _ = run(tmp_path, [push(event)])
    assert status == 0
    assert said.lines[1] == f"tapcell monitor: tap 1: the printer's {warning}: ignored"
    logged = json.loads(lines[0])
    assert logged["printer"][field if field != "tap_pos" else "tap_pos"] is None
    assert logged["analysis"]["z"] == pytest.approx(said.rows[0].tapcell_z_mm)


@pytest.mark.parametrize("result, message", [
    ({"status": None}, "the status in the result of objects/query is NoneType, not an object"),
    ({"nope": 1}, "the status in the result of objects/query is NoneType, not an object"),
    ([1, 2, 3], "the result of objects/query is list, not an object"),
    ({"status": {"configfile": {"settings": "x"}}}, "configfile.settings is str, not an object"),
])
def test_a_handshake_reply_that_makes_no_sense_ends_with_a_message(tmp_path, result, message):
    status, said, lines, connections = run(tmp_path, [], query_result=result)
    assert status == 2 and len(connections) == 1 and lines == []
    assert said.lines == [f"tapcell monitor: ws://printer:7125/klippysocket does not answer as Klipper's API "
                          f"through Moonraker does: {message}"]


def test_settings_the_analysis_refuses_are_left_at_their_defaults(tmp_path):
    result = {"status": {"configfile": {"settings": {"load_cell_probe": {
        "trigger_force": float("nan"), "min_tap_quality": 1e308}}}}}
    status, said, lines, _ = run(tmp_path, [push(tap_event())], query_result=result)
    assert status == 0 and len(lines) == 1
    assert said.lines[0].startswith("tapcell monitor: the printer's trigger_force = nan is not usable (")
    assert said.lines[1].startswith("tapcell monitor: the printer's min_tap_quality = 1e+308 is not usable (")


def test_a_large_tap_up_to_the_servers_limit_is_taken(tmp_path):
    connections = run(tmp_path, [push(tap_event())])[3]
    assert connections[0]["max_size"] == monitor_module.MAX_MESSAGE_BYTES == 64 * 1024 * 1024


def _name_not_resolved():
    return socket.gaierror(socket.EAI_NONAME, "Name or service not known")


def _message_too_big():
    from websockets.exceptions import ConnectionClosedError
    from websockets.frames import Close

    return ConnectionClosedError(None, Close(1009, "message too big"))  # we closed the link: too big


@pytest.mark.parametrize("failure, problem, last_words", [
    (_name_not_resolved, "the host of ws://printr.lcoal:7125/klippysocket does not resolve (Name or service not known)",
     "check the name in --moonraker"),
    (_message_too_big, "the server sent a message over 67,108,864 bytes (the limit)", "giving up"),
])
def test_a_link_that_keeps_failing_the_same_way_gives_up_after_3_tries(monkeypatch, failure, problem, last_words):
    monkeypatch.setattr(monitor_module, "RECONNECT_S", 0.0)
    args = argparse.Namespace(moonraker="http://printr.lcoal:7125", probe="load_cell_probe", log=None,
                              plot_dir=None, count=1, force=False, set=[])
    tries = []

    def connect(url, **kwargs):
        tries.append(url)
        raise failure()

    said = Said()
    assert monitor(args, said, connect) == 2
    assert len(tries) == monitor_module.NAME_RETRIES == monitor_module.OVERSIZE_RETRIES == 3
    assert said.lines == [f"tapcell monitor: {problem}; trying again in 0 s"] * 2 + [
        f"tapcell monitor: {problem}, 3 times in a row: {last_words}"]


def test_outputs_that_cannot_be_written_are_refused_before_connecting(tmp_path, capsys):
    (tmp_path / "afile").write_text("x")
    for extra, message in ((["--log", str(tmp_path)], f"--log {tmp_path} is a directory"),
                           (["--plot-dir", str(tmp_path / "afile" / "plots")],
                            f"--plot-dir {tmp_path / 'afile' / 'plots'} cannot be made a folder (Not a directory)")):
        status = monitor_module.main(["--moonraker", "http://127.0.0.1:9", *extra])
        assert (status, capsys.readouterr().err) == (2, f"tapcell monitor: {message}\n")
