"""Dead letters' reasons on every adapter: kept per key, the first record stays, read back by key."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone

from fleetbus.workers.store.rejections import Rejection
from fleetbus.workers.store.repositories import Repositories
from tests.store.second import second_connection

T0 = datetime(2026, 11, 24, 8, 0, 0, tzinfo=timezone.utc)


async def test_a_rejection_recorded_again_keeps_the_first_and_survives_a_new_connection(
    store: Repositories,
) -> None:
    first = Rejection("k1", "schema", "body.rssi: not an integer", T0)
    await store.rejections.record_rejections([first, Rejection("k2", "too-large", "70000 bytes", T0)])
    # the same message after a redelivery: recorded again, later, perhaps worded otherwise
    await store.rejections.record_rejections([Rejection("k1", "schema", "again", T0 + timedelta(seconds=5))])
    await store.rejections.record_rejections([])
    other = second_connection(store)  # what `fleetbus dlq` sees
    await other.open()
    try:
        found = await other.rejections.rejections(["k1", "k2", "never-rejected", "k1"])
    finally:
        await other.close()
    assert found == {"k1": first, "k2": Rejection("k2", "too-large", "70000 bytes", T0)}
    assert await store.rejections.rejections([]) == {}


async def test_rejections_are_pruned_by_when_they_were_made_oldest_first(store: Repositories) -> None:
    made = [Rejection(f"k{i}", "schema", "body: missing", T0 + timedelta(minutes=i)) for i in range(5)]
    await store.rejections.record_rejections(made)
    assert await store.housekeeping.prune_rejections(T0 + timedelta(minutes=2), None, 10) == 2
    assert await store.housekeeping.prune_rejections(None, 2, 10) == 1, "beyond the newest two"
    keys = [rejection.key for rejection in made]
    assert sorted(await store.rejections.rejections(keys)) == ["k3", "k4"]
