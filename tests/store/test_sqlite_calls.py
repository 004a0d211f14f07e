"""Where SQLite calls run: urgent small ones on the caller's thread, on a connection of their own
that never waits for the write lock; the rest (and any that finds another process writing) on the
store's thread, which waits for it; and what a stored batch does in its one transaction."""

from __future__ import annotations

import asyncio
import sqlite3
import threading
from dataclasses import replace
from datetime import timedelta
from pathlib import Path

from fleetbus.workers.store.hazards import NewHazard
from fleetbus.workers.store.repositories import Repositories
from fleetbus.workers.store.sqlite import sqlite_repositories
from fleetbus.workers.store.sqlite_database import in_transaction
from tests.store.test_contract import EPOCH, T0, record


async def hold_store_thread(store: Repositories, write: bool) -> tuple[asyncio.Future[None], threading.Event]:
    """A call that keeps the store's thread (inside a write transaction if ``write``) until released;
    returns once it runs."""
    running, release = threading.Event(), threading.Event()

    def hold(db: sqlite3.Connection) -> None:
        running.set()
        release.wait(30)

    call = asyncio.ensure_future(
        store.events._database._run(lambda db: in_transaction(db, lambda: hold(db)) if write else hold(db))
    )
    assert await asyncio.to_thread(running.wait, 30)
    return call, release


async def test_an_urgent_batch_finding_the_database_locked_waits_off_the_event_loop(tmp_path: Path) -> None:
    path = tmp_path / "store.sqlite3"
    async with sqlite_repositories(path, busy_timeout=30) as store:
        locker = sqlite3.connect(path, isolation_level=None)
        locker.execute("BEGIN IMMEDIATE")  # another process writing
        try:
            write = asyncio.create_task(store.events.store_batch([record(seq=0)], T0, urgent=True))
            await asyncio.sleep(0)  # the task's first step: the attempt here, then the hand-over
            # neither failed at once on the lock nor blocked this loop until the busy timeout
            assert not write.done()
        finally:
            locker.execute("COMMIT")
            locker.close()
        stored = await asyncio.wait_for(write, 30)
        assert stored.results[0].inserted and await store.events.count_events() == 1


async def test_calls_from_two_threads_never_share_the_connection_at_once(tmp_path: Path) -> None:
    async with sqlite_repositories(tmp_path / "store.sqlite3") as store:
        errors: list[BaseException] = []

        def robot(name: str) -> None:
            async def writes() -> None:
                for seq in range(150):
                    stored = await store.events.store_batch([record(name, seq)], T0, urgent=True)
                    assert stored.results[0].inserted
                    await store.hazards.set_localised(name, seq % 2 == 0, T0)

            try:
                asyncio.run(writes())
            except BaseException as error:  # reported by the test's own thread
                errors.append(error)

        threads = [threading.Thread(target=robot, args=(f"robot{i}",)) for i in range(2)]
        for thread in threads:
            thread.start()
        await asyncio.to_thread(lambda: [thread.join(60) for thread in threads])
        assert errors == []
        assert await store.events.count_events() == 300
        assert (
            await store.events.high_water("robot0", EPOCH) == 149
            and await store.events.high_water("robot1", EPOCH) == 149
        )
        assert await store.events.gaps() == []


async def test_holding_a_registered_hazard_again_only_reads(tmp_path: Path) -> None:
    path = tmp_path / "store.sqlite3"
    async with sqlite_repositories(path, busy_timeout=30) as store:
        hazard = record(seq=3)
        stored = await store.events.store_batch([record(seq=2, type="status"), hazard], T0, urgent=True)
        [held] = (await store.hazards.hold_hazards([NewHazard.of(stored.records[1])])).hazards
        assert (held.robot_id, held.seq, held.hazard_id) == (hazard.robot_id, 3, 1)
        locker = sqlite3.connect(path, isolation_level=None)
        locker.execute("BEGIN IMMEDIATE")  # another process writing: a write would wait for it
        try:
            again = await asyncio.wait_for(store.hazards.hold_hazards([NewHazard.of(stored.records[1])]), 5)
        finally:
            locker.execute("COMMIT")
            locker.close()
        assert [h.hazard_id for h in again.hazards] == [1]


async def test_a_reused_sequence_number_registers_no_hazard(tmp_path: Path) -> None:
    async with sqlite_repositories(tmp_path / "store.sqlite3") as store:
        await store.events.store_batch([record(seq=0, type="status")], T0)
        reused = replace(record(seq=0), message_id="another")
        stored = await store.events.store_batch([reused], T0, urgent=True)
        assert not stored.results[0].inserted
        assert await store.hazards.held_hazards() == []


async def test_an_urgent_write_waits_for_the_bulk_write_in_hand_not_for_the_queue(tmp_path: Path) -> None:
    async with sqlite_repositories(tmp_path / "store.sqlite3") as store:
        bulk, release_bulk = await hold_store_thread(store, write=True)  # a bulk batch being written
        # a read on the way (the wardens' gate, the held list) does not wait for the writer
        assert (await asyncio.wait_for(store.hazards.hold_hazards([]), 5)).hazards == []
        urgent = asyncio.create_task(store.events.store_batch([record(seq=0)], T0, urgent=True))
        release_queued = threading.Event()
        queued = asyncio.ensure_future(store.events._database._run(lambda db: release_queued.wait(30)))
        for _ in range(20):
            await asyncio.sleep(0)
        assert not urgent.done(), "SQLite has one writer: the urgent write waits for the bulk one"
        release_bulk.set()
        await bulk
        # the store's thread went on to the queued call, which keeps it; the urgent write is not
        # queued behind that: it is written on the caller's thread once the write lock is free
        stored = await asyncio.wait_for(urgent, 5)
        assert stored.results[0].inserted and not queued.done()
        release_queued.set()
        await queued


async def test_an_urgent_write_goes_in_between_two_parts_of_a_bulk_write(tmp_path: Path) -> None:
    """A bulk batch is written in parts; a hazard's write waiting for the lock goes between two
    (the parts before it committed), not after the whole batch."""
    async with sqlite_repositories(tmp_path / "store.sqlite3") as store:
        database = store.events._database
        first_part, release, finish = threading.Event(), threading.Event(), threading.Event()

        def bulk(db: sqlite3.Connection) -> None:
            db.execute("CREATE TABLE IF NOT EXISTS parts (n INTEGER)")
            db.execute("INSERT INTO parts VALUES (1)")
            first_part.set()
            release.wait(30)  # the urgent write is waiting by now
            database.let_small_calls_in(db)
            db.execute("INSERT INTO parts VALUES (2)")
            finish.wait(30)

        writing = asyncio.ensure_future(database._run(lambda db: in_transaction(db, lambda: bulk(db))))
        assert await asyncio.to_thread(first_part.wait, 30)
        urgent = asyncio.create_task(store.events.store_batch([record(seq=0)], T0, urgent=True))
        for _ in range(20):
            await asyncio.sleep(0)
        assert not urgent.done(), "the first part holds the write lock"
        release.set()
        stored = await asyncio.wait_for(urgent, 5)
        assert stored.results[0].inserted and not writing.done(), "in before the bulk write's end"
        finish.set()
        await asyncio.wait_for(writing, 30)
        assert await database._run(lambda db: db.execute("SELECT count(*) FROM parts").fetchone()[0]) == 2


async def test_each_robots_newest_of_a_type_is_a_seek_however_many_the_fleet_sent(tmp_path: Path) -> None:
    """Robots that sent no status: their newest status is found by a seek each, not by walking every
    status of the fleet (what SQLite did with only the type's index: seconds with 1,000 robots)."""
    async with sqlite_repositories(tmp_path / "store.sqlite3") as store:
        at = [T0 + timedelta(milliseconds=seq) for seq in range(5000)]
        statuses = [record("explorer1", seq, "status", when) for seq, when in enumerate(at)]
        await store.events.write_events(statuses)
        guides = [f"guide{i}" for i in range(50)]
        await store.events.write_events([record(name, 0, "localisation", T0) for name in guides])
        steps = 0

        def counted() -> int:
            nonlocal steps
            steps += 1
            return 0  # go on

        run = store.events._database._run  # the store's thread's connection, where reads run
        await run(lambda db: db.set_progress_handler(counted, 100))
        try:
            assert await store.events.newest_events(guides, "status") == {}
        finally:
            await run(lambda db: db.set_progress_handler(None, 0))
    # 100 virtual machine steps a count: a seek a robot is a few counts in all, a walk of the
    # fleet's statuses for each robot thousands
    assert steps < 200, f"{steps * 100:,} steps for 50 robots' newest status"
