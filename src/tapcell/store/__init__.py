"""The tap store: every tap (samples, moves, both results, the cause) and every mesh, per
printer, with the probe's settings, in SQLite (default) or PostgreSQL. Needs tapcell[history]."""

from .database import Added, Store, StoreError, default_url, is_rejected, normalise_url, shown_url
from .records import RecordError

__all__ = ["Added", "RecordError", "Store", "StoreError", "default_url", "is_rejected", "normalise_url", "shown_url"]
