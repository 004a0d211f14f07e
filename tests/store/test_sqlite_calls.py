"""Where SQLite calls run: urgent small ones on the caller's thread when the database is free, the
rest (and any that finds another process writing) on the store's thread, which waits for the lock;
and what a stored batch does in its one transaction."""

from __future__ import annotations

import asyncio
import sqlite3
import threading
from dataclasses import replace
from pathlib import Path

from tests.store.test_contract import T0, record
from workers.store.hazards import NewHazard
from workers.store.sqlite import SQLiteEventStore


async def test_an_urgent_batch_finding_the_database_locked_waits_off_the_event_loop(tmp_path: Path) -> None:
    path = tmp_path / "store.sqlite3"
    async with SQLiteEventStore(path, busy_timeout=30) as store:
        locker = sqlite3.connect(path, isolation_level=None)
        locker.execute("BEGIN IMMEDIATE")  # another process writing
        try:
            write = asyncio.create_task(store.store_batch([record(seq=0)], T0, urgent=True))
            await asyncio.sleep(0)  # the task's first step: the attempt here, then the hand-over
            # neither failed at once on the lock nor blocked this loop until the busy timeout
            assert not write.done()
        finally:
            locker.execute("COMMIT")
            locker.close()
        stored = await asyncio.wait_for(write, 30)
        assert stored.results[0].inserted and await store.count_events() == 1


async def test_calls_from_two_threads_never_share_the_connection_at_once(tmp_path: Path) -> None:
    async with SQLiteEventStore(tmp_path / "store.sqlite3") as store:
        errors: list[BaseException] = []

        def robot(name: str) -> None:
            async def writes() -> None:
                for seq in range(150):
                    stored = await store.store_batch([record(name, seq)], T0, urgent=True)
                    assert stored.results[0].inserted
                    await store.set_localised(name, seq % 2 == 0, T0)

            try:
                asyncio.run(writes())
            except BaseException as error:  # reported by the test's own thread
                errors.append(error)

        threads = [threading.Thread(target=robot, args=(f"robot{i}",)) for i in range(2)]
        for thread in threads:
            thread.start()
        await asyncio.to_thread(lambda: [thread.join(60) for thread in threads])
        assert errors == []
        assert await store.count_events() == 300
        assert await store.high_water("robot0") == 149 and await store.high_water("robot1") == 149
        assert await store.gaps() == []


async def test_a_stored_hazard_is_registered_in_the_same_transaction_and_holding_it_only_reads(
    tmp_path: Path,
) -> None:
    path = tmp_path / "store.sqlite3"
    async with SQLiteEventStore(path, busy_timeout=30) as store:
        hazard = record(seq=3)
        stored = await store.store_batch([record(seq=2, type="status"), hazard], T0, urgent=True)
        [held] = await store.held_hazards()
        assert (held.robot_id, held.seq, held.hazard_id) == (hazard.robot_id, 3, 1)
        assert held.event == NewHazard.of(stored.records[1]).event
        locker = sqlite3.connect(path, isolation_level=None)
        locker.execute("BEGIN IMMEDIATE")  # another process writing: a write would wait for it
        try:
            again = await asyncio.wait_for(store.hold_hazards([NewHazard.of(stored.records[1])]), 5)
        finally:
            locker.execute("COMMIT")
            locker.close()
        assert [h.hazard_id for h in again.hazards] == [1]


async def test_a_reused_sequence_number_registers_no_hazard(tmp_path: Path) -> None:
    async with SQLiteEventStore(tmp_path / "store.sqlite3") as store:
        await store.store_batch([record(seq=0, type="status")], T0)
        reused = replace(record(seq=0), message_id="another")
        stored = await store.store_batch([reused], T0, urgent=True)
        assert not stored.results[0].inserted
        assert await store.held_hazards() == []
