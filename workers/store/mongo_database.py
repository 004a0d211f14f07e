"""One MongoDB database through pymongo's ``AsyncMongoClient``, with durable writes.

Writes are journaled majority writes: acknowledged data survives a crash of the primary.
mongod accepts "majority" on a standalone too; mongoeco accepts both (its memory engine has no
journal, so j is a no-op there), so no fallback is needed.
"""

from __future__ import annotations

import functools
import inspect
from collections.abc import Awaitable, Callable
from typing import Any, NoReturn, TypeVar
from urllib.parse import urlsplit

from bson.codec_options import TypeDecoder, TypeRegistry
from bson.decimal128 import Decimal128
from bson.errors import InvalidDocument
from pymongo import AsyncMongoClient
from pymongo.errors import (
    AutoReconnect,
    ConnectionFailure,
    NetworkTimeout,
    OperationFailure,
    PyMongoError,
    ServerSelectionTimeoutError,
)
from pymongo.write_concern import WriteConcern

from fleetbus.workers.store.base import StoreUnavailable

DUPLICATE_KEY = 11000
UNAVAILABLE = (AutoReconnect, ConnectionFailure, NetworkTimeout, ServerSelectionTimeoutError)
#: Server errors that pass: a primary stepping down or shutting down, an election under way
#: (NotWritablePrimary 10107, InterruptedDueToReplStateChange 11602...), a write concern not met in
#: time (WriteConcernFailed 64). The same operation may succeed a moment later.
TRANSIENT_CODES = frozenset({6, 7, 64, 89, 91, 189, 262, 9001, 10107, 11600, 11602, 13435, 13436})
TRANSIENT_LABELS = ("RetryableWriteError", "TransientTransactionError")
DEFAULT_DATABASE = "fleetbus"
C = TypeVar("C", bound=type)


def database_name(url: str) -> str:
    path = urlsplit(url).path.strip("/")
    return path or DEFAULT_DATABASE


def is_transient(error: BaseException) -> bool:
    """Whether a MongoDB error is one to retry (the store unavailable for now), not a refusal."""
    if isinstance(error, UNAVAILABLE):
        return True
    if isinstance(error, PyMongoError) and any(error.has_error_label(label) for label in TRANSIENT_LABELS):
        return True
    return isinstance(error, OperationFailure) and error.code in TRANSIENT_CODES


def raise_as_store_error(error: PyMongoError, where: str) -> NoReturn:
    """Raise a transient error as StoreUnavailable (which the workers retry), any other as it is."""
    if is_transient(error):
        raise StoreUnavailable(f"MongoDB at {where}: {error}") from error
    raise error


def _unavailable_as_store_error(method: Callable[..., Awaitable[Any]]) -> Callable[..., Awaitable[Any]]:
    @functools.wraps(method)
    async def guarded(self: Any, *args: Any, **kwargs: Any) -> Any:
        try:
            return await method(self, *args, **kwargs)
        except PyMongoError as error:
            raise_as_store_error(error, self._safe_url())

    return guarded


def translate_unavailable(interface: type) -> Callable[[C], C]:
    """Every operation of ``interface`` reports an unreachable server or a transient server error
    (:func:`is_transient`) as StoreUnavailable, which workers retry."""

    def decorate(cls: C) -> C:
        for name, _ in inspect.getmembers(interface, inspect.iscoroutinefunction):
            if not name.startswith("_"):
                setattr(cls, name, _unavailable_as_store_error(getattr(cls, name)))
        return cls

    return decorate


class WideIntegers(TypeDecoder):
    """Integers past MongoDB's 64 bits, kept exactly: the robots' JSON may carry them (a ROS
    ``uint64`` holds up to 2**64 - 1), BSON has no such integer. They are written as Decimal128
    (:func:`_wide_integer`, called only for values BSON cannot encode; 34 digits) and read back
    as the integers they were. fleetbus writes no other Decimal128."""

    bson_type = Decimal128

    def transform_bson(self, value: Decimal128) -> int | float:
        number = value.to_decimal()
        return int(number) if number == number.to_integral_value() else float(number)


def _wide_integer(value: Any) -> Any:
    if isinstance(value, int) and not isinstance(value, bool):
        wide = Decimal128(str(value))
        if int(wide.to_decimal()) == value:
            return wide
        raise InvalidDocument(f"an integer of {len(str(abs(value)))} digits: MongoDB keeps up to 34")
    return value  # anything else BSON cannot encode: pymongo says what


#: How the client encodes and decodes fleetbus's documents on MongoDB. (The recording encodes its
#: documents ahead of the write without it and keeps such a body raw: mongoeco, the MongoDB
#: stand-in the tests run on, cannot size a collection that holds a Decimal128.)
TYPE_REGISTRY = TypeRegistry([WideIntegers()], fallback_encoder=_wide_integer)


class MongoDatabase:
    def __init__(self, url: str, database: str | None = None, server_selection_timeout: float = 5.0) -> None:
        self.url = url
        self._database_name = database or database_name(url)
        self._timeout_ms = int(server_selection_timeout * 1000)
        self._client: AsyncMongoClient[dict[str, Any]] | None = None

    def _connect(self) -> None:
        if self._client is None:
            self._client = AsyncMongoClient(
                self.url,
                serverSelectionTimeoutMS=self._timeout_ms,
                tz_aware=True,
                type_registry=TYPE_REGISTRY,
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

    async def close(self) -> None:
        if self._client is not None:
            await self._client.close()
            self._client = None
