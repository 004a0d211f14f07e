"""What a fleetbus store is: the event log and the coordination state, in one database."""

from __future__ import annotations

from workers.store.base import EventStore
from workers.store.hazards import CoordinationStore


class Store(EventStore, CoordinationStore):
    """Implemented by :class:`~workers.store.sqlite.SQLiteEventStore` and
    :class:`~workers.store.mongo.MongoEventStore`."""
