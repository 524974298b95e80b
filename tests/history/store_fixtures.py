"""Store fixtures: the same tests on a SQLite file and on a real PostgreSQL (temp cluster).

A plain module imported by the test file, not a conftest.py: tests/api's modules import their
helpers with `from conftest import ...`, which a second conftest.py loaded after theirs (as
`pytest tests/api tests/history` does) would shadow."""

from __future__ import annotations

import itertools
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the bench package beside tests/
from bench._postgres import Cluster, ClusterUnavailable  # noqa: E402  (after the path)
from api.real_packages import unavailable  # noqa: E402

_names = itertools.count()


@pytest.fixture(scope="session")
def pg_cluster():
    try:
        cluster = Cluster()
        cluster.start()
    except ClusterUnavailable as exc:
        unavailable(str(exc))
    try:
        yield cluster
    finally:
        cluster.stop()


@pytest.fixture(params=["sqlite", "postgresql"])
def store_url(request, tmp_path):
    """An empty database's URL, on each backend."""
    if request.param == "sqlite":
        return f"sqlite:///{tmp_path / 'taps.db'}"
    cluster = request.getfixturevalue("pg_cluster")
    return cluster.new_database(f"store_{next(_names)}")
