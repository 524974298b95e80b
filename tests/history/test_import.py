"""`tapcell import`: monitor logs keep their logged results, tap files are analysed, a second
import adds nothing, a broken file is named with its line."""

from __future__ import annotations

import json

from tapcell.store import Store
from tapcell.tap import analyze_tap
from tapcell.tap.readers import tap_to_json_dict
from tapcell.tools.cli import main as tapcell


def _log_line(seed: int, source: str) -> dict:
    from tapcell.tap.synth import synth_tap

    tap = synth_tap(seed=seed, z_contact_mm=0.05)
    document = tap_to_json_dict(tap, analyze_tap(tap))
    document["printer"] = {"z": 0.0512, "tap_pos": [30.0, 40.0, 0.0512], "is_valid": False,
                           "error": {"error_code": "TAP_PULLBACK_TOO_SHORT", "message": "short"}}
    document["meta"]["monitor_source"] = source
    return document


def test_import_loads_logs_and_tap_files_once(tmp_path, capsys):
    from tapcell.tap.synth import synth_tap

    log = tmp_path / "taps.jsonl"
    lines = [_log_line(seed, "http://voron.local:7125") for seed in (1, 2)]
    lines[1]["analysis"]["z"] = 0.0499  # a logged result is kept as logged, not recomputed
    log.write_text("".join(json.dumps(line) + "\n" for line in lines))
    tap_file = tmp_path / "one.json"
    tap_file.write_text(json.dumps(tap_to_json_dict(synth_tap(seed=9, z_contact_mm=0.2))))
    db = f"sqlite:///{tmp_path / 'taps.db'}"

    assert tapcell(["import", "--db", db, str(log), str(tap_file)]) == 0
    out = capsys.readouterr().out
    assert f"{log}: 2 taps added to printer 'http://voron.local:7125'" in out
    assert f"{tap_file}: 1 taps added to printer 'imported'" in out
    assert tapcell(["import", "--db", db, str(log)]) == 0
    assert f"{log}: 0 taps added to printer 'http://voron.local:7125', 2 already stored" in capsys.readouterr().out

    with Store(db) as store:
        voron = store.printer("http://voron.local:7125")["id"]
        rows = sorted(store.taps(voron), key=lambda row: row["id"])
        imported = store.taps(store.printer("imported")["id"])
    assert [row["tapcell_z_mm"] for row in rows][1] == 0.0499
    assert rows[0]["printer_error"] == "TAP_PULLBACK_TOO_SHORT"
    assert rows[0]["cause"] == "printer: TAP_PULLBACK_TOO_SHORT - short"
    assert abs(imported[0]["tapcell_z_mm"] - 0.2) < 0.005  # analysed on import


def test_a_broken_line_is_named_and_the_rest_still_imports(tmp_path, capsys):
    bad = tmp_path / "bad.jsonl"
    bad.write_text(json.dumps(_log_line(3, "x")) + "\n{not json\n")
    good = tmp_path / "good.jsonl"
    good.write_text(json.dumps(_log_line(4, "x")) + "\n")
    db = str(tmp_path / "taps.db")
    assert tapcell(["import", "--db", db, "--printer", "p", str(bad), str(good)]) == 1
    captured = capsys.readouterr()
    assert f"tapcell import: {bad}: line 2: not JSON" in captured.err
    assert f"{good}: 1 taps added to printer 'p'" in captured.out


def test_import_into_a_foreign_database_says_so(tmp_path, capsys):
    import sqlite3

    path = tmp_path / "moonraker.db"
    with sqlite3.connect(path) as connection:
        connection.execute("CREATE TABLE job_history (id INTEGER)")
    assert tapcell(["import", "--db", str(path), str(tmp_path)]) == 2
    assert "not a tapcell store (it holds other tables: job_history)" in capsys.readouterr().err
