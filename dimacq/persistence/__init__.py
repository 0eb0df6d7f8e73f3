"""Persistence: SQLAlchemy 2 database (SQLite in WAL mode by default, any SQLAlchemy URL works),
versioned schema migrations, and bulk arrays in HDF5 files referenced from the database."""

from dimacq.persistence.arrays import ArrayStore
from dimacq.persistence.db import Database, open_database
from dimacq.persistence.migrations import SCHEMA_VERSION, current_version, migrate

__all__ = [
    "SCHEMA_VERSION",
    "ArrayStore",
    "Database",
    "current_version",
    "migrate",
    "open_database",
]
