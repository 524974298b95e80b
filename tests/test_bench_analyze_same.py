"""bench/analyze_same: the arguments of record and check, and what a record is named."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the bench package beside tests/

from bench import analyze_same  # noqa: E402  (after the path)


def test_settings_and_sets_in_any_order():
    assert analyze_same._settings_and_sets(["--set", "mains_hz=auto", "a", "--set=x=1", "b"]) == (
        ["mains_hz=auto", "x=1"], ["a", "b"])
    assert analyze_same._settings_and_sets(["a", "b"]) == ([], ["a", "b"])
    assert analyze_same._settings_and_sets(["--set", "mains_hz", "a"]) is None  # no KEY=VALUE
    assert analyze_same._settings_and_sets(["a", "--set"]) is None  # nothing after --set


def test_a_record_without_settings_keeps_its_old_name_and_settings_name_theirs():
    plain = analyze_same._record_name("/data/taps", "native")
    assert plain.startswith("taps-") and plain.endswith("-native.json") and plain.count("-") == 2
    auto = analyze_same._record_name("/data/taps", "native", ["mains_hz=auto"])
    assert auto == plain.replace("-native.json", "-mains_hz_auto-native.json")
    assert analyze_same._record_name("/data/taps", "twins", ["mains_hz=[50, 60]"]).endswith(
        "-mains_hz_50_60_-twins.json")


def test_the_usage_is_printed_for_a_bad_command_line(capsys):
    assert analyze_same.main(["record", "/tmp/x"]) == 2
    assert analyze_same.main(["check", "/tmp/x", "--set", "nokey", "set"]) == 2
    assert analyze_same.main(["check", "/tmp/x", "--set", "a=1"]) == 2  # settings but no set
    assert "--set KEY=VALUE" in capsys.readouterr().err


def test_settings_reach_tapcell_analyze(tmp_path, monkeypatch):
    calls = []

    class Run:
        stdout = b'[{"file": "x", "elapsed_ms": 1.5, "cpu_ms": 2.0}]\n'
        returncode = 0

    def fake_run(command, **_):
        calls.append(command)
        return Run()

    monkeypatch.setattr(analyze_same.subprocess, "run", fake_run)
    tap = tmp_path / "tap.json"
    tap.write_text("{}")
    assert analyze_same.main(["record", str(tmp_path / "rec"), "--set", "mains_hz=auto", str(tap)]) == 0
    assert all(command[1:5] == ["analyze", "--json", "--set", "mains_hz=auto"] for command in calls)
    assert len(calls) == 2  # kernels and twins
    recorded = (tmp_path / "rec" / analyze_same._record_name(str(tap), "native", ["mains_hz=auto"])).read_bytes()
    assert b'"elapsed_ms": -' in recorded and b"exit 0" in recorded
    assert analyze_same.main(["check", str(tmp_path / "rec"), "--set", "mains_hz=auto", str(tap)]) == 0
    # the same set checked without the settings has no record: a missing record is an error, not "same"
    assert analyze_same.main(["check", str(tmp_path / "rec"), str(tap)]) == 2


def test_a_misplaced_option_a_missing_set_or_record_is_named_before_anything_runs(tmp_path, capsys, monkeypatch):
    ran = []
    monkeypatch.setattr(analyze_same, "analyze_output", lambda *a, **k: ran.append(a) or b"")
    taps = tmp_path / "taps"
    taps.mkdir()
    (taps / "one.json").write_text("{}")
    # --set before the record folder: it is not taken for the folder (a traceback on 'mains_hz=auto' before)
    assert analyze_same.main(["check", "--set", "mains_hz=auto", str(tmp_path / "rec"), str(taps)]) == 2
    assert "'--set' where the record folder belongs" in capsys.readouterr().err
    assert analyze_same.main(["check", str(tmp_path / "rec"), str(tmp_path / "nowhere")]) == 2
    assert f"{tmp_path / 'nowhere'}: no such tap file or folder" in capsys.readouterr().err
    # a check whose record was made without these settings (or never): named, with how to make it
    assert analyze_same.main(["record", str(tmp_path / "rec"), str(taps)]) == 0
    assert analyze_same.main(["check", str(tmp_path / "rec"), "--set", "mains_hz=auto", str(taps)]) == 2
    err = capsys.readouterr().err
    assert "no record of" in err and "--set mains_hz=auto" in err and "`record` it first" in err
    assert len(ran) == 2  # the record's two runs (kernels, twins); no check ran
    assert analyze_same.main(["check", str(tmp_path / "rec"), str(taps)]) == 0


def test_a_check_names_the_taps_whose_lines_differ(tmp_path, capsys, monkeypatch):
    taps = tmp_path / "taps"
    taps.mkdir()
    for name in ("a", "b", "c"):
        (taps / f"{name}.json").write_text("{}")

    def output(z_of_b, status=0):
        lines = [f'{{"file": "{taps / name}.json", "z": {z}, "elapsed_ms": -}}'
                 for name, z in (("a", 0.01), ("b", z_of_b), ("c", 0.03))]
        return ("[\n" + ",\n".join(lines) + f"\n]\nexit {status}\n").encode()

    monkeypatch.setattr(analyze_same, "analyze_output", lambda *a, **k: output(0.02))
    assert analyze_same.main(["record", str(tmp_path / "rec"), str(taps)]) == 0
    monkeypatch.setattr(analyze_same, "analyze_output", lambda *a, **k: output(0.025))
    assert analyze_same.main(["check", str(tmp_path / "rec"), str(taps)]) == 1
    out = capsys.readouterr().out
    assert out.count("1 of 3 taps differ") == 2  # kernels and twins
    assert f"    {taps / 'b'}.json\n" in out and "a.json\n" not in out and "c.json\n" not in out
    assert "outside the taps' lines" not in out
    # the same taps, another exit status: no tap named, the line outside them shown
    monkeypatch.setattr(analyze_same, "analyze_output", lambda *a, **k: output(0.02, status=1))
    assert analyze_same.main(["check", str(tmp_path / "rec"), str(taps)]) == 1
    out = capsys.readouterr().out
    assert "0 of 3 taps differ" in out and "outside the taps' lines: exit 0" in out


def test_more_differing_taps_than_are_shown_are_counted(capsys):
    # 25 taps differ: the first SHOWN_DIFFERENCES (20) by name, in order, then how many more.
    before = b"[\n" + b"".join(b'{"file": "t%02d.json", "z": 1}\n' % i for i in range(30)) + b"]\n"
    now = before.replace(b'"z": 1}\n', b'"z": 2}\n', 25)
    analyze_same._print_differences(before, now)
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "  25 of 30 taps differ"
    assert [line.strip() for line in lines[1:21]] == [f"t{i:02d}.json" for i in range(20)]
    assert lines[21:] == ["    ... and 5 more"]
