"""Store fixtures: each adapter against a real database, fresh per test (MongoDB: ``tests.store.mongodb``)."""

from __future__ import annotations

import uuid
from collections.abc import AsyncIterator
from pathlib import Path

import pytest
from pymongo import AsyncMongoClient

from tests.store.mongodb import mongodb_url  # noqa: F401  (re-exported fixture)
from workers.store.interface import Store
from workers.store.mongo import MongoEventStore
from workers.store.sqlite import SQLiteEventStore


@pytest.fixture(params=["sqlite", "mongodb"])
async def store(request: pytest.FixtureRequest, tmp_path: Path) -> AsyncIterator[Store]:
    if request.param == "sqlite":
        async with SQLiteEventStore(tmp_path / "store.sqlite3") as adapter:
            yield adapter
        return
    url: str = request.getfixturevalue("mongodb_url")
    database = f"test_{uuid.uuid4().hex[:12]}"
    try:
        async with MongoEventStore(url, database=database) as adapter:
            yield adapter
    finally:
        # a real server given by FLEETBUS_MONGODB_URL would otherwise keep every test's database
        client: AsyncMongoClient[dict[str, object]] = AsyncMongoClient(url, serverSelectionTimeoutMS=5000)
        try:
            await client.drop_database(database)
        finally:
            await client.close()
