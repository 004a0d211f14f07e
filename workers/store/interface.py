"""What a fleetbus store is: events, sequence ledger, coordination, beacons, maps, the service
layer's users, missions and channels, and the workers' leases, in one database."""

from __future__ import annotations

from workers.store.base import EventStore
from workers.store.beacons import BeaconRegistry
from workers.store.channels import ChannelStore
from workers.store.discards import DiscardLog
from workers.store.hazards import CoordinationStore
from workers.store.leases import LeaseStore
from workers.store.ledger import SequenceLedger
from workers.store.maps import MapStore
from workers.store.missions import MissionStore
from workers.store.users import UserStore


class Store(
    EventStore,
    CoordinationStore,
    BeaconRegistry,
    MapStore,
    SequenceLedger,
    UserStore,
    MissionStore,
    ChannelStore,
    DiscardLog,
    LeaseStore,
):
    """Implemented by :class:`~workers.store.sqlite.SQLiteEventStore` and
    :class:`~workers.store.mongo.MongoEventStore`."""
