"""Store fixtures: the same tests on a SQLite file and on a real PostgreSQL (temp cluster)."""

from __future__ import annotations

import itertools

import pytest

from pg_cluster import Cluster

_names = itertools.count()


@pytest.fixture(scope="session")
def pg_cluster():
    cluster = Cluster()
    cluster.start()
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
