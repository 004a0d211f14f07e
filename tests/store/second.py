"""A second, independent connection to the same database as a test's store: a concurrent writer."""

from __future__ import annotations

from fleetbus.workers.store.interface import Store
from fleetbus.workers.store.mongo import MongoEventStore
from fleetbus.workers.store.sqlite import SQLiteEventStore


def second_connection(store: Store) -> Store:
    """Not yet opened; use ``async with``."""
    if isinstance(store, SQLiteEventStore):
        return SQLiteEventStore(store.path)
    assert isinstance(store, MongoEventStore)
    return MongoEventStore(store.url, database=store._database_name)
