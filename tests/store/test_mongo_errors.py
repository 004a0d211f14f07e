"""MongoDB's errors in their classes: what passes (an election, a primary stepping down, a write
concern not met in time) is StoreUnavailable, which the workers retry; a refusal is not."""

from __future__ import annotations

import pytest
from pymongo.errors import (
    AutoReconnect,
    DuplicateKeyError,
    NotPrimaryError,
    OperationFailure,
    WriteConcernError,
)

from fleetbus.workers.store.base import StoreUnavailable
from fleetbus.workers.store.mongo_database import MongoDatabase, is_transient, translate_unavailable


@pytest.mark.parametrize(
    "error",
    [
        NotPrimaryError("not primary", {"code": 10107, "codeName": "NotWritablePrimary"}),
        OperationFailure("interrupted due to repl state change", code=11602),
        OperationFailure("primary stepped down", code=189),
        WriteConcernError("waiting for replication timed out", code=64),
        OperationFailure("retry me", code=1, details={"errorLabels": ["RetryableWriteError"]}),
        AutoReconnect("connection reset"),
    ],
)
def test_transient_errors_are_retried(error: Exception) -> None:
    assert is_transient(error)


@pytest.mark.parametrize(
    "error",
    [
        DuplicateKeyError("E11000 duplicate key", code=11000),
        OperationFailure("not authorized", code=13),
        WriteConcernError("no such write concern", code=100),
        ValueError("a bug"),
    ],
)
def test_refusals_and_bugs_are_not(error: Exception) -> None:
    assert not is_transient(error)


class Probe:
    async def write(self) -> None:
        raise NotImplementedError


async def test_an_election_reaches_the_worker_as_store_unavailable() -> None:
    @translate_unavailable(Probe)
    class Electing(MongoDatabase, Probe):
        def __init__(self, error: Exception) -> None:
            super().__init__("mongodb://db.example:27017/fleetbus")
            self.error = error

        async def write(self) -> None:
            raise self.error

    with pytest.raises(StoreUnavailable, match=r"db\.example:27017/fleetbus: not primary"):
        await Electing(NotPrimaryError("not primary", {"code": 10107})).write()
    with pytest.raises(OperationFailure, match="not authorized"):
        await Electing(OperationFailure("not authorized", code=13)).write()
