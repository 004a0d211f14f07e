"""What a fleetbus store is: events, sequence ledger, coordination, beacons and maps, in one database."""

from __future__ import annotations

from workers.store.base import EventStore
from workers.store.beacons import BeaconRegistry
from workers.store.hazards import CoordinationStore
from workers.store.ledger import SequenceLedger
from workers.store.maps import MapStore


class Store(EventStore, CoordinationStore, BeaconRegistry, MapStore, SequenceLedger):
    """Implemented by :class:`~workers.store.sqlite.SQLiteEventStore` and
    :class:`~workers.store.mongo.MongoEventStore`."""
