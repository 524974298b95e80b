"""The store's tables and the ordered steps that build them.

A store records its version in `schema_version` (one row). Opening a store runs every step
after that version, each in its own transaction, so a store written by an older tapcell is
brought up to date and a killed migration leaves the last complete version behind (SQLite and
PostgreSQL both run DDL inside transactions).

Version 1 held printers, taps and meshes. Version 2 adds the probe's settings at the time of
each tap (`probe_settings`, `taps.settings_id`) and the index the fleet page reads by.
"""

from __future__ import annotations

from collections.abc import Callable

import sqlalchemy as sa
from sqlalchemy.engine import Connection

def _define(metadata: sa.MetaData, version: int) -> dict[str, sa.Table]:
    """The tables as of `version` (1 or 2) in `metadata`."""
    tables = {}
    tables["schema_version"] = sa.Table(
        "schema_version", metadata,
        sa.Column("version", sa.Integer, nullable=False),
    )
    tables["printers"] = sa.Table(
        "printers", metadata,
        sa.Column("id", sa.Integer, primary_key=True),
        sa.Column("name", sa.String(100), nullable=False, unique=True),
        sa.Column("url", sa.String(500), nullable=False, default=""),
        sa.Column("created_s", sa.Float, nullable=False),
    )
    if version >= 2:
        tables["probe_settings"] = sa.Table(
            "probe_settings", metadata,
            sa.Column("id", sa.Integer, primary_key=True),
            sa.Column("printer_id", sa.Integer, sa.ForeignKey("printers.id"), nullable=False),
            sa.Column("settings_key", sa.String(64), nullable=False),
            sa.Column("recorded_s", sa.Float, nullable=False),
            # JSON: the probe's section as the printer reported it
            sa.Column("settings", sa.Text, nullable=False),
            sa.UniqueConstraint("printer_id", "settings_key", name="settings_printer_key"),
        )
    tables["taps"] = sa.Table(
        "taps", metadata,
        sa.Column("id", sa.BigInteger().with_variant(sa.Integer, "sqlite"), primary_key=True),
        sa.Column("printer_id", sa.Integer, sa.ForeignKey("printers.id"), nullable=False),
        # sha256 of the samples: the same tap seen twice (two monitors, an import run twice) is kept once.
        sa.Column("tap_key", sa.String(64), nullable=False),
        sa.Column("recorded_s", sa.Float, nullable=False),  # Unix time of the tap (else of its arrival)
        sa.Column("x_mm", sa.Float),
        sa.Column("y_mm", sa.Float),
        sa.Column("printer_z_mm", sa.Float),
        sa.Column("printer_valid", sa.Boolean),
        sa.Column("printer_error", sa.String(100)),
        sa.Column("tapcell_z_mm", sa.Float),
        sa.Column("tapcell_valid", sa.Boolean, nullable=False),
        sa.Column("tapcell_error", sa.String(100)),
        sa.Column("cause", sa.Text, nullable=False, default=""),
        sa.Column("quality", sa.Float),
        sa.Column("stiffness_g_um", sa.Float),
        sa.Column("noise_sigma_g", sa.Float),
        # The whole tap as tapcell.tap.v1 with both results, zlib-compressed JSON.
        sa.Column("document", sa.LargeBinary, nullable=False),
        *([sa.Column("settings_id", sa.Integer, sa.ForeignKey("probe_settings.id"))] if version >= 2 else []),
        sa.UniqueConstraint("printer_id", "tap_key", name="taps_printer_key"),
    )
    tables["meshes"] = sa.Table(
        "meshes", metadata,
        sa.Column("id", sa.Integer, primary_key=True),
        sa.Column("printer_id", sa.Integer, sa.ForeignKey("printers.id"), nullable=False),
        sa.Column("mesh_key", sa.String(64), nullable=False),
        sa.Column("recorded_s", sa.Float, nullable=False),
        sa.Column("profile", sa.String(100), nullable=False),
        sa.Column("x_min_mm", sa.Float, nullable=False),
        sa.Column("y_min_mm", sa.Float, nullable=False),
        sa.Column("x_max_mm", sa.Float, nullable=False),
        sa.Column("y_max_mm", sa.Float, nullable=False),
        sa.Column("matrix", sa.Text, nullable=False),  # JSON rows of Z (mm), one row per Y
        sa.UniqueConstraint("printer_id", "mesh_key", name="meshes_printer_key"),
    )
    return tables


metadata = sa.MetaData()
_CURRENT = _define(metadata, 2)
schema_version = _CURRENT["schema_version"]
printers = _CURRENT["printers"]
probe_settings = _CURRENT["probe_settings"]
taps = _CURRENT["taps"]
meshes = _CURRENT["meshes"]


def _version_1(connection: Connection) -> None:
    old = sa.MetaData()
    tables = _define(old, 1)
    old.create_all(connection)
    sa.Index("taps_printer_id", tables["taps"].c.printer_id, tables["taps"].c.id).create(connection)
    connection.execute(tables["schema_version"].insert().values(version=0))


def _version_2(connection: Connection) -> None:
    probe_settings.create(connection)
    # An ALTER (not a new table), so that a version-1 store keeps its rows.
    connection.execute(sa.text("ALTER TABLE taps ADD COLUMN settings_id INTEGER REFERENCES probe_settings(id)"))
    sa.Index("meshes_printer_id", meshes.c.printer_id, meshes.c.id).create(connection)


# Ordered: MIGRATIONS[k] brings a store from version k to version k + 1.
MIGRATIONS: list[Callable[[Connection], None]] = [_version_1, _version_2]
CURRENT_VERSION = len(MIGRATIONS)

TABLE_NAMES = frozenset(metadata.tables)
