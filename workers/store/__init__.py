"""Event storage: one interface, an embedded SQLite default and MongoDB for production."""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from typing import TypeVar

from fleetbus.settings import Settings
from fleetbus.workers.store.base import (
    EventQuery,
    EventRecord,
    EventStore,
    StoreError,
    StoreUnavailable,
    WriteResult,
)
from fleetbus.workers.store.hazards import Hazard, HazardRefused, HazardState, RobotState
from fleetbus.workers.store.interface import Store
from fleetbus.workers.store.recordings import RecordingStore

T = TypeVar("T")

__all__ = [
    "EventQuery",
    "EventRecord",
    "EventStore",
    "Hazard",
    "HazardRefused",
    "HazardState",
    "RecordingStore",
    "RobotState",
    "Store",
    "StoreError",
    "StoreUnavailable",
    "WriteResult",
    "open_recording_store",
    "open_store",
    "run_with_store",
]


def run_with_store(settings: Settings, operation: Callable[[Store], Awaitable[T]]) -> T:
    """For synchronous callers (commands, tests): open the store, run one operation, close it."""

    async def go() -> T:
        async with open_store(settings) as store:
            return await operation(store)

    return asyncio.run(go())


def open_store(settings: Settings) -> Store:
    """The store the settings select (MongoDB when ``mongodb_url`` is set), not yet opened."""
    if settings.mongodb_url:
        from fleetbus.workers.store.mongo import MongoEventStore

        return MongoEventStore(settings.mongodb_url)
    from fleetbus.workers.store.sqlite import SQLiteEventStore

    return SQLiteEventStore(settings.sqlite_path)


def open_recording_store(settings: Settings) -> RecordingStore:
    """The recorder's store: MongoDB collections ``recorded.<type>`` when ``mongodb_url`` is set,
    else a SQLite file of its own next to the event log; not yet opened."""
    if settings.mongodb_url:
        from fleetbus.workers.store.mongo_recordings import MongoRecordingStore

        return MongoRecordingStore(settings.mongodb_url, max_field_indexes=settings.field_indexes_max)
    from fleetbus.workers.store.sqlite_recordings import SQLiteRecordingStore

    return SQLiteRecordingStore(settings.recording_path, max_field_indexes=settings.field_indexes_max)
