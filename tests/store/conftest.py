"""Store fixtures: each adapter against a real database, fresh per test (MongoDB: ``tests.store.mongodb``)."""

from __future__ import annotations

import uuid
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path

import pytest
from pymongo import AsyncMongoClient

from fleetbus.workers.store.mongo import mongo_repositories
from fleetbus.workers.store.mongo_recordings import MongoRecordingStore
from fleetbus.workers.store.recordings import RecordingStore
from fleetbus.workers.store.repositories import Repositories
from fleetbus.workers.store.sqlite import sqlite_repositories
from fleetbus.workers.store.sqlite_recordings import SQLiteRecordingStore
from tests.store.mongodb import mongodb_url  # noqa: F401  (re-exported fixture)


@asynccontextmanager
async def fresh_database(url: str) -> AsyncIterator[str]:
    """A database name of this test's own, dropped after it (a real server would keep them all)."""
    database = f"test_{uuid.uuid4().hex[:12]}"
    try:
        yield database
    finally:
        client: AsyncMongoClient[dict[str, object]] = AsyncMongoClient(url, serverSelectionTimeoutMS=5000)
        try:
            await client.drop_database(database)
        finally:
            await client.close()


@pytest.fixture(params=["sqlite", "mongodb"])
async def store(request: pytest.FixtureRequest, tmp_path: Path) -> AsyncIterator[Repositories]:
    """Every repository on each backend, over a fresh database."""
    if request.param == "sqlite":
        async with sqlite_repositories(tmp_path / "store.sqlite3") as repositories:
            yield repositories
        return
    url: str = request.getfixturevalue("mongodb_url")
    async with fresh_database(url) as database, mongo_repositories(url, database=database) as repositories:
        yield repositories


@pytest.fixture(params=["sqlite", "mongodb"])
async def recording(request: pytest.FixtureRequest, tmp_path: Path) -> AsyncIterator[RecordingStore]:
    """The recording store on each adapter, empty."""
    if request.param == "sqlite":
        async with SQLiteRecordingStore(tmp_path / "recording.sqlite3") as adapter:
            yield adapter
        return
    url: str = request.getfixturevalue("mongodb_url")
    async with fresh_database(url) as database, MongoRecordingStore(url, database=database) as adapter:
        yield adapter
