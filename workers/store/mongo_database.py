"""One MongoDB database through pymongo's ``AsyncMongoClient``, with durable writes.

Writes are journaled majority writes: acknowledged data survives a crash of the primary.
mongod accepts "majority" on a standalone too; mongoeco accepts both (its memory engine has no
journal, so j is a no-op there), so no fallback is needed.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any
from urllib.parse import urlsplit

from pymongo import AsyncMongoClient
from pymongo.errors import AutoReconnect, ConnectionFailure, NetworkTimeout, ServerSelectionTimeoutError
from pymongo.write_concern import WriteConcern

from workers.store.base import StoreUnavailable

DUPLICATE_KEY = 11000
UNAVAILABLE = (AutoReconnect, ConnectionFailure, NetworkTimeout, ServerSelectionTimeoutError)
DEFAULT_DATABASE = "fleetbus"


def database_name(url: str) -> str:
    path = urlsplit(url).path.strip("/")
    return path or DEFAULT_DATABASE


class MongoDatabase:
    def __init__(self, url: str, database: str | None = None, server_selection_timeout: float = 5.0) -> None:
        self.url = url
        self._database_name = database or database_name(url)
        self._timeout_ms = int(server_selection_timeout * 1000)
        self._client: AsyncMongoClient[dict[str, Any]] | None = None

    def _connect(self) -> None:
        if self._client is None:
            self._client = AsyncMongoClient(
                self.url, serverSelectionTimeoutMS=self._timeout_ms, tz_aware=True
            )

    def _database(self) -> Any:
        if self._client is None:
            raise RuntimeError("the store is not open")
        return self._client.get_database(
            self._database_name, write_concern=WriteConcern(w="majority", j=True)
        )

    def _collection(self, name: str) -> Any:
        return self._database()[name]

    def _safe_url(self) -> str:
        """Hosts and database without credentials (``urlsplit().port`` fails on a host list)."""
        hosts = urlsplit(self.url).netloc.rpartition("@")[2]
        return f"{hosts}/{self._database_name}"

    @contextmanager
    def _reachable(self) -> Iterator[None]:
        """Report a database that cannot be reached as :class:`StoreUnavailable` (retry later)."""
        try:
            yield
        except UNAVAILABLE as error:
            raise StoreUnavailable(f"MongoDB at {self._safe_url()}: {error}") from error

    async def close(self) -> None:
        if self._client is not None:
            await self._client.close()
            self._client = None
