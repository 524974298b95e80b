"""The tap store on SQLite and on a real PostgreSQL: round trip, duplicates, concurrent
writers, migration from version 1, foreign/corrupt/newer databases, the fleet numbers."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import threading
import zlib

import numpy as np
import pytest
import sqlalchemy as sa

from tapcell.store import Store, StoreError
from tapcell.store import schema
from tapcell.store.records import tap_record
from tapcell.tap import analyze_tap
from tapcell.tap.readers import tap_to_json_dict
from tapcell.tap.synth import synth_tap

from store_fixtures import pg_cluster, store_url  # noqa: F401  (the fixtures)


def tap_document(seed: int, x_mm: float = 50.0, y_mm: float = 60.0, z_mm: float = 0.1, **printer) -> dict:
    tap = synth_tap(seed=seed, z_contact_mm=z_mm)
    document = tap_to_json_dict(tap, analyze_tap(tap))
    document["printer"] = {"z": z_mm + 0.002, "tap_pos": [x_mm, y_mm, z_mm + 0.002], "is_valid": True,
                           "error": None, **printer}
    return document


def test_a_tap_comes_back_whole_with_its_columns(store_url):
    document = tap_document(1, z_mm=0.123)
    with Store(store_url) as store:
        added = store.add_tap("voron", document, recorded_s=1000.0, settings={"trigger_force": 75.0})
        printer = store.printer("voron")
        row = store.tap(printer["id"], added.id)
    assert added.new
    assert row["document"] == document
    assert row["settings"] == {"trigger_force": 75.0}
    assert row["recorded_s"] == 1000.0
    assert (row["x_mm"], row["y_mm"]) == (50.0, 60.0)
    assert row["printer_z_mm"] == pytest.approx(0.125)
    assert row["tapcell_z_mm"] == pytest.approx(document["analysis"]["z"])
    assert abs(row["tapcell_z_mm"] - 0.123) < 0.005  # the analysis found the synthetic contact
    assert row["tapcell_valid"] is True and row["printer_valid"] is True and row["cause"] == ""
    assert row["noise_sigma_g"] == pytest.approx(document["analysis"]["noise_sigma_g"])


def test_a_rejected_tap_keeps_both_causes_and_filters(store_url):
    good = tap_document(2)
    bad = tap_document(3, is_valid=False, error={"error_code": "TAP_SHAPE_INVALID", "message": "no dwell"})
    with Store(store_url) as store:
        store.add_taps("prusa", [good, bad])
        printer_id = store.printer("prusa")["id"]
        rejected = store.taps(printer_id, status="rejected")
        valid = store.taps(printer_id, status="valid")
        by_cause = store.taps(printer_id, cause="TAP_SHAPE_INVALID")
        causes = store.causes(printer_id)
    assert [row["printer_error"] for row in rejected] == ["TAP_SHAPE_INVALID"]
    assert rejected[0]["cause"] == "printer: TAP_SHAPE_INVALID - no dwell"
    assert len(valid) == 1 and valid[0]["id"] != rejected[0]["id"]
    assert [row["id"] for row in by_cause] == [rejected[0]["id"]]
    assert causes == ["TAP_SHAPE_INVALID"]


def test_the_same_tap_twice_is_kept_once(store_url):
    document = tap_document(4)
    with Store(store_url) as store:
        first = store.add_tap("a", document)
        second = store.add_tap("a", json.loads(json.dumps(document)))
        other_printer = store.add_tap("b", document)
        count = len(store.taps(store.printer("a")["id"]))
    assert first.new and not second.new and second.id == first.id
    assert other_printer.new  # the key is per printer
    assert count == 1


def test_two_writers_on_one_printer_keep_each_tap_once(store_url):
    documents = [tap_document(seed) for seed in range(10, 22)]
    Store(store_url).close()  # made (and migrated) once, as a farm's first monitor does
    results: list = []

    def writer(order):
        with Store(store_url) as store:
            for document in order:
                results.append(store.add_tap("shared", document))

    threads = [threading.Thread(target=writer, args=(documents,)),
               threading.Thread(target=writer, args=(documents[::-1],))]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=60)
    with Store(store_url) as store:
        stored = store.taps(store.printer("shared")["id"], limit=100)
    assert len(results) == 24
    assert sum(added.new for added in results) == 12
    assert len(stored) == 12


def test_a_version_1_store_is_migrated_and_keeps_its_taps(store_url):
    engine = sa.create_engine(store_url.replace("postgresql://", "postgresql+psycopg://"))
    original = tap_document(5)
    record = tap_record(original, 500.0)
    with engine.begin() as connection:
        schema.MIGRATIONS[0](connection)
        connection.execute(schema.schema_version.update().values(version=1))
        connection.execute(sa.text("INSERT INTO printers (id, name, url, created_s) VALUES (1, 'old', '', 1.0)"))
        columns = record.columns()
        names = ", ".join(columns)
        connection.execute(sa.text(f"INSERT INTO taps (printer_id, {names}) VALUES (1, "
                                   + ", ".join(f":{name}" for name in columns) + ")"), columns)
    engine.dispose()
    with Store(store_url) as store:
        assert store.version() == schema.CURRENT_VERSION == 2
        rows = store.taps(1)
        kept = store.tap(1, rows[0]["id"])
        added = store.add_tap("old", tap_document(6), settings={"trigger_force": 60.0})
    assert len(rows) == 1 and rows[0]["settings_id"] is None
    assert kept["document"] == original
    assert added.new


def test_a_foreign_database_is_refused_by_name(store_url):
    engine = sa.create_engine(store_url.replace("postgresql://", "postgresql+psycopg://"))
    with engine.begin() as connection:
        connection.exec_driver_sql("CREATE TABLE jobs (id INTEGER PRIMARY KEY, filename TEXT)")
    engine.dispose()
    with pytest.raises(StoreError, match=r"not a tapcell store \(it holds other tables: jobs\)"):
        Store(store_url)


def test_a_store_from_a_newer_tapcell_is_refused(store_url):
    Store(store_url).close()
    engine = sa.create_engine(store_url.replace("postgresql://", "postgresql+psycopg://"))
    with engine.begin() as connection:
        connection.execute(schema.schema_version.update().values(version=99))
    engine.dispose()
    with pytest.raises(StoreError, match="schema version 99, written by a newer tapcell"):
        Store(store_url)


def test_a_corrupt_sqlite_file_is_refused_naming_the_file(tmp_path):
    path = tmp_path / "taps.db"
    path.write_bytes(b"this is not a database, it is a tap log\n" * 200)
    with pytest.raises(StoreError) as caught:
        Store(str(path))
    assert str(path) in str(caught.value)
    assert "cannot be read as a tapcell store: file is not a database" in str(caught.value)


def test_the_viewer_does_not_create_a_missing_store(tmp_path):
    with pytest.raises(StoreError, match="no tap store there"):
        Store(str(tmp_path / "none.db"), create=False)
    assert not (tmp_path / "none.db").exists()


def test_a_bad_url_is_refused_clearly():
    with pytest.raises(StoreError, match="unsupported database 'mysql'"):
        Store("mysql://user@host/db")


def test_fleet_numbers_match_the_taps(store_url):
    # Two spots, three taps each, with known Z: the pooled within-spot sigma is exact.
    z_by_spot = {(10.0, 10.0): [0.100, 0.102, 0.104], (100.0, 100.0): [0.200, 0.201, 0.202]}
    documents = []
    seed = 30
    for (x, y), zs in z_by_spot.items():
        for z in zs:
            document = tap_document(seed, x, y)
            document["analysis"]["z"] = z
            documents.append(document)
            seed += 1
    documents.append(tap_document(seed, 150.0, 150.0, is_valid=False,
                                  error={"error_code": "TAP_SHAPE_INVALID", "message": "x"}))
    with Store(store_url) as store:
        store.add_taps("p", documents, recorded_s=10.0)
        [row] = store.fleet()
    expected_um = math.sqrt((0.002**2 * 2 + 0.001**2 * 2) / 4) * 1000.0  # sum of squares / (n - groups)
    assert row["repeatability_um"] == pytest.approx(expected_um, rel=1e-9)
    assert row["rejection_rate"] == pytest.approx(1 / 7)
    assert row["taps"] == 7 and row["window"] == 7
    noise = sorted(d["analysis"]["noise_sigma_g"] for d in documents)
    assert row["noise_sigma_g"] == pytest.approx(noise[3])
    assert not row["flagged"]  # too few taps for the change test
    assert all(trend["t"] is None for trend in row["trends"])


def test_meshes_are_kept_once_per_content(store_url):
    status = {"profile_name": "default", "mesh_min": [10.0, 20.0], "mesh_max": [210.0, 220.0],
              "probed_matrix": [[0.01, 0.02, 0.03], [0.0, -0.01, -0.02]]}
    with Store(store_url) as store:
        first = store.add_mesh("m", status, recorded_s=1.0)
        again = store.add_mesh("m", status, recorded_s=2.0)
        none = store.add_mesh("m", {"profile_name": "", "probed_matrix": [[]], "mesh_min": [0, 0], "mesh_max": [0, 0]})
        [mesh] = store.meshes(store.printer("m")["id"])
    assert first.new and not again.new and none is None
    assert mesh["matrix"] == [[0.01, 0.02, 0.03], [0.0, -0.01, -0.02]]
    assert (mesh["x_min_mm"], mesh["y_max_mm"], mesh["profile"]) == (10.0, 220.0, "default")


KILLED_WRITER = """
import sys
from tapcell.store import Store
from tapcell.tap import analyze_tap
from tapcell.tap.readers import tap_to_json_dict
from tapcell.tap.synth import synth_tap
tap = synth_tap(seed=1)
document = tap_to_json_dict(tap, analyze_tap(tap))
store = Store(sys.argv[1])
print("ready", flush=True)
for n in range(100000):
    document["force"][0] = float(n)  # a new tap each time
    store.add_tap("killed", document)
"""


def test_a_killed_writer_leaves_only_whole_taps(tmp_path):
    url = f"sqlite:///{tmp_path / 'taps.db'}"
    writer = subprocess.Popen([sys.executable, "-c", KILLED_WRITER, url], stdout=subprocess.PIPE, text=True)
    assert writer.stdout.readline().strip() == "ready"
    with Store(url) as store:  # kill once some taps are in
        deadline_rows = 0
        for _ in range(600):
            printer = store.printer("killed")
            if printer and len(store.taps(printer["id"], limit=30)) >= 30:
                deadline_rows = 30
                break
            threading.Event().wait(0.05)
    os.kill(writer.pid, signal.SIGKILL)
    writer.wait(timeout=10)
    assert deadline_rows == 30
    with Store(url) as store:
        printer_id = store.printer("killed")["id"]
        rows = store.taps(printer_id, limit=100000)
        forces = sorted(store.tap(printer_id, row["id"])["document"]["force"][0] for row in rows)
    assert forces == [float(n) for n in range(len(rows))]  # whole taps, in order, none half-written


def test_stored_document_is_compressed_json():
    document = tap_document(7)
    record = tap_record(document, 1.0)
    assert json.loads(zlib.decompress(record.document)) == document
    assert len(record.document) < len(json.dumps(document)) / 2
    assert np.isfinite(record.tapcell_z_mm)
