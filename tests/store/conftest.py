"""Store fixtures: each adapter against a real database, fresh per test (MongoDB: see ``mongodb_url``)."""

from __future__ import annotations

import uuid
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from workers.store.interface import Store
from workers.store.mongo import MongoEventStore
from workers.store.sqlite import SQLiteEventStore


@pytest.fixture(params=["sqlite", "mongodb"])
async def store(request: pytest.FixtureRequest, tmp_path: Path) -> AsyncIterator[Store]:
    if request.param == "sqlite":
        adapter: Store = SQLiteEventStore(tmp_path / "store.sqlite3")
    else:
        url = request.getfixturevalue("mongodb_url")
        adapter = MongoEventStore(url, database=f"test_{uuid.uuid4().hex[:12]}")
    async with adapter:
        yield adapter
