"""The tap store: one SQLite file or a PostgreSQL database, through SQLAlchemy Core.

Every write is one transaction (a tap with its printer and settings rows, or a mesh): a killed
writer loses at most the tap in flight and a reader never sees half of one. The same tap seen
twice (two monitors on one printer, an import run twice) is kept once: taps are keyed by a
digest of their samples and inserted with ON CONFLICT DO NOTHING.

On SQLite the store runs in WAL mode (readers go on while a monitor writes) and every write
transaction starts with BEGIN IMMEDIATE, so two writers queue on the busy timeout instead of
failing when one upgrades its read lock.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass
from pathlib import Path
import sqlalchemy as sa
from sqlalchemy import event
from sqlalchemy.engine import Connection, Engine
from sqlalchemy.exc import ArgumentError, DBAPIError, NoSuchModuleError

from . import health, schema
from .records import MeshRecord, RecordError, TapRecord, mesh_record, settings_key, tap_document, tap_record

SQLITE_BUSY_TIMEOUT_MS = 30_000
FLEET_WINDOW_TAPS = health.RECENT_TAPS + health.BASELINE_TAPS
TAP_COLUMNS = [column for column in schema.taps.c if column.name != "document"]


class StoreError(Exception):
    """The store cannot be opened or used; the message names the database and the problem."""


def default_url() -> str:
    """~/.local/share/tapcell/taps.db (or under $XDG_DATA_HOME)."""
    base = Path(os.environ.get("XDG_DATA_HOME") or Path.home() / ".local" / "share")
    return f"sqlite:///{base / 'tapcell' / 'taps.db'}"


def normalise_url(url: str) -> str:
    """A plain path means SQLite; postgresql:// means psycopg 3."""
    if "://" not in url:
        return f"sqlite:///{Path(url).expanduser()}"
    for prefix in ("postgresql://", "postgres://"):
        if url.startswith(prefix):
            return "postgresql+psycopg://" + url[len(prefix):]
    return url


def shown_url(url: str) -> str:
    """The URL without its password, for messages."""
    try:
        return sa.engine.make_url(url).render_as_string(hide_password=True)
    except ArgumentError:
        return url


def _sqlite_pragmas(dbapi_connection, _record) -> None:
    # The driver's own transaction handling off: SQLAlchemy's begin event below says BEGIN.
    dbapi_connection.isolation_level = None
    cursor = dbapi_connection.cursor()
    cursor.execute(f"PRAGMA busy_timeout = {SQLITE_BUSY_TIMEOUT_MS}")
    cursor.execute("PRAGMA foreign_keys = ON")
    cursor.execute("PRAGMA journal_mode = WAL")  # persistent; outside any transaction, as SQLite requires
    # In WAL mode NORMAL never corrupts and a killed process loses nothing committed; only a power
    # cut may lose the last commits. FULL would fsync every tap.
    cursor.execute("PRAGMA synchronous = NORMAL")
    cursor.close()


def _sqlite_begin(connection: Connection) -> None:
    writing = connection.get_execution_options().get("tapcell_write", False)
    connection.exec_driver_sql("BEGIN IMMEDIATE" if writing else "BEGIN")


@dataclass(frozen=True)
class Added:
    """What a write did: the row's id and whether it was new (False: already stored)."""

    id: int
    new: bool


class Store:
    """A tap store at a URL. `create=False` refuses to make a new one (the web viewer)."""

    def __init__(self, url: str | None = None, create: bool = True):
        self.url = normalise_url(url or default_url())
        self.shown = shown_url(self.url)
        self.engine = self._engine(create)
        try:
            self._check_and_migrate()
        except DBAPIError as exc:
            self.engine.dispose()
            raise StoreError(f"{self.shown}: cannot be read as a tapcell store: {_reason(exc)}") from None
        except StoreError:
            self.engine.dispose()
            raise

    # -- opening ---------------------------------------------------------------------------------
    def _engine(self, create: bool) -> Engine:
        try:
            parsed = sa.engine.make_url(self.url)
        except ArgumentError:
            raise StoreError(f"{self.url}: not a database URL (use a path, sqlite:///PATH or postgresql://...)") from None
        if parsed.get_backend_name() not in ("sqlite", "postgresql"):
            raise StoreError(f"{self.shown}: unsupported database '{parsed.get_backend_name()}' "
                             "(use sqlite:///PATH or postgresql://USER@HOST:PORT/NAME)")
        if parsed.get_backend_name() == "sqlite":
            path = parsed.database
            if not path or path == ":memory:":
                raise StoreError(f"{self.shown}: give the SQLite store a file (sqlite:///PATH)")
            if not Path(path).exists():
                if not create:
                    raise StoreError(f"{path}: no tap store there; tapcell monitor --db or tapcell import makes one")
                Path(path).parent.mkdir(parents=True, exist_ok=True)
        try:
            engine = sa.create_engine(parsed, pool_pre_ping=True)
        except (NoSuchModuleError, ImportError) as exc:
            raise StoreError(f"{self.shown}: the database driver is missing ({exc}); "
                             "install tapcell[history] (and tapcell[postgresql] for PostgreSQL)") from None
        if engine.dialect.name == "sqlite":
            event.listen(engine, "connect", _sqlite_pragmas)
            event.listen(engine, "begin", _sqlite_begin)
        return engine

    def _write(self):
        """A write transaction (BEGIN IMMEDIATE on SQLite)."""
        return self.engine.connect().execution_options(tapcell_write=True)

    def _check_and_migrate(self) -> None:
        with self._write() as connection, connection.begin():
            if self.engine.dialect.name == "postgresql":  # one migrating process at a time on a shared server
                connection.execute(sa.text("SELECT pg_advisory_xact_lock(7125022)"))
            version = self._version(connection)
            if version > schema.CURRENT_VERSION:
                raise StoreError(f"{self.shown}: the store is at schema version {version}, written by a newer "
                                 f"tapcell (this one knows up to {schema.CURRENT_VERSION}); upgrade tapcell")
            for step in range(max(version, 0), schema.CURRENT_VERSION):
                schema.MIGRATIONS[step](connection)
                connection.execute(schema.schema_version.update().values(version=step + 1))

    def _version(self, connection: Connection) -> int:
        """The store's version; 0 for an empty database; StoreError for someone else's."""
        names = set(sa.inspect(connection).get_table_names())
        if "schema_version" not in names:
            if names:
                raise StoreError(f"{self.shown}: not a tapcell store (it holds other tables: "
                                 f"{', '.join(sorted(names)[:5])}); give --db a new file or database")
            return 0
        rows = connection.execute(sa.select(schema.schema_version.c.version)).scalars().all()
        if len(rows) != 1:
            raise StoreError(f"{self.shown}: schema_version holds {len(rows)} rows, expected 1: not a tapcell store")
        return int(rows[0])

    def version(self) -> int:
        with self.engine.connect() as connection:
            return self._version(connection)

    def close(self) -> None:
        self.engine.dispose()

    def __enter__(self) -> Store:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- writes ----------------------------------------------------------------------------------
    def _insert(self):
        if self.engine.dialect.name == "postgresql":
            from sqlalchemy.dialects.postgresql import insert
        else:
            from sqlalchemy.dialects.sqlite import insert
        return insert

    def _printer_id(self, connection: Connection, name: str, url: str) -> int:
        insert = self._insert()
        connection.execute(insert(schema.printers).values(name=name, url=url, created_s=time.time())
                           .on_conflict_do_nothing(index_elements=["name"]))
        return connection.execute(sa.select(schema.printers.c.id).where(schema.printers.c.name == name)).scalar_one()

    def _settings_id(self, connection: Connection, printer_id: int, settings: dict | None, recorded_s: float) -> int | None:
        if settings is None:
            return None
        key = settings_key(settings)
        insert = self._insert()
        connection.execute(insert(schema.probe_settings).values(
            printer_id=printer_id, settings_key=key, recorded_s=recorded_s, settings=json.dumps(settings, sort_keys=True))
            .on_conflict_do_nothing(index_elements=["printer_id", "settings_key"]))
        table = schema.probe_settings
        return connection.execute(sa.select(table.c.id).where(table.c.printer_id == printer_id,
                                                              table.c.settings_key == key)).scalar_one()

    def add_printer(self, name: str, url: str = "") -> int:
        _check_name(name)
        with self._write() as connection, connection.begin():
            return self._printer_id(connection, name, url)

    def add_tap(self, printer: str, document: dict, recorded_s: float | None = None,
                settings: dict | None = None, printer_url: str = "") -> Added:
        """Keep one analysed tap (a tapcell.tap.v1 document with `analysis`, maybe `printer`)."""
        return self.add_taps(printer, [document], recorded_s, settings, printer_url)[0]

    def add_taps(self, printer: str, documents: list[dict], recorded_s: float | None = None,
                 settings: dict | None = None, printer_url: str = "") -> list[Added]:
        """Keep taps in one transaction; each document's meta.recorded_s wins over `recorded_s`."""
        _check_name(printer)
        now = time.time() if recorded_s is None else recorded_s
        records = [tap_record(document, _recorded_s(document, now)) for document in documents]
        return self.add_records(printer, records, settings, printer_url)

    def add_records(self, printer: str, records: list[TapRecord], settings: dict | None = None,
                    printer_url: str = "") -> list[Added]:
        insert = self._insert()
        table = schema.taps
        added = []
        with self._write() as connection, connection.begin():
            printer_id = self._printer_id(connection, printer, printer_url)
            settings_id = self._settings_id(connection, printer_id, settings, records[0].recorded_s if records else 0.0)
            for record in records:
                new_id = connection.execute(
                    insert(table).values(printer_id=printer_id, settings_id=settings_id, **record.columns())
                    .on_conflict_do_nothing(index_elements=["printer_id", "tap_key"]).returning(table.c.id)
                ).scalar()
                if new_id is not None:
                    added.append(Added(int(new_id), True))
                    continue
                old_id = connection.execute(sa.select(table.c.id).where(
                    table.c.printer_id == printer_id, table.c.tap_key == record.tap_key)).scalar_one()
                added.append(Added(int(old_id), False))
        return added

    def add_mesh(self, printer: str, bed_mesh_status: dict, recorded_s: float | None = None,
                 printer_url: str = "") -> Added | None:
        """Keep the loaded mesh of a `bed_mesh` status (None when no mesh is loaded)."""
        _check_name(printer)
        record = mesh_record(bed_mesh_status, time.time() if recorded_s is None else recorded_s)
        if record is None:
            return None
        return self.add_mesh_record(printer, record, printer_url)

    def add_mesh_record(self, printer: str, record: MeshRecord, printer_url: str = "") -> Added:
        insert = self._insert()
        table = schema.meshes
        with self._write() as connection, connection.begin():
            printer_id = self._printer_id(connection, printer, printer_url)
            new_id = connection.execute(
                insert(table).values(printer_id=printer_id, **record.columns())
                .on_conflict_do_nothing(index_elements=["printer_id", "mesh_key"]).returning(table.c.id)).scalar()
            if new_id is not None:
                return Added(int(new_id), True)
            return Added(connection.execute(sa.select(table.c.id).where(
                table.c.printer_id == printer_id, table.c.mesh_key == record.mesh_key)).scalar_one(), False)

    # -- reads -----------------------------------------------------------------------------------
    def printers(self) -> list[dict]:
        table = schema.printers
        with self.engine.connect() as connection:
            rows = connection.execute(sa.select(table).order_by(table.c.name)).mappings().all()
        return [dict(row) for row in rows]

    def printer(self, name: str) -> dict | None:
        table = schema.printers
        with self.engine.connect() as connection:
            row = connection.execute(sa.select(table).where(table.c.name == name)).mappings().first()
        return None if row is None else dict(row)

    def fleet(self) -> list[dict]:
        """Per printer: the last tap and the health of its latest taps, with the change test.

        Three queries whatever the fleet's size: each printer's first id of its latest window (an
        index probe per printer), the window's rows, and the tap counts."""
        taps, printers = schema.taps, schema.printers
        inner = taps.alias("inner")
        window_start = (sa.select(inner.c.id).where(inner.c.printer_id == printers.c.id)
                        .order_by(inner.c.id.desc()).offset(FLEET_WINDOW_TAPS - 1).limit(1)
                        .scalar_subquery())
        starts = sa.select(printers.c.id.label("printer_id"),
                           sa.func.coalesce(window_start, 0).label("first_id")).subquery()
        rows_query = (sa.select(*TAP_COLUMNS).join(starts, starts.c.printer_id == taps.c.printer_id)
                      .where(taps.c.id >= starts.c.first_id).order_by(taps.c.printer_id, taps.c.id))
        with self.engine.connect() as connection:
            found = connection.execute(sa.select(printers).order_by(printers.c.name)).mappings().all()
            recent: dict[int, list[dict]] = {}
            result = connection.execute(rows_query)
            keys = list(result.keys())
            for values in result.all():  # plain tuples: ~12,500 rows for 50 printers
                row = dict(zip(keys, values))
                recent.setdefault(row["printer_id"], []).append(row)
            counts = dict(connection.execute(sa.select(taps.c.printer_id, sa.func.count())
                                             .group_by(taps.c.printer_id)).all())
        return [printer_health(dict(printer), recent.get(printer["id"], []), int(counts.get(printer["id"], 0)))
                for printer in found]

    def taps(self, printer_id: int, status: str = "all", cause: str = "", limit: int = 200,
             before_id: int | None = None) -> list[dict]:
        """A printer's taps, newest first, filtered by status ('all', 'valid', 'rejected') and cause code."""
        table = schema.taps
        query = sa.select(*TAP_COLUMNS).where(table.c.printer_id == printer_id)
        if status == "valid":
            query = query.where(sa.not_(rejected_clause()))
        elif status == "rejected":
            query = query.where(rejected_clause())
        if cause:
            query = query.where(sa.or_(table.c.tapcell_error == cause, table.c.printer_error == cause))
        if before_id is not None:
            query = query.where(table.c.id < before_id)
        with self.engine.connect() as connection:
            rows = connection.execute(query.order_by(table.c.id.desc()).limit(limit)).mappings().all()
        return [dict(row) for row in rows]

    def causes(self, printer_id: int) -> list[str]:
        table = schema.taps
        with self.engine.connect() as connection:
            found = set()
            for column in (table.c.tapcell_error, table.c.printer_error):
                found.update(connection.execute(sa.select(column).where(table.c.printer_id == printer_id,
                                                                        column.is_not(None)).distinct()).scalars())
        return sorted(found)

    def tap(self, printer_id: int, tap_id: int) -> dict | None:
        """One tap with its document (samples, moves, both results)."""
        table = schema.taps
        with self.engine.connect() as connection:
            row = connection.execute(sa.select(table).where(table.c.printer_id == printer_id, table.c.id == tap_id)
                                     ).mappings().first()
            if row is None:
                return None
            found = dict(row)
            found["document"] = tap_document(found["document"])
            found["settings"] = None
            if found.get("settings_id") is not None:
                text = connection.execute(sa.select(schema.probe_settings.c.settings).where(
                    schema.probe_settings.c.id == found["settings_id"])).scalar()
                found["settings"] = None if text is None else json.loads(text)
        return found

    def meshes(self, printer_id: int, limit: int = 100, ids: tuple[int, ...] = ()) -> list[dict]:
        """A printer's latest `limit` meshes, newest first, and those of `ids` wherever they are."""
        table = schema.meshes
        query = sa.select(table).where(table.c.printer_id == printer_id)
        latest = query.order_by(table.c.id.desc()).limit(limit)
        with self.engine.connect() as connection:
            rows = list(connection.execute(latest).mappings().all())
            missing = [mesh_id for mesh_id in ids if mesh_id not in {row["id"] for row in rows}]
            if missing:
                rows += connection.execute(query.where(table.c.id.in_(missing))).mappings().all()
        return [dict(row, matrix=json.loads(row["matrix"])) for row in rows]

    def bed_spots(self, printer_id: int, limit: int = 20_000) -> list[tuple[float, float, bool]]:
        """(x, y, rejected) of a printer's latest taps that have a position, oldest first."""
        table = schema.taps
        query = (sa.select(table.c.x_mm, table.c.y_mm, rejected_clause().label("rejected"))
                 .where(table.c.printer_id == printer_id, table.c.x_mm.is_not(None), table.c.y_mm.is_not(None))
                 .order_by(table.c.id.desc()).limit(limit))
        with self.engine.connect() as connection:
            rows = [(float(x), float(y), bool(rejected)) for x, y, rejected in connection.execute(query)]
        return rows[::-1]

    def latest_ids(self) -> dict[str, int]:
        """The newest tap and mesh ids: what the live pages poll (two index lookups, whatever the size)."""
        with self.engine.connect() as connection:
            tap_id = connection.execute(sa.select(sa.func.max(schema.taps.c.id))).scalar()
            mesh_id = connection.execute(sa.select(sa.func.max(schema.meshes.c.id))).scalar()
        return {"tap": int(tap_id or 0), "mesh": int(mesh_id or 0)}

    def size_bytes(self) -> int | None:
        """The database's size on disk (SQLite file with its WAL, or pg_database_size)."""
        if self.engine.dialect.name == "sqlite":
            path = Path(sa.engine.make_url(self.url).database)
            return sum(p.stat().st_size for p in (path, Path(f"{path}-wal")) if p.exists())
        with self.engine.connect() as connection:
            return int(connection.execute(sa.text("SELECT pg_database_size(current_database())")).scalar_one())


def rejected_clause():
    """A tap the printer or tapcell rejected."""
    return sa.or_(schema.taps.c.tapcell_valid.is_(False), schema.taps.c.printer_valid.is_(False))


def is_rejected(row: dict) -> bool:
    return (not row["tapcell_valid"]) or row["printer_valid"] is False


def printer_health(printer: dict, recent: list[dict], tap_count: int) -> dict:
    """The fleet page's row for one printer, from its latest taps (oldest first)."""
    last = recent[-1] if recent else None
    valid = [row for row in recent if not is_rejected(row)]
    stiffness = [row["stiffness_g_um"] for row in valid if row["stiffness_g_um"] is not None]
    noise = [row["noise_sigma_g"] for row in recent if row["noise_sigma_g"] is not None]
    trends = [health.trend("noise_sigma_g", [row["noise_sigma_g"] for row in recent]),
              health.trend("stiffness_g_um", [row["stiffness_g_um"] if not is_rejected(row) else None for row in recent]),
              health.trend("rejected", [1.0 if is_rejected(row) else 0.0 for row in recent], proportion=True)]
    return {
        "name": printer["name"], "id": printer["id"], "url": printer["url"], "taps": tap_count,
        "window": len(recent), "last": last,
        "repeatability_um": health.repeatability_um([r["x_mm"] for r in valid], [r["y_mm"] for r in valid],
                                                    [r["tapcell_z_mm"] for r in valid]),
        "stiffness_g_um": _median(stiffness), "noise_sigma_g": _median(noise),
        "rejection_rate": (len(recent) - len(valid)) / len(recent) if recent else None,
        "trends": [t.to_json() for t in trends], "flagged": any(t.flagged for t in trends),
        # The trend chart's points: noise per tap, to 0.1 mg (the page carries 250 per printer).
        "series": {"id": [row["id"] for row in recent],
                   "noise_sigma_g": [None if row["noise_sigma_g"] is None else round(row["noise_sigma_g"], 4)
                                     for row in recent]},
    }


def _median(values: list[float]) -> float | None:
    if not values:
        return None
    ordered = sorted(values)
    middle = len(ordered) // 2
    return ordered[middle] if len(ordered) % 2 else (ordered[middle - 1] + ordered[middle]) / 2


def _recorded_s(document: dict, default: float) -> float:
    meta = document.get("meta")
    value = meta.get("recorded_s") if isinstance(meta, dict) else None
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else default


def _check_name(name: str) -> None:
    if not isinstance(name, str) or not name.strip() or len(name) > 100:
        raise RecordError(f"printer name {name!r}: give 1 to 100 characters")


def _reason(exc: Exception) -> str:
    original = getattr(exc, "orig", None)
    return str(original or exc).strip().splitlines()[0]
