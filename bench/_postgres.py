"""A throw-away PostgreSQL cluster on 127.0.0.1 for the store tests and `bench history`
(Debian's postgresql: initdb and pg_ctl on a free port, a temp data directory, trust auth on
loopback only, durability off: nothing in it outlives the run).

PostgreSQL refuses to run as root: run as root (CI, make test) the cluster runs as the
`postgres` system user the Debian package creates. What is missing raises ClusterUnavailable
with the reason (the tests skip or fail on it, the bench says it).
"""

from __future__ import annotations

import glob
import os
import pwd
import shutil
import socket
import subprocess
import tempfile
from pathlib import Path

SUPERUSER = "tapcell"
START_TIMEOUT_S = 60


def _binary(name: str) -> str | None:
    found = shutil.which(name)
    if found:
        return found
    candidates = sorted(glob.glob(f"/usr/lib/postgresql/*/bin/{name}"))
    return candidates[-1] if candidates else None


class ClusterUnavailable(Exception):
    """PostgreSQL cannot be started here; says why."""


def _unavailable(why: str):
    raise ClusterUnavailable(why)


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


class Cluster:
    def __init__(self):
        self.initdb, self.pg_ctl = _binary("initdb"), _binary("pg_ctl")
        if not (self.initdb and self.pg_ctl):
            _unavailable("PostgreSQL's initdb/pg_ctl are missing: 'make postgresql' installs Debian's postgresql")
        self.folder = Path(tempfile.mkdtemp(prefix="tapcell-pg-"))
        self.data = self.folder / "data"
        self.port = _free_port()
        self.user = None
        if os.geteuid() == 0:
            try:
                self.user = pwd.getpwnam("postgres").pw_name
            except KeyError:
                _unavailable("running as root and there is no 'postgres' user to run PostgreSQL as")
            shutil.chown(self.folder, self.user)
        self.url = f"postgresql://{SUPERUSER}@127.0.0.1:{self.port}/postgres"

    def _run(self, *command: str) -> None:
        result = subprocess.run(command, user=self.user, capture_output=True, text=True, timeout=START_TIMEOUT_S)
        if result.returncode != 0:
            _unavailable(f"{' '.join(command[:2])} failed: {result.stderr.strip()[-400:]}")

    def start(self, durable: bool = False) -> None:
        """Start it; durable=True keeps PostgreSQL's default fsync and commit (a farm's server, the bench)."""
        self._run(self.initdb, "-D", str(self.data), "-U", SUPERUSER, "--auth=trust", "-E", "UTF8",
                  "--locale=C", *([] if durable else ["--no-sync"]))
        options = f"-p {self.port} -h 127.0.0.1 -k {self.folder} -c max_connections=200 -c shared_buffers=128MB"
        if not durable:
            options += " -c fsync=off -c full_page_writes=off -c synchronous_commit=off"
        self._run(self.pg_ctl, "-D", str(self.data), "-l", str(self.folder / "server.log"), "-o", options,
                  "-w", "-t", str(START_TIMEOUT_S), "start")

    def stop(self) -> None:
        subprocess.run([self.pg_ctl, "-D", str(self.data), "-m", "immediate", "-w", "stop"], user=self.user,
                       capture_output=True, timeout=START_TIMEOUT_S)
        shutil.rmtree(self.folder, ignore_errors=True)

    def new_database(self, name: str) -> str:
        """An empty database; its URL."""
        import sqlalchemy as sa

        engine = sa.create_engine(self.url.replace("postgresql://", "postgresql+psycopg://"),
                                  isolation_level="AUTOCOMMIT")
        with engine.connect() as connection:
            connection.exec_driver_sql(f'DROP DATABASE IF EXISTS "{name}"')
            connection.exec_driver_sql(f'CREATE DATABASE "{name}"')
        engine.dispose()
        return self.url.rsplit("/", 1)[0] + "/" + name
