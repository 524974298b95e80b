"""Every reader, and clear errors that name the file and the problem."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tapcell.tap import TapFileError, analyze_tap, read_tap_file, readers, tap_to_json_dict
from tapcell.tap.readers import tap_from_object
from tapcell.tap.synth import synth_tap


@pytest.fixture
def tap():
    return synth_tap(seed=7)


def test_json_round_trip_keeps_everything(tmp_path, tap):
    path = tmp_path / "tap.json"
    path.write_text(json.dumps(tap_to_json_dict(tap, analyze_tap(tap))))
    (read,) = read_tap_file(path)
    assert np.array_equal(read.time_s, tap.time_s) and np.array_equal(read.force_g, tap.force_g)
    assert read.moves == tap.moves
    assert read.truth == {"z_contact": 0.0, "label": "clean"}
    assert read.sample_rate_sps == 660.0
    assert read.meta["sensor_integration_s"] == pytest.approx(1 / 660)
    assert analyze_tap(read).z_mm == analyze_tap(tap).z_mm


def test_jsonl_holds_many_taps(tmp_path):
    taps = [synth_tap(seed=s) for s in range(3)]
    path = tmp_path / "taps.jsonl"
    path.write_text("\n".join(json.dumps(tap_to_json_dict(t)) for t in taps) + "\n")
    read = read_tap_file(path)
    assert len(read) == 3
    assert [r.meta["seed"] for r in read] == [0, 1, 2]


def test_csv_with_extra_columns(tmp_path, tap):
    lines = ["Time,force,counts,z"] + [f"{float(t)!r},{float(f)!r},0,{float(z)!r}" for t, f, z in zip(tap.time_s, tap.force_g, tap.z_mm)]
    path = tmp_path / "tap.csv"
    path.write_text("\n".join(lines))
    (read,) = read_tap_file(path)
    assert read.moves == [] and np.array_equal(read.z_mm, tap.z_mm)
    result = analyze_tap(read)
    with_moves = analyze_tap(tap)
    # The z trace gives the motion the moves give: the same Z (measured 0.4 µm from truth both ways,
    # the toe model on a contact with no toe).
    assert result.valid and abs(result.z_mm - with_moves.z_mm) * 1000 < 0.05


def test_dump_taps_event(tmp_path, tap):
    document = tap_to_json_dict(tap)
    event = {"tap": {"time": list(tap.time_s - tap.time_s[0]), "force": document["force"],
                     "moves": [dict(m, print_time=m["print_time"] - tap.time_s[0], start_x=1.0, start_y=2.0,
                                    x_r=0.0, y_r=0.0) for m in document["moves"]],
                     "home_end_time": 0.4, "pullback_start_time": 0.7, "pullback_end_time": 1.0,
                     "tap_points": [], "is_valid": True, "error": None}}
    path = tmp_path / "event.json"
    path.write_text(json.dumps(event))
    (read,) = read_tap_file(path)
    assert read.events["pullback_start_time"] == 0.7
    assert analyze_tap(read).z_mm == pytest.approx(analyze_tap(tap).z_mm, abs=1e-9)


def test_workbench_capture_with_positions(tmp_path, tap):
    document = {"time": list(tap.time_s), "force": list(tap.force_g),
                "position": [[10.0, 20.0, z] for z in tap.z_mm], "is_valid": True}
    path = tmp_path / "workbench.json"
    path.write_text(json.dumps(document))
    (read,) = read_tap_file(path)
    assert np.array_equal(read.z_mm, tap.z_mm)
    assert analyze_tap(read).valid


@pytest.mark.parametrize("document, problem", [
    ({"format": "tapcell.tap.v1", "force": [1.0] * 20, "z": [0.0] * 20}, "missing key 'time'"),
    ({"time": list(range(20)), "force": [1.0] * 19, "z": [0.0] * 20}, "'time' has 20 values but 'force' has 19"),
    ({"time": list(range(20)), "force": [1.0] * 20}, "needs 'z' or 'moves'"),
    ({"time": [0, 1, 1] + list(range(2, 19)), "force": [1.0] * 20, "z": [0.0] * 20}, "not strictly increasing"),
    ({"time": list(range(5)), "force": [1.0] * 5, "z": [0.0] * 5}, "5 samples, at least 12 needed"),
    ({"format": "other", "time": [], "force": []}, "unknown format 'other'"),
    ({"time": list(range(20)), "force": ["a"] * 20, "z": [0.0] * 20}, "'force' must be a list of numbers"),
    ({"time": list(range(20)), "force": [1.0] * 20, "moves": [{"print_time": 0}]}, "moves[0] lacks move_t"),
    ({"time": list(range(20)), "force": [[1.0, 2.0]] * 20, "z": [0.0] * 20}, "'force' must be a flat list of numbers"),
    ({"time": list(range(20)), "force": ["1.0"] * 20, "z": [0.0] * 20}, "'force' must be a list of numbers"),
    ({"time": list(range(20)), "force": [True] * 20, "z": [0.0] * 20}, "'force' must be a list of numbers"),
    ({"time": list(range(20)), "force": [10 ** 400] + [1.0] * 19, "z": [0.0] * 20},
     "not valid tap data: an integer with 401 digits (at most 20 allowed)"),
    ({"time": list(range(20)), "force": [1.0] * 20, "z": [0.0] * 20, "sample_rate": -(10 ** 400)},
     "not valid tap data: an integer with 401 digits (at most 20 allowed)"),
    ({"time": list(range(20)), "force": [1.0] * 20, "z": [0.0] * 20, "sample_rate": 0},
     "'sample_rate' must be positive"),
    ({"time": [0.01 * i for i in range(20)], "force": [1.0] * 20, "z": [0.0] * 20, "sample_rate": 1e300},
     "'sample_rate' 1e+300 disagrees with the samples' times (100 sps on average); allowed: within 2x"),
    ({"time": [0.01 * i for i in range(20)], "force": [1.0] * 20, "z": [0.0] * 20, "sample_rate": 49.9},
     "'sample_rate' 49.9 disagrees with the samples' times (100 sps on average)"),
])
def test_bad_files_name_the_file_and_problem(tmp_path, document, problem):
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(document))
    with pytest.raises(TapFileError) as caught:
        read_tap_file(path)
    assert str(path) in str(caught.value) and problem in str(caught.value)


def test_nan_invalid_json_and_bad_csv(tmp_path):
    nan = tmp_path / "nan.json"
    nan.write_text('{"time": [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11], "force": [NaN, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1], "z": [0,0,0,0,0,0,0,0,0,0,0,0]}')
    with pytest.raises(TapFileError, match=r"'force' holds NaN or infinity \(index 0\)"):
        read_tap_file(nan)
    broken = tmp_path / "broken.jsonl"
    broken.write_text('{"time": [1]}\n{not json\n')
    with pytest.raises(TapFileError, match="line 1: missing key 'force'"):
        read_tap_file(broken)
    csv_file = tmp_path / "t.csv"
    csv_file.write_text("time,force\n0,1\n")
    with pytest.raises(TapFileError, match="CSV header lacks column"):
        read_tap_file(csv_file)
    csv_file.write_text("time,force,z\n0,1,0\n1,2\n")
    with pytest.raises(TapFileError, match=r"CSV line 3: column 'z' is not a number \('<missing>'\)"):
        read_tap_file(csv_file)
    with pytest.raises(TapFileError, match="cannot read the file"):
        read_tap_file(tmp_path / "missing.json")


def _valid_document():
    return tap_to_json_dict(synth_tap(seed=3))


# Finding 9 of issue 10: hostile tap files gave a traceback or were accepted.
@pytest.mark.parametrize("name, text, problem", [
    ("nested.json", "[" * 100_000 + "]" * 100_000, "not valid tap data: JSON nested too deeply"),
    ("nested.jsonl", '{"time": ' + "[" * 100_000 + "]" * 100_000 + "}\n", "line 1: not valid tap data: JSON nested too deeply"),
    ("digits.json", '{"time": [' + "7" * 5001 + "]}", "not valid tap data: an integer with 5001 digits (at most 20 allowed)"),
    ("digits_meta.json", None, "not valid tap data: an integer with 400 digits"),
    ("list.json", None, "holds a JSON list; a .json tap file holds one object"),
    ("long_field.csv", 'time,force,z\n0,"' + "1" * 200_000 + '",0\n', "not a valid CSV file (field larger than field limit"),
])
def test_hostile_tap_files_give_a_tap_file_error(tmp_path, name, text, problem):
    if name == "digits_meta.json":
        document = _valid_document()
        document["probe"] = {"trigger_force": int("9" * 400)}
        text = json.dumps(document)
    elif name == "list.json":
        text = json.dumps([_valid_document()])
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(TapFileError) as caught:
        read_tap_file(path)
    assert str(caught.value).startswith(f"{path}: ") and problem in str(caught.value)


def test_devices_and_oversized_files_are_refused_without_reading_them(tmp_path, monkeypatch):
    with pytest.raises(TapFileError, match=r"^/dev/zero: is a character device, not a tap file$"):
        read_tap_file("/dev/zero")
    path = tmp_path / "big.json"
    path.write_text(json.dumps(_valid_document()))
    monkeypatch.setattr(readers, "MAX_FILE_BYTES", 16 * 1024)
    assert path.stat().st_size > readers.MAX_FILE_BYTES
    with pytest.raises(TapFileError, match=r"big.json: is larger than 16,384 bytes, not a tap file$"):
        read_tap_file(path)


def test_an_in_memory_integer_beyond_a_float_reads_as_infinity():
    document = tap_to_json_dict(synth_tap(seed=3))
    document["force"] = [10 ** 400] + document["force"][1:]
    with pytest.raises(TapFileError, match=r"^<memory>: 'force' holds NaN or infinity \(index 0\)$"):
        tap_from_object(document)


@pytest.mark.parametrize("change, message", [
    (lambda moves: moves.__setitem__(2, [1, 2]), "moves[2] must be an object"),
    (lambda moves: moves[3].pop("accel"), "moves[3] lacks accel"),
    (lambda moves: moves[1].__setitem__("start_v", True), "'moves[1].start_v' must be a finite number, got True"),
    (lambda moves: moves[4].__setitem__("start_z", "0.1"), "'moves[4].start_z' must be a finite number, got '0.1'"),
    (lambda moves: moves[0].__setitem__("move_t", float("nan")), "'moves[0].move_t' must be a finite number"),
    (lambda moves: moves[0].__setitem__("move_t", 10 ** 400), "'moves[0].move_t' must be a finite number"),
    (lambda moves: moves[3].__setitem__("start_z", float("-inf")), "'moves[3].start_z' must be a finite number, got -inf"),
    (lambda moves: (moves[1].__setitem__("accel", float("inf")), moves[2].__setitem__("accel", float("-inf"))),
     "'moves[1].accel' must be a finite number, got inf"),  # their sum is NaN
    (lambda moves: moves[2].__setitem__("move_t", -0.1), "moves[2]: start_v and move_t must be >= 0"),
])
def test_a_bad_move_is_named(tap, change, message):
    """Moves are converted all at once; any bad item is then found and named one by one."""
    document = tap_to_json_dict(tap)
    change(document["moves"])
    with pytest.raises(TapFileError, match=message.replace("[", r"\[").replace("]", r"\]").replace(".", r"\.")):
        tap_from_object(document, "tap.json")


def test_moves_whose_sum_overflows_are_read(tap):
    """The moves' finite check is their sum where that is finite; a sum beyond a float looks item by item."""
    document = tap_to_json_dict(tap)
    document["moves"][0]["accel"] = document["moves"][1]["accel"] = 1e308
    moves = tap_from_object(document).moves
    assert (moves[0].accel, moves[1].accel) == (1e308, 1e308) and moves[2:] == tap.moves[2:]


def test_integer_moves_read_as_floats(tap):
    document = tap_to_json_dict(tap)
    document["moves"][0]["z_r"] = -1
    moves = tap_from_object(document).moves
    assert moves[0].z_r == -1.0 and type(moves[0].z_r) is float
    assert moves[1:] == tap.moves[1:]


@pytest.mark.parametrize("name", ["a/b.json", "a//b.json", "./a.json", "a/./b.json", "a.json/", "//a.json", "///a.json",
                                  "a/.", ".", "..csv", ".csv", "a.", "a/../b.JSONL", "taps.tar.CSV"])
def test_file_names_and_kinds_are_spelled_as_pathlib_spells_them(name):
    # Messages name the file as pathlib spells it, and the kind comes from its suffix; the reader
    # only imports pathlib for names it would respell.
    from pathlib import Path

    assert readers._file_name(name) == str(Path(name))
    assert readers._suffix(readers._file_name(name)) == Path(name).suffix.lower()


def test_a_respelled_name_is_the_one_in_the_message(tmp_path):
    with pytest.raises(TapFileError, match=rf"^{tmp_path}/missing.json: cannot read the file"):
        read_tap_file(f"{tmp_path}//./missing.json")


@pytest.mark.parametrize("change, problem", [
    # All floats (the common path) and floats mixed with other items (the item-by-item path).
    (lambda force: force.__setitem__(5, float("inf")), "'force' holds NaN or infinity (index 5)"),
    (lambda force: force.__setitem__(7, 1), None),
    (lambda force: force.__setitem__(7, True), "'force' must be a list of numbers"),
    (lambda force: force.__setitem__(7, None), "'force' must be a list of numbers"),
    (lambda force: force.__setitem__(7, [1.0]), "'force' must be a flat list of numbers"),
])
def test_float_arrays_with_one_odd_item(tap, change, problem):
    document = tap_to_json_dict(tap)
    change(document["force"])
    if problem is None:
        assert np.array_equal(tap_from_object(document).force_g, np.array(document["force"], dtype=float))
        return
    with pytest.raises(TapFileError) as caught:
        tap_from_object(document, "tap.json")
    assert str(caught.value) == f"tap.json: {problem}"


@pytest.mark.parametrize("index, step_s", [(3, 0.0), (300, -1e-9), (300, -1.0)])
def test_the_first_time_not_after_the_one_before_is_named(tap, index, step_s):
    document = tap_to_json_dict(tap)
    time_s = document["time"]
    time_s[index] = time_s[index - 1] + step_s
    time_s[index + 5] = time_s[index + 4]  # a later one too: the first is named
    with pytest.raises(TapFileError) as caught:
        tap_from_object(document, "tap.json")
    assert str(caught.value) == (f"tap.json: 'time' is not strictly increasing "
                                 f"(index {index}: {time_s[index]!r} after {time_s[index - 1]!r})")


@pytest.mark.parametrize("text, empty", [("", True), (" \n\t\r", True), ("\u3000\u00a0\n", True), (" {} ", False),
                                         ("\n\n[]", False), ("\x00", False)])
def test_a_file_of_white_space_alone_is_empty(tmp_path, text, empty):
    """Empty as str.strip() sees it (Unicode white space too); anything else is read as JSON."""
    path = tmp_path / "tap.json"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(TapFileError) as problem:
        read_tap_file(path)
    assert ("the file is empty" in str(problem.value)) == empty


# cli_hostile's review list: a NaN event time and a 1 MB string for the probe's x were taken.
@pytest.mark.parametrize("where, key, value, problem", [
    ("events", "home_end_time", float("nan"), "'events.home_end_time' must be a finite number, got nan"),
    ("events", "pullback_end_time", "soon", "'events.pullback_end_time' must be a finite number, got 'soon'"),
    ("probe", "x", "a" * 1_000_000, "'probe.x' must be a finite number, got 'aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa... (1000002 characters)"),
    ("probe", "trigger_force", True, "'probe.trigger_force' must be a finite number, got True"),
    ("probe", "speed", [5.0], "'probe.speed' must be a finite number, got [5.0]"),
])
def test_a_known_event_or_probe_key_must_hold_a_number(tmp_path, where, key, value, problem):
    document = _valid_document()
    document.setdefault(where, {})[key] = value
    path = tmp_path / "tap.json"
    path.write_text(json.dumps(document))
    with pytest.raises(TapFileError) as caught:
        read_tap_file(path)
    assert str(caught.value) == f"{path}: {problem}"


def test_null_and_unknown_event_and_probe_keys_are_kept():
    document = _valid_document()
    document["events"] = {"home_end_time": None, "pullback_start_time": 2, "note": "by hand"}
    document["probe"] = {"pullback_speed": None, "x": 110, "nozzle": "0.4 mm"}
    tap = tap_from_object(document, "tap.json", "")
    assert tap.events == {"home_end_time": None, "pullback_start_time": 2.0, "note": "by hand"}
    assert tap.probe == {"pullback_speed": None, "x": 110.0, "nozzle": "0.4 mm"}
    assert isinstance(tap.probe["x"], float)
