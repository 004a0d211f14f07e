"""Event storage: narrow repositories (:mod:`fleetbus.workers.store.repositories`), each written
once over a persistence port (:mod:`fleetbus.workers.store.port`) that the embedded SQLite default
and MongoDB for production implement; and the recorder's store."""

from __future__ import annotations

from fleetbus.workers.store.base import (
    EventQuery,
    EventRecord,
    EventStore,
    StoreError,
    StoreUnavailable,
    WriteResult,
)
from fleetbus.workers.store.hazards import Hazard, HazardRefused, HazardState, RobotState
from fleetbus.workers.store.recordings import RecordingStore
from fleetbus.workers.store.repositories import (
    EventLog,
    Repositories,
    StoreSettings,
    open_repositories,
    repositories_for,
    run_with_repositories,
)

__all__ = [
    "EventLog",
    "EventQuery",
    "EventRecord",
    "EventStore",
    "Hazard",
    "HazardRefused",
    "HazardState",
    "RecordingStore",
    "Repositories",
    "RobotState",
    "StoreError",
    "StoreSettings",
    "StoreUnavailable",
    "WriteResult",
    "open_recording_store",
    "open_repositories",
    "repositories_for",
    "run_with_repositories",
]


def open_recording_store(settings: StoreSettings) -> RecordingStore:
    """The recorder's store: MongoDB collections ``recorded.<type>`` when ``mongodb_url`` is set,
    else a SQLite file of its own next to the event log; not yet opened."""
    if settings.mongodb_url:
        from fleetbus.workers.store.mongo_recordings import MongoRecordingStore

        return MongoRecordingStore(settings.mongodb_url, max_field_indexes=settings.field_indexes_max)
    from fleetbus.workers.store.sqlite_recordings import SQLiteRecordingStore

    return SQLiteRecordingStore(settings.recording_path, max_field_indexes=settings.field_indexes_max)
