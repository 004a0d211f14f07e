"""The persistence port means the same on every database: what a repository written once relies on
(nulls in filters, unique indexes, conditional writes, counters, ordered deletes, units of work)."""

from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import AsyncExitStack, asynccontextmanager
from datetime import datetime, timedelta, timezone
from pathlib import Path

import pytest

from fleetbus.workers.store.mongo import MongoStore
from fleetbus.workers.store.port import (
    BOOL,
    BYTES,
    INTEGER,
    JSON,
    SERIAL,
    TEXT,
    TIME,
    Collection,
    Database,
    In,
    Index,
    Ne,
    NotIn,
    Range,
    Schema,
)
from fleetbus.workers.store.sqlite import SQLiteStore
from tests.store.conftest import fresh_database

T0 = datetime(2026, 3, 1, 12, 0, 0, 123456, tzinfo=timezone.utc)
THINGS = Schema(
    "things",
    {
        "area": TEXT,
        "number": INTEGER,
        "code": TEXT,
        "label": TEXT.maybe,
        "at": TIME.maybe,
        "flag": BOOL,
        "data": JSON.maybe,
        "blob": BYTES.maybe,
        "version": INTEGER,
    },
    key=("area", "number"),
    indexes=(Index("code", unique=True), Index("at")),
)
LOG = Schema("log", {"what": TEXT, "at": TIME}, serial=True, indexes=(Index("at"),))
COUNTS = Schema("counts", {"name": TEXT, "n": INTEGER, "first": TIME, "last": TIME}, key=("name",))


@asynccontextmanager
async def opened(store: Database) -> AsyncIterator[Database]:
    for schema in (THINGS, LOG, COUNTS):
        store.collection(schema)
    await store.open()
    try:
        yield store
    finally:
        await store.close()


@pytest.fixture(params=["sqlite", "mongodb"])
async def database(request: pytest.FixtureRequest, tmp_path: Path) -> AsyncIterator[Database]:
    if request.param == "sqlite":
        async with opened(SQLiteStore(tmp_path / "port.sqlite3")) as store:
            yield store
        return
    url: str = request.getfixturevalue("mongodb_url")
    async with fresh_database(url) as name, opened(MongoStore(url, name)) as store:
        yield store


def thing(number: int, **fields: object) -> dict[str, object]:
    return {
        "area": "a",
        "number": number,
        "code": f"c{number}",
        "label": None,
        "at": None,
        "flag": False,
        "data": None,
        "blob": None,
        "version": 0,
        **fields,
    }


async def test_every_kind_round_trips(database: Database) -> None:
    things = database.collection(THINGS)
    # JSON's integers past 64 bits too (a ROS uint64, 2**64 - 1), as exactly as the rest
    wide = {"a": [1, 2.5, None, "é"], "wide": [2**64 - 1, -(2**63) - 1, 10**30]}
    original = thing(1, label="x☢", at=T0, flag=True, data=wide, blob=b"\x00\xff")
    assert await things.insert([original]) == [True]
    assert await things.get("a", 1) == original
    assert await things.get("a", 2) is None
    assert await things.get_many([("a", 2), ("a", 1)]) == [None, original]
    [found] = await things.find(fields=["number", "at"])
    assert found == {"number": 1, "at": T0}


async def test_a_taken_key_or_unique_field_is_not_inserted(database: Database) -> None:
    things = database.collection(THINGS)
    assert await things.insert([thing(1, code="x"), thing(2), thing(1), thing(3, code="x"), thing(4)]) == [
        True,
        True,
        False,
        False,
        True,
    ]
    assert await things.insert([thing(2, label="other")]) == [False]
    assert (await things.get("a", 2))["label"] is None, "nothing stored changed"
    assert await things.count() == 3


async def test_filters_mean_the_same_with_nulls(database: Database) -> None:
    things = database.collection(THINGS)
    await things.insert([thing(1, label="x", at=T0), thing(2, label="y"), thing(3)])

    async def numbers(**where: object) -> list[int]:
        return [doc["number"] async for doc in _each(things, where)]

    assert await numbers(label=None) == [3]
    assert await numbers(label=Ne(None)) == [1, 2]
    assert await numbers(label=Ne("x")) == [2, 3], "a null field is not 'x'"
    assert await numbers(label=In(["x", None])) == [1, 3]
    assert await numbers(label=NotIn(["x"])) == [2, 3], "a null field is in no list"
    assert await numbers(label=NotIn(["x", None])) == [2]
    assert await numbers(at=Range(le=T0)) == [1], "a null field is in no range"
    assert await numbers(at=Range(gt=T0 - timedelta(microseconds=1), lt=T0 + timedelta(microseconds=1))) == [
        1
    ]
    assert await numbers(number=In(list(range(2, 500)))) == [2, 3], "a long list"
    assert await numbers(number=NotIn(list(range(2, 500)))) == [1]
    assert await numbers(area="a", number=2) == [2], "the whole key"
    assert await numbers(flag=False) == [1, 2, 3]


async def _each(collection: Collection, where: dict[str, object]):  # type: ignore[no-untyped-def]
    for doc in await collection.find(where, order=["number"]):
        yield doc


async def test_order_skip_and_limit(database: Database) -> None:
    things = database.collection(THINGS)
    await things.insert([thing(n, at=T0 + timedelta(seconds=n % 3)) for n in range(6)])
    found = await things.find(order=["-at", "number"], skip=1, limit=3)
    assert [doc["number"] for doc in found] == [5, 1, 4]
    assert [doc["number"] for doc in await things.find(order=["at", "-number"], limit=2)] == [3, 0]


async def test_updates_are_conditional_and_count_what_matched(database: Database) -> None:
    things = database.collection(THINGS)
    await things.insert([thing(1), thing(2)])
    assert (
        await things.update({"area": "a", "number": 1, "version": 0}, {"label": "x"}, add={"version": 1}) == 1
    )
    assert (
        await things.update({"area": "a", "number": 1, "version": 0}, {"label": "y"}, add={"version": 1}) == 0
    )
    assert (await things.get("a", 1))["label"] == "x" and (await things.get("a", 1))["version"] == 1
    assert await things.update({"area": "a"}, {"flag": True}) == 2
    assert await things.update({"number": 3}, {"flag": True}) == 0


async def test_put_inserts_or_overwrites_under_a_condition(database: Database) -> None:
    counts = database.collection(COUNTS)
    first = {"name": "c", "n": 1, "first": T0, "last": T0}
    assert await counts.put(first, overwrite=["n"], where={"last": Range(lt=T0)})
    later = {"name": "c", "n": 5, "first": T0 + timedelta(hours=1), "last": T0 + timedelta(hours=1)}
    assert not await counts.put(later, where={"last": Range(gt=T0)}), "the stored one does not match"
    assert await counts.get("c") == first
    assert await counts.put(later, overwrite=["n", "last"], where={"last": In([T0])})
    assert await counts.get("c") == {**later, "first": T0}
    assert await counts.put({**later, "n": 9})
    assert (await counts.get("c"))["n"] == 9


async def test_increments_are_atomic_counters(database: Database) -> None:
    counts = database.collection(COUNTS)
    row = {"name": "c", "n": 3, "first": T0, "last": T0}
    assert await counts.increment(row, "n", overwrite=["last"]) == 3
    assert (
        await counts.increment(
            {**row, "n": 2, "first": T0 + timedelta(1), "last": T0 + timedelta(1)}, "n", overwrite=["last"]
        )
        == 5
    )
    assert await counts.get("c") == {"name": "c", "n": 5, "first": T0, "last": T0 + timedelta(1)}


async def test_serial_collections_number_in_insertion_order(database: Database) -> None:
    log = database.collection(LOG)
    assert await log.insert([{"what": "a", "at": T0}, {"what": "b", "at": T0}]) == [True, True]
    await log.insert([{"what": "c", "at": T0 - timedelta(1)}])
    found = await log.find(order=["-" + SERIAL])
    assert [(doc[SERIAL], doc["what"]) for doc in found] == [(3, "c"), (2, "b"), (1, "a")]
    assert await log.delete({}, order=[SERIAL], limit=2) == 2
    assert [doc["what"] for doc in await log.find()] == ["c"]


async def test_deletes_go_first_in_order_up_to_a_limit(database: Database) -> None:
    things = database.collection(THINGS)
    await things.insert([thing(n, at=T0 + timedelta(seconds=-n)) for n in range(5)])
    assert await things.delete({"at": Range(lt=T0)}, order=["at"], limit=2) == 2
    assert [doc["number"] for doc in await things.find(order=["number"])] == [0, 1, 2]
    assert await things.delete({"number": In([0, 2, 7])}) == 2
    assert await things.delete({"number": 7}, order=["at"], limit=5) == 0
    assert await things.count() == 1


async def test_groups_count_and_take_the_highest(database: Database) -> None:
    things = database.collection(THINGS)
    await things.insert([thing(n, label=f"l{n}", at=T0 + timedelta(n), flag=n % 2 == 0) for n in range(5)])
    groups = await things.group("flag", highest=["at", "number"])
    assert {flag: (g.count, g.highest) for flag, g in groups.items()} == {
        True: (3, {"at": T0 + timedelta(4), "number": 4}),
        False: (2, {"at": T0 + timedelta(3), "number": 3}),
    }
    assert await things.group("flag", {"number": Range(gt=9)}) == {}


async def test_first_each_takes_each_values_first_document_in_order(database: Database) -> None:
    things = database.collection(THINGS)
    await things.insert(
        [
            thing(n, area=area, code=f"{area}{n}", at=T0 + timedelta(n), flag=n != 4)
            for area in "ab"
            for n in range(5)
        ]
    )
    newest = await things.first_each("area", ["a", "b", "c", "a"], order=["-at"])
    assert {area: doc["number"] for area, doc in newest.items()} == {"a": 4, "b": 4}
    assert newest["a"] == await things.get("a", 4)
    flagged = await things.first_each("area", ["b"], order=["-at"], where={"flag": True})
    assert {area: doc["number"] for area, doc in flagged.items()} == {"b": 3}
    assert await things.first_each("area", [], order=["at"]) == {}
    log = database.collection(LOG)
    await log.insert([{"what": what, "at": T0 + timedelta(n)} for n, what in enumerate("xyxy")])
    first = await log.first_each("what", ["x", "y"], order=["at"])
    assert {what: doc[SERIAL] for what, doc in first.items()} == {"x": 1, "y": 2}


async def test_a_unit_of_work_keeps_what_it_wrote_before_letting_urgent_calls_in(database: Database) -> None:
    things = database.collection(THINGS)

    async def work() -> None:
        await things.insert([thing(1)])
        await database.let_urgent_calls_in()
        await things.insert([thing(2)])

    await database.transaction(work)
    assert await things.count() == 2


async def test_a_unit_of_work_sees_its_own_writes(database: Database) -> None:
    things = database.collection(THINGS)

    async def work() -> int:
        await things.insert([thing(1)])
        await things.update({"area": "a", "number": 1}, {"label": "x"})
        return await things.count({"label": "x"})

    assert await database.transaction(work) == 1
    assert await database.snapshot(lambda: things.count({"label": "x"}), urgent=True) == 1


async def test_sqlite_rolls_a_failed_unit_back(tmp_path: Path) -> None:
    store = SQLiteStore(tmp_path / "port.sqlite3")
    things = store.collection(THINGS)
    await store.open()
    try:

        async def work() -> None:
            await things.insert([thing(1)])
            raise ValueError("refused")

        with pytest.raises(ValueError, match="refused"):
            await store.transaction(work, urgent=True)
        assert await things.count() == 0
    finally:
        await store.close()


@pytest.mark.parametrize("kind", ["sqlite", "mongodb"])
async def test_an_optional_field_added_later_reads_null_in_what_was_stored(
    kind: str, request: pytest.FixtureRequest, tmp_path: Path
) -> None:
    before = Schema("grown", {"name": TEXT, "n": INTEGER}, key=("name",))
    after = Schema("grown", {**before.fields, "extra": JSON.maybe}, key=("name",))
    required = Schema("grown", {**before.fields, "needed": TEXT}, key=("name",))

    @asynccontextmanager
    async def store_with(schema: Schema, name: str) -> AsyncIterator[Collection]:
        if kind == "sqlite":
            store: Database = SQLiteStore(tmp_path / "grown.sqlite3")
        else:
            store = MongoStore(request.getfixturevalue("mongodb_url"), name)
        collection = store.collection(schema)
        await store.open()
        try:
            yield collection
        finally:
            await store.close()

    async with AsyncExitStack() as stack:
        name = ""
        if kind == "mongodb":
            name = await stack.enter_async_context(fresh_database(request.getfixturevalue("mongodb_url")))
        async with store_with(before, name) as grown:
            await grown.insert([{"name": "old", "n": 1}])
        async with store_with(after, name) as grown:
            assert await grown.get("old") == {"name": "old", "n": 1, "extra": None}
            await grown.insert([{"name": "new", "n": 2, "extra": ["a"]}])
            assert await grown.get("new") == {"name": "new", "n": 2, "extra": ["a"]}
            assert await grown.update({"name": "old"}, {"extra": {"b": 1}}) == 1
            assert (await grown.get("old"))["extra"] == {"b": 1}
        if kind == "sqlite":  # MongoDB has no columns: a required field is the repository's to fill
            with pytest.raises(ValueError, match="required field 'needed'"):
                async with store_with(required, name) as grown:
                    await grown.get("old")
