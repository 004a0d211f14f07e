"""The sequence ledger on every adapter: gaps open and close, duplicates are recorded, reused numbers
seen; all of it per robot and epoch."""

from __future__ import annotations

import asyncio
import itertools
from dataclasses import replace
from datetime import datetime, timedelta, timezone

from fleetbus.workers.store.base import EventQuery
from fleetbus.workers.store.ledger import Duplicate, Gap, RobotEpoch, apply_seqs
from fleetbus.workers.store.repositories import Repositories
from tests.store.second import second_connection
from tests.store.test_contract import EPOCH, LATER, record

T0 = datetime(2026, 11, 23, 8, 0, tzinfo=timezone.utc)
T1 = T0 + timedelta(seconds=1)
EXPLORER = RobotEpoch("explorer1", EPOCH)
EXPLORER_LATER = RobotEpoch("explorer1", LATER)
WARDEN = RobotEpoch("warden1", EPOCH)


def spans(gaps: list[Gap]) -> list[tuple[str, str, int, int]]:
    return [(gap.robot_id, gap.epoch, gap.first, gap.last) for gap in gaps]


async def test_a_gap_opens_and_closes_piece_by_piece(store: Repositories) -> None:
    await store.events.observe_sequences({EXPLORER: [0, 1, 2]}, T0)
    assert await store.events.gaps() == [] and await store.events.high_water("explorer1", EPOCH) == 2
    await store.events.observe_sequences({EXPLORER: [7, 8], WARDEN: [3]}, T0)
    assert spans(await store.events.gaps()) == [("explorer1", EPOCH, 3, 6), ("warden1", EPOCH, 0, 2)]
    await store.events.observe_sequences({EXPLORER: [5]}, T1)
    assert spans(await store.events.gaps("explorer1")) == [
        ("explorer1", EPOCH, 3, 4),
        ("explorer1", EPOCH, 6, 6),
    ]
    assert {gap.detected_at for gap in await store.events.gaps()} == {T0}, "pieces keep the time it opened"
    await store.events.observe_sequences({EXPLORER: [3, 4, 6, 9]}, T1)
    assert spans(await store.events.gaps()) == [("warden1", EPOCH, 0, 2)]
    assert await store.events.high_water("explorer1", EPOCH) == 9


async def test_each_epoch_of_a_robot_has_its_own_numbers(store: Repositories) -> None:
    """A client started again counts from 0 in a new epoch: no gap, no reuse, across epochs."""
    await store.events.observe_sequences({EXPLORER: [0, 1, 2, 3, 4]}, T0)
    await store.events.observe_sequences({EXPLORER_LATER: [0, 1]}, T1)
    assert await store.events.gaps() == []
    assert (
        await store.events.high_water("explorer1", EPOCH) == 4
        and await store.events.high_water("explorer1", LATER) == 1
    )
    await store.events.observe_sequences({EXPLORER_LATER: [5], EXPLORER: [6]}, T1)
    assert spans(await store.events.gaps("explorer1")) == [
        ("explorer1", EPOCH, 5, 5),
        ("explorer1", LATER, 2, 4),
    ]


async def test_observing_again_changes_nothing(store: Repositories) -> None:
    for seqs in ([0, 4], [4, 0], [2], [2], [0, 4]):
        await store.events.observe_sequences({EXPLORER: seqs}, T0)
    assert spans(await store.events.gaps()) == [("explorer1", EPOCH, 1, 1), ("explorer1", EPOCH, 3, 3)]
    assert await store.events.high_water("explorer1", EPOCH) == 4
    assert await store.events.high_water("explorer1", LATER) is None
    assert await store.events.high_water("nobody", EPOCH) is None


async def test_duplicates_are_recorded_newest_first(store: Repositories) -> None:
    await store.events.record_duplicates(
        [
            Duplicate("explorer1", EPOCH, 3, "m-3", T0, redelivered=False),
            Duplicate("explorer1", LATER, 4, "m-4", T1, redelivered=True),
            Duplicate("warden1", EPOCH, 1, "w-1", T0, redelivered=False),
        ]
    )
    found = await store.events.duplicates("explorer1")
    assert [(d.epoch, d.seq, d.redelivered, d.seen_at) for d in found] == [
        (LATER, 4, True, T1),
        (EPOCH, 3, False, T0),
    ]
    assert len(await store.events.duplicates()) == 3 and len(await store.events.duplicates(limit=1)) == 1


async def test_a_write_that_finds_its_key_taken_says_by_which_message(store: Repositories) -> None:
    first = record(seq=5)
    await store.events.write_events([first])
    resent, reused = first, replace(first, message_id="another-message")
    results = await store.events.write_events([resent, reused, record(seq=6)])
    assert [(r.inserted, r.stored_message_id) for r in results] == [
        (False, first.message_id),
        (False, first.message_id),
        (True, None),
    ]


async def test_a_key_holds_one_content_whatever_message_id_a_send_carries(store: Repositories) -> None:
    """Same (robot, epoch, seq) and same content digest: the stored event, whichever message id the
    resend carries (a client that mints one per send); another digest: a reused number, even under
    the stored message id. Records stored without a digest are told apart by their message ids."""
    first = replace(record(seq=5), digest="d" * 64)
    legacy = record(seq=6)  # stored without a digest
    await store.events.write_events([first, legacy])
    resent = replace(first, message_id="minted-again")
    reused = replace(first, digest="e" * 64)
    legacy_resent, legacy_reused = replace(legacy, digest="f" * 64), replace(legacy, message_id="other")
    batch = [resent, reused, legacy_resent, legacy_reused]
    stored = await store.events.store_batch(batch, T1)
    assert [(r.stored_message_id, r.stored_digest) for r in stored.results] == [
        (first.message_id, first.digest),
        (first.message_id, first.digest),
        (legacy.message_id, None),
        (legacy.message_id, None),
    ]
    pairs = list(zip(stored.results, batch, strict=True))
    assert [r.holds(item) for r, item in pairs] == [True, False, True, False]
    assert [r.reused(item) for r, item in pairs] == [False, True, False, True]
    found = {r.seq: r for r in await store.events.find_events(EventQuery(robot_id="explorer1"))}
    assert found[5] == first and found[6] == legacy, "what was stored stays"
    assert await store.events.high_water("explorer1", EPOCH) == 6


def test_the_ledger_does_not_depend_on_the_order_it_sees_numbers_in() -> None:
    numbers = [0, 2, 3, 7, 9, 12]
    outcomes = set()
    for order in itertools.permutations(numbers):
        high_water, gaps = None, []
        for seq in order:
            change = apply_seqs(RobotEpoch("r", EPOCH), high_water, gaps, [seq], T0)
            high_water, gaps = change.high_water, change.gaps
        outcomes.add((high_water, tuple((g.first, g.last) for g in gaps)))
    assert outcomes == {(12, ((1, 1), (4, 6), (8, 8), (10, 11)))}


async def test_a_stored_batch_is_stamped_written_and_observed_in_one_step(store: Repositories) -> None:
    await store.channels.mount("explorer1", "alice", "m-1", T0)
    await store.channels.check_in("alice", "m-1", T0)
    first = record(seq=1)
    await store.events.write_events([first])
    reused = replace(first, message_id="another-message")
    batch = [record(seq=0), reused, record("warden1", seq=4)]

    stored = await store.events.store_batch(batch, T1)

    assert [r.mission_id for r in stored.records] == ["m-1", "m-1", None]
    assert [(r.inserted, r.stored_message_id) for r in stored.results] == [
        (True, None),
        (False, first.message_id),
        (True, None),
    ]
    found = await store.events.find_events(EventQuery(mission_id="m-1"))
    assert [(r.robot_id, r.seq) for r in found] == [("explorer1", 0)], "the first record of seq 1 is kept"
    # seq 1 was stored before without the ledger's knowledge; the reused number is not observed
    assert (
        await store.events.high_water("explorer1", EPOCH) == 0
        and await store.events.high_water("warden1", EPOCH) == 4
    )
    assert spans(await store.events.gaps()) == [("warden1", EPOCH, 0, 3)]
    again = await store.events.store_batch(batch, T1)
    assert [r.inserted for r in again.results] == [False, False, False]
    assert await store.events.count_events() == 3 and spans(await store.events.gaps()) == [
        ("warden1", EPOCH, 0, 3)
    ]


async def test_two_lanes_observing_one_robot_at_once_leave_the_ledger_one_lane_would(
    store: Repositories,
) -> None:
    """The express lane and a shard observe the same robot's numbers concurrently, from two
    connections (two worker processes when the shards are shared): no update may be lost."""
    other = second_connection(store)
    await other.open()
    try:
        express = [[seq] for seq in range(5, 200, 10)]  # a hazard every tenth number
        bulk = [[seq for seq in range(start, start + 10) if seq % 10 != 5] for start in range(0, 200, 10)]

        async def observe(observer: Repositories, batches: list[list[int]]) -> None:
            for seqs in batches:
                await observer.events.observe_sequences({EXPLORER: seqs}, T0)

        await asyncio.gather(observe(store, bulk), observe(other, express))
        assert await store.events.gaps() == [], "every number below the mark was observed"
        assert await store.events.high_water("explorer1", EPOCH) == 199
    finally:
        await other.close()


async def test_a_resend_of_a_pruned_event_is_a_duplicate_not_a_second_copy(store: Repositories) -> None:
    statuses = [record(seq=seq, type="status", at=T0 + timedelta(seconds=seq)) for seq in range(4)]
    await store.events.store_batch(statuses, T0)
    assert await store.housekeeping.prune_events("status", None, 1, 10) == 3  # seq 0-2 pruned

    gap_filler = record(seq=9, type="status")
    stored = await store.events.store_batch([statuses[0], statuses[3], gap_filler, record(seq=6)], T1)

    assert [(r.inserted, r.stored_message_id, r.pruned) for r in stored.results] == [
        (False, None, True),
        (False, statuses[3].message_id, False),
        (True, None, False),
        (True, None, False),
    ]
    assert sorted(r.seq for r in await store.events.find_events(EventQuery())) == [3, 6, 9]
    # a number in an open gap (4, 5, 7, 8) was never seen: it is stored when it comes
    late = await store.events.store_batch([record(seq=5, type="status")], T1)
    assert late.results[0].inserted and spans(await store.events.gaps()) == [
        ("explorer1", EPOCH, 4, 4),
        ("explorer1", EPOCH, 7, 8),
    ]


async def test_a_write_repeated_after_its_answer_was_lost_is_not_a_duplicate(store: Repositories) -> None:
    first = record(seq=5)
    await store.events.store_batch([first], T0)
    again = await store.events.store_batch([first], T0)  # the worker's retry: the very same record
    resent = replace(first, received_at=first.received_at + timedelta(seconds=3))  # the robot's resend
    later = await store.events.store_batch([resent], T1)
    assert [(r.inserted, r.rewritten, r.stored_message_id) for r in (*again.results, *later.results)] == [
        (False, True, first.message_id),
        (False, False, first.message_id),
    ]
