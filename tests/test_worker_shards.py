"""Workers sharing the ingest shards through leases in the store (workers as threads here; as
processes, killed for real, in ``test_scaling.py``)."""

from __future__ import annotations

import logging

import pytest

from fleetbus.schemas.routing import EXPRESS_QUEUE, ingest_shard_queue
from fleetbus.workers.ingest import IngestConsumer
from fleetbus.workers.shards import share
from tests.support import Bus, wait_for


def test_each_worker_takes_its_share_and_a_stopped_workers_shards_move_at_once(bus: Bus) -> None:
    bus.settings = bus.settings.updated(ingest_shards=4)
    with bus.worker() as first:
        assert first.context is not None and sorted(first.context.shards.held) == [0, 1, 2, 3]
        with bus.worker() as second:
            assert second.context is not None
            pools = (first.context.shards, second.context.shards)
            wait_for(lambda: [len(pool.held) for pool in pools] == [2, 2], what="two shards each")
            assert sorted(bus.shard_holders().values()) == [2, 2]
            assert set(first.context.shards.held).isdisjoint(second.context.shards.held)
        wait_for(lambda: len(first.context.shards.held) == 4, timeout=10, what="the first takes all back")
        assert list(bus.shard_holders().values()) == [4]
    assert bus.with_store(lambda store: store.leases.leases()) == [], (
        "a stopped worker leaves no lease behind"
    )


def test_shares_differ_by_one_at_most_and_cover_every_shard() -> None:
    workers = ["a", "b", "c"]
    assert [share(4, workers, w) for w in workers] == [2, 1, 1]
    assert [share(2, workers, w) for w in workers] == [1, 1, 0], "a worker beyond the shards stands by"
    assert share(1, ["a"], "a") == 1


def test_the_command_line_sets_the_number_of_shards(bus: Bus) -> None:
    worker = bus.spawn_worker("--no-recorder", "--shards", "3")  # FLEETBUS_INGEST_SHARDS is 1 here
    try:
        wait_for(
            lambda: list(bus.shard_holders().values()) == [3], timeout=60, what="one worker holding 3 shards"
        )
        assert bus.ready_messages("fleetbus.ingest.events.2") == 0, "the third shard's queue exists"
    finally:
        worker.terminate()
        assert worker.wait(60) == 0


def test_what_a_consumer_ends_with_when_its_shard_is_handed_over_or_its_worker_stops_is_logged(
    bus: Bus, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """Giving a shard back and stopping wait for each consumer to end: what one ends with is said
    (it was thrown away), on the shard's queue as on the express lane's thread."""
    bus.settings = bus.settings.updated(ingest_shards=2)
    run = IngestConsumer.run

    async def fails_once_stopped(consumer: IngestConsumer) -> None:
        await run(consumer)
        raise RuntimeError(f"a bug stopping {consumer._queue.name}")

    monkeypatch.setattr(IngestConsumer, "run", fails_once_stopped)

    def said() -> list[str]:
        return sorted(r.getMessage() for r in caplog.records if r.name == "fleetbus.worker" and r.exc_info)

    def ended(what: str, queue: str) -> str:
        return f"consuming {what} ended with an error: RuntimeError('a bug stopping {queue}')"

    shard_0, shard_1 = ingest_shard_queue(0), ingest_shard_queue(1)
    with caplog.at_level(logging.ERROR, logger="fleetbus.worker"), bus.worker() as first:
        assert first.context is not None
        with bus.worker():
            wait_for(lambda: sorted(first.context.shards.held) == [0], what="shard 1 handed over")
            wait_for(lambda: said() == [ended(shard_1, shard_1)], what="what it ended with said")
        caplog.clear()
        wait_for(lambda: sorted(first.context.shards.held) == [0, 1], what="shard 1 taken back")
    assert said() == sorted(
        [ended(shard_0, shard_0), ended(shard_1, shard_1), ended("the express lane", EXPRESS_QUEUE)]
    )
