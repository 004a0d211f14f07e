"""What the bounds ask of every adapter: pruning by time in batches, map versions and staged
chunks, and the running counts of what was removed."""

from __future__ import annotations

from dataclasses import replace
from datetime import datetime, timedelta, timezone

import pytest

from fleetbus.workers.store.base import EventQuery
from fleetbus.workers.store.discards import Discard
from fleetbus.workers.store.hazards import Hazard, NewHazard
from fleetbus.workers.store.ledger import Duplicate, RobotEpoch
from fleetbus.workers.store.maps import MapVersion, versions_to_prune
from fleetbus.workers.store.repositories import Repositories
from fleetbus.workers.store.statuses import WorkerStatus
from tests.store.test_contract import EPOCH, record

T0 = datetime(2026, 1, 1, tzinfo=timezone.utc)
META = {"resolution": 0.1, "origin": [0, 0, 0], "occupied_thresh": 0.65, "free_thresh": 0.2, "negate": 0}


def received(robot: str, seq: int, type: str, minutes: int):
    """An event received ``minutes`` after T0 (and sent long before: pruning goes by reception)."""
    return replace(
        record(robot, seq, type, T0 - timedelta(days=365)), received_at=T0 + timedelta(minutes=minutes)
    )


async def test_events_are_pruned_by_reception_time_oldest_first_in_batches(store: Repositories) -> None:
    await store.events.write_events([received("r1", seq, "status", seq) for seq in range(7)])
    await store.events.write_events([received("r1", 100, "behaviour", 0)])
    before = T0 + timedelta(minutes=5)  # seq 0-4 are older
    assert await store.housekeeping.prune_events("status", before, None, 2) == 2, (
        "a batch is at most its limit"
    )
    left = [r.seq for r in await store.events.find_events(EventQuery(type="status"))]
    assert left == [2, 3, 4, 5, 6], "the oldest went first"
    assert await store.housekeeping.prune_events("status", before, None, 10) == 3
    assert await store.housekeeping.prune_events("status", before, None, 10) == 0
    assert sorted(r.seq for r in await store.events.find_events(EventQuery())) == [5, 6, 100], (
        "other types untouched"
    )
    assert await store.housekeeping.prune_events("status", None, 1, 10) == 1, "beyond the newest one"
    assert [r.seq for r in await store.events.find_events(EventQuery(type="status"))] == [6]
    assert await store.housekeeping.prune_events("status", None, None, 10) == 0, "no limit, nothing goes"


async def test_events_received_at_the_same_moment_still_go_a_batch_at_a_time(store: Repositories) -> None:
    await store.events.write_events([received("r1", seq, "status", 0) for seq in range(7)])
    assert await store.housekeeping.prune_events("status", T0 + timedelta(minutes=1), None, 3) == 3
    assert await store.housekeeping.prune_events("status", T0 + timedelta(minutes=1), None, 3) == 3
    assert await store.events.count_events("status") == 1


async def test_the_event_of_a_hazard_not_yet_cleared_is_never_pruned(store: Repositories) -> None:
    events = [received("explorer1", seq, "hazard", seq) for seq in range(4)]
    await store.events.write_events(events)
    await store.hazards.hold_hazards([NewHazard.of(event) for event in events[:3]])
    held = await store.hazards.held_hazards()
    await store.hazards.mark_announced(held, T0)
    first, second = held[0], held[1]
    for step in (store.hazards.claim, store.hazards.mark_reached, store.hazards.mark_cleared):
        await step(first.mission_id, first.hazard_id, "warden1", T0)
    # hazard 1 is cleared, 2 and 3 are open, seq 3 never became a hazard: only 1 and 3 may go
    later = T0 + timedelta(days=1)
    assert await store.housekeeping.prune_events("hazard", later, None, 1) == 1
    assert await store.housekeeping.prune_events("hazard", later, None, 10) == 1
    assert await store.housekeeping.prune_events("hazard", later, None, 10) == 0
    left = {r.seq for r in await store.events.find_events(EventQuery(type="hazard"))}
    assert left == {second.seq, held[2].seq} == {1, 2}


async def _clear(store: Repositories, hazard: Hazard, at: datetime) -> Hazard:
    for step in (store.hazards.claim, store.hazards.mark_reached, store.hazards.mark_cleared):
        hazard = await step(hazard.mission_id, hazard.hazard_id, "warden1", at)
    return hazard


async def test_cleared_hazards_are_pruned_by_when_they_were_cleared_and_no_id_is_given_twice(
    store: Repositories,
) -> None:
    events = [received("explorer1", seq, "hazard", seq) for seq in range(6)]
    await store.events.write_events(events)
    await store.hazards.hold_hazards([NewHazard.of(event) for event in events[:4]])
    held = await store.hazards.held_hazards()
    await store.hazards.mark_announced(held, T0)
    # hazards 1, 2 and 4 cleared on days 1, 2 and 4; hazard 3 stays open
    cleared = [await _clear(store, held[i], T0 + timedelta(days=day)) for i, day in ((0, 1), (1, 2), (3, 4))]
    day3 = T0 + timedelta(days=3)
    # a cleared state central has not confirmed stays (every state is unsent but at a site's central)
    assert await store.housekeeping.prune_cleared_hazards(day3, None, 10) == 0
    await store.hazards.mark_sent(cleared[:1])  # a site: central confirmed hazard 1's cleared state
    assert await store.housekeeping.prune_cleared_hazards(day3, None, 10) == 1
    # not a site: none waits for central
    assert await store.housekeeping.prune_cleared_hazards(day3, None, 10, unsent_too=True) == 1
    left = await store.hazards.recent_hazards(10)
    assert sorted(h.hazard_id for h in left) == [3, 4], "the open one and the one cleared since stay"
    assert await store.housekeeping.prune_cleared_hazards(None, 1, 10, unsent_too=True) == 0, "the newest"
    assert await store.housekeeping.prune_cleared_hazards(T0 + timedelta(days=5), None, 10, unsent_too=True)
    assert [h.hazard_id for h in await store.hazards.recent_hazards(10)] == [3]
    # hazard 4, the mission's highest id, is gone: the next hazard is 5, not 4 again
    await store.hazards.hold_hazards([NewHazard.of(events[4])])
    [fifth] = await store.hazards.held_hazards()
    assert fifth.hazard_id == 5


async def test_numberings_not_observed_for_their_bound_leave_the_ledger(store: Repositories) -> None:
    old, busy, gappy = (RobotEpoch("r1", e) for e in ("e-old", "e-busy", "e-gappy"))
    await store.events.observe_sequences({old: [0, 1]}, T0)
    await store.events.observe_sequences({gappy: [0, 3]}, T0 + timedelta(days=1))  # 1 and 2 missing
    await store.events.observe_sequences({busy: [0]}, T0)
    await store.events.observe_sequences({busy: [1]}, T0 + timedelta(days=2))  # observed again since
    assert [(g.epoch, g.first, g.last) for g in await store.events.gaps()] == [("e-gappy", 1, 2)]
    assert await store.housekeeping.prune_numberings(T0 + timedelta(hours=12), None, 10) == 1
    assert await store.events.high_water("r1", "e-old") is None, "forgotten: its numbers are new again"
    assert await store.events.high_water("r1", "e-busy") == 1
    assert await store.housekeeping.prune_numberings(None, 1, 10) == 1, "beyond the one observed last"
    assert await store.events.high_water("r1", "e-busy") == 1 and await store.events.gaps() == []


async def test_duplicates_and_discards_are_pruned_by_age_and_by_count(store: Repositories) -> None:
    # one batch's duplicates share their time: the count goes by the store's own order
    same_time = T0 + timedelta(minutes=10)
    await store.events.record_duplicates(
        [Duplicate("r1", EPOCH, seq, f"m{seq}", T0 + timedelta(minutes=seq), False) for seq in range(3)]
    )
    await store.events.record_duplicates(
        [Duplicate("r1", EPOCH, seq, f"m{seq}", same_time, True) for seq in range(3, 6)]
    )
    assert await store.housekeeping.prune_duplicates(T0 + timedelta(minutes=2), None, 10) == 2
    assert await store.housekeeping.prune_duplicates(None, 2, 1) == 1, "a batch is at most its limit"
    assert await store.housekeeping.prune_duplicates(None, 2, 10) == 1
    assert sorted(d.seq for d in await store.events.duplicates()) == [4, 5], "the last two recorded stay"
    await store.discards.record_discards(
        [
            Discard("r1.beacon", "r1.x", "r1", f"d{i}", "no header", T0 + timedelta(minutes=i))
            for i in range(4)
        ]
    )
    assert await store.housekeeping.prune_discards(T0 + timedelta(minutes=1), None, 10) == 1
    assert await store.housekeeping.prune_discards(None, 2, 10) == 1
    assert [d.message_id for d in await store.discards.recent_discards()] == ["d3", "d2"]


async def test_map_versions_can_be_listed_marked_read_and_deleted(store: Repositories) -> None:
    for seq in range(3):
        await store.maps.commit_map("explorer1", EPOCH, seq, b"P5 map %d" % seq, META, T0, "0" * 64, 4, None)
    assert [v.version for v in await store.maps.map_versions()] == [3, 2, 1]
    await store.maps.note_map_read(1, T0 + timedelta(minutes=1))
    assert await store.maps.map_reads() == {1: T0 + timedelta(minutes=1)}
    assert await store.maps.delete_map_versions([1, 2]) == 2
    assert await store.maps.delete_map_versions([1]) == 0
    assert [v.version for v in await store.maps.map_versions()] == [3]
    assert await store.maps.map_version(1) is None
    with pytest.raises(Exception, match="no chunk"):
        await store.maps.map_chunk(1, 0)
    assert (await store.maps.map_version()).version == 3
    fourth = await store.maps.commit_map("explorer1", EPOCH, 9, b"P5 next", META, T0, "0" * 64, 4, None)
    assert fourth.version == 4, "a pruned version's number is never given again"


async def test_staged_chunks_expire_by_map_after_their_last_chunk(store: Repositories) -> None:
    await store.maps.stage_map_chunk("old", 0, b"a")
    await store.maps.stage_map_chunk("old", 1, b"b")
    now = datetime.now(timezone.utc)
    assert await store.maps.expire_staged_chunks(now - timedelta(hours=1), 10) == {}, "staged just now"
    assert await store.maps.expire_staged_chunks(now + timedelta(seconds=5), 10) == {"old": 2}
    assert await store.maps.staged_map_chunks("old") == {}
    assert await store.maps.expire_staged_chunks(now + timedelta(seconds=5), 10) == {}


async def test_bound_counts_add_up(store: Repositories) -> None:
    await store.housekeeping.count_bounded({("events", "status"): 3, ("overflow", "w1.inbox maxlen"): 0}, T0)
    await store.housekeeping.count_bounded({("events", "status"): 2}, T0 + timedelta(minutes=1))
    [count] = await store.housekeeping.bound_counts()
    assert (count.bound, count.subject, count.count) == ("events", "status", 5)
    assert (count.first_at, count.last_at) == (T0, T0 + timedelta(minutes=1))


def test_each_robot_keeps_its_newest_versions_and_those_being_fetched() -> None:
    def version(number: int, robot: str) -> MapVersion:
        return MapVersion(number, robot, EPOCH, number, {}, T0, 1, "", 1, 1)

    versions = [version(n, "a") for n in range(1, 6)] + [version(6, "b")]
    reads = {1: T0, 2: T0 - timedelta(hours=1)}
    assert versions_to_prune(versions, reads, keep=2, read_since=T0 - timedelta(minutes=10)) == [2, 3]


async def test_the_statuses_and_leases_of_workers_gone_long_ago_are_pruned(store: Repositories) -> None:
    for minutes, name in ((0, "gone-long-ago"), (10, "gone-lately"), (20, "running")):
        await store.statuses.put_status(WorkerStatus(name, T0 + timedelta(minutes=minutes)))
    await store.leases.acquire_lease("worker:gone-long-ago", "gone-long-ago", T0, T0 - timedelta(seconds=5))
    await store.leases.acquire_lease("shard:0", "running", T0 + timedelta(hours=1), T0)
    assert await store.housekeeping.prune_gone_workers(T0 + timedelta(minutes=5), None, 10) == 2
    assert [s.name for s in await store.statuses.statuses()] == ["gone-lately", "running"]
    assert [lease.name for lease in await store.leases.leases()] == ["shard:0"], "the live lease stays"
    assert await store.housekeeping.prune_gone_workers(None, 1, 10) == 1, "beyond the one updated last"
    assert [s.name for s in await store.statuses.statuses()] == ["running"]
