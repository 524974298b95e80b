"""`tapcell web` refuses what it cannot show before it listens, with a message naming the store."""

from __future__ import annotations

import sqlite3

import pytest

from tapcell.tools.cli import main as tapcell


def test_web_refuses_a_missing_store_without_creating_it(tmp_path, capsys):
    path = tmp_path / "none.db"
    assert tapcell(["web", "--db", str(path), "--port", "7131"]) == 2
    assert f"tapcell web: {path}: no tap store there; tapcell monitor --db or tapcell import makes one" in \
        capsys.readouterr().err
    assert not path.exists()


def test_web_refuses_a_foreign_or_corrupt_database(tmp_path, capsys):
    foreign = tmp_path / "moonraker-sql.db"
    with sqlite3.connect(foreign) as connection:
        connection.execute("CREATE TABLE namespace_store (namespace TEXT)")
    assert tapcell(["web", "--db", str(foreign)]) == 2
    assert "not a tapcell store (it holds other tables: namespace_store)" in capsys.readouterr().err
    corrupt = tmp_path / "corrupt.db"
    corrupt.write_bytes(b"\x00garbage" * 1000)
    assert tapcell(["web", "--db", str(corrupt)]) == 2
    assert f"{corrupt}: cannot be read as a tapcell store: file is not a database" in capsys.readouterr().err


def test_web_refuses_a_bad_port(capsys):
    with pytest.raises(SystemExit) as exit_:
        tapcell(["web", "--port", "70000"])
    assert exit_.value.code == 2
    assert "--port: 70000 is not a port (1..65535)" in capsys.readouterr().err
