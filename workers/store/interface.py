"""What a fleetbus store is: the event log, coordination state and beacon registry, in one database."""

from __future__ import annotations

from workers.store.base import EventStore
from workers.store.beacons import BeaconRegistry
from workers.store.hazards import CoordinationStore
from workers.store.maps import MapStore


class Store(EventStore, CoordinationStore, BeaconRegistry, MapStore):
    """Implemented by :class:`~workers.store.sqlite.SQLiteEventStore` and
    :class:`~workers.store.mongo.MongoEventStore`."""
