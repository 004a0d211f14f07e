"""The persistence port: what a repository asks of a database, implemented once per database
(:class:`~fleetbus.workers.store.sqlite.SQLiteStore`, :class:`~fleetbus.workers.store.mongo.MongoStore`).

Every repository is written once, over this port. It declares its collections (a
:class:`Schema`: typed fields, a key, indexes) and works on them through :class:`Collection`:
insert-unique, get by key, find and count and group by indexed fields, conditional update (on a
version, or on any filter), an atomic counter, insert-or-overwrite under a condition, delete. The
filter language is small and means the same on both databases: equality (``None`` matches a
null field), :class:`In`, :class:`NotIn`, :class:`Ne` (a null field is neither in a list nor
equal to a value) and :class:`Range`.

What each database gives, said once: SQLite has transactions, so :meth:`Database.transaction`
is one (``BEGIN IMMEDIATE`` ... ``COMMIT``, one fsync); MongoDB makes the write of one document
atomic, so there ``transaction`` runs the steps in turn. A unit of work is therefore written as
steps that are each atomic on one document (an insert-unique, an update conditional on what was
read, an increment) and that a retry completes when a worker died between two: the same code is
then correct on both, and SQLite makes the whole unit one commit.
"""

from __future__ import annotations

import abc
from collections.abc import Callable, Coroutine, Mapping, Sequence
from dataclasses import dataclass, field, replace
from datetime import datetime
from typing import Any, TypeVar

T = TypeVar("T")
Doc = dict[str, Any]
"""A document: field name to value (datetimes for :data:`TIME` fields)."""
Filter = Mapping[str, Any]
"""Field name to the value it must equal (``None``: null) or a :class:`Match`; all must hold."""
Work = Coroutine[Any, Any, T]


@dataclass(frozen=True)
class Kind:
    """A field's type, the same on every database."""

    name: str
    optional: bool = False
    """May be null (``None``)."""

    @property
    def maybe(self) -> Kind:
        return replace(self, optional=True)


TEXT = Kind("text")
INTEGER = Kind("integer")
REAL = Kind("real")
BOOL = Kind("bool")
JSON = Kind("json")
"""Any JSON value (a document, a list...): kept as JSON text on SQLite, as BSON on MongoDB."""
BYTES = Kind("bytes")
TIME = Kind("time")
"""A timezone-aware datetime, kept as integer microseconds since the epoch: exact and sortable
(BSON dates stop at milliseconds); read back in UTC."""

SERIAL = "serial"
"""The key field of a :attr:`Schema.serial` collection."""


@dataclass(frozen=True)
class Index:
    fields: tuple[str, ...]
    unique: bool = False

    def __init__(self, *fields: str, unique: bool = False) -> None:
        object.__setattr__(self, "fields", fields)
        object.__setattr__(self, "unique", unique)


@dataclass(frozen=True)
class Schema:
    """A collection (a table on SQLite): its fields, its key, and the indexes its queries use.

    A query that filters or sorts on fields other than a prefix of the key needs an index
    declared here; a database leaves out an index its key already gives it. A field added to a
    schema after its collection holds documents must be optional: those documents read it as null
    on every database (SQLite adds the column when it opens the file)."""

    name: str
    fields: Mapping[str, Kind]
    key: tuple[str, ...] = ()
    indexes: tuple[Index, ...] = ()
    serial: bool = False
    """The database numbers the documents 1, 2, 3... as they are inserted, in the field
    :data:`SERIAL` (the key): the order they were stored in, which a time cannot tell for
    documents of the same moment."""

    def __post_init__(self) -> None:
        if self.serial:
            object.__setattr__(self, "fields", {SERIAL: INTEGER, **self.fields})
            object.__setattr__(self, "key", (SERIAL,))
        if not self.key or not set(self.key) <= set(self.fields):
            raise ValueError(f"{self.name}: the key {self.key} must name fields")
        for index in self.indexes:
            if not set(index.fields) <= set(self.fields):
                raise ValueError(f"{self.name}: index {index.fields} names an unknown field")
            if index.unique and any(self.fields[name].optional for name in index.fields):
                # SQLite takes nulls as distinct, MongoDB as one value: neither is assumed
                raise ValueError(f"{self.name}: unique index {index.fields} on a field that may be null")

    def kind(self, name: str) -> Kind:
        try:
            return self.fields[name]
        except KeyError:
            raise ValueError(f"{self.name} has no field {name!r}") from None

    def key_of(self, doc: Mapping[str, Any]) -> tuple[Any, ...]:
        return tuple(doc[name] for name in self.key)


class Match:
    """A condition on one field other than equality."""


@dataclass(frozen=True)
class In(Match):
    values: tuple[Any, ...]

    def __init__(self, values: Sequence[Any] | set[Any] | frozenset[Any]) -> None:
        object.__setattr__(self, "values", tuple(values))


@dataclass(frozen=True)
class NotIn(Match):
    """None of these values (a null field matches)."""

    values: tuple[Any, ...]

    def __init__(self, values: Sequence[Any] | set[Any] | frozenset[Any]) -> None:
        object.__setattr__(self, "values", tuple(values))


@dataclass(frozen=True)
class Ne(Match):
    """Not this value (a null field matches, unless the value is ``None``: then any present one)."""

    value: Any


@dataclass(frozen=True)
class Range(Match):
    """Between bounds (those given); a null field is in no range."""

    gt: Any = None
    ge: Any = None
    lt: Any = None
    le: Any = None


@dataclass(frozen=True)
class Group:
    count: int
    highest: dict[str, Any] = field(default_factory=dict)


def descending(name: str) -> tuple[str, bool]:
    """An order's field name without its ``-``, and whether it is descending."""
    return (name[1:], True) if name.startswith("-") else (name, False)


class Collection(abc.ABC):
    """The documents of one :class:`Schema` on one database.

    ``order`` names fields, each ``-field`` for descending; ``fields`` chooses what a read
    returns (all when None)."""

    schema: Schema

    @abc.abstractmethod
    async def insert(self, docs: Sequence[Doc]) -> list[bool]:
        """Insert each document unless its key or a unique index's fields are taken (by a stored
        document or an earlier one of ``docs``): True for each inserted. A serial collection
        numbers them."""

    @abc.abstractmethod
    async def get(self, *key: Any) -> Doc | None:
        """The document under this key (its fields' values in the key's order)."""

    @abc.abstractmethod
    async def get_many(self, keys: Sequence[tuple[Any, ...]]) -> list[Doc | None]:
        """The document under each key, in order."""

    @abc.abstractmethod
    async def find(
        self,
        where: Filter | None = None,
        *,
        order: Sequence[str] = (),
        limit: int | None = None,
        skip: int = 0,
        fields: Sequence[str] | None = None,
    ) -> list[Doc]: ...

    @abc.abstractmethod
    async def count(self, where: Filter | None = None) -> int: ...

    @abc.abstractmethod
    async def group(
        self, by: str, where: Filter | None = None, *, highest: Sequence[str] = ()
    ) -> dict[Any, Group]:
        """The matching documents by the value of ``by``: how many, and the highest value of
        each of ``highest``."""

    @abc.abstractmethod
    async def first_each(
        self, by: str, values: Sequence[Any], *, order: Sequence[str], where: Filter | None = None
    ) -> dict[Any, Doc]:
        """For each of ``values`` of the field ``by``, the first matching document in ``order``
        (for those that have one): one query however many values, each read by an index on
        ``by`` and ``order``'s fields however many documents it has."""

    @abc.abstractmethod
    async def update(
        self, where: Filter, changes: Mapping[str, Any], *, add: Mapping[str, int] | None = None
    ) -> int:
        """Set ``changes`` and add ``add`` (numbers) in every matching document, each atomically;
        how many matched. ``where`` with a version read before makes a compare-and-set."""

    @abc.abstractmethod
    async def put(
        self, doc: Doc, *, overwrite: Sequence[str] | None = None, where: Filter | None = None
    ) -> bool:
        """Insert ``doc``; when its key is taken, set the stored document's ``overwrite`` fields
        (all but the key when None) to ``doc``'s, if it matches ``where``. Atomic; False: the
        stored document did not match."""

    @abc.abstractmethod
    async def increment(self, doc: Doc, counter: str, *, overwrite: Sequence[str] = ()) -> int:
        """Add ``doc[counter]`` to the stored document's ``counter`` and set its ``overwrite``
        fields, or insert ``doc`` when none is stored; atomic. The counter's new value."""

    @abc.abstractmethod
    async def delete(self, where: Filter, *, order: Sequence[str] = (), limit: int | None = None) -> int:
        """Delete the matching documents (the first ``limit`` of them in ``order``); how many."""


class Database(abc.ABC):
    """One database and the collections of every repository in it."""

    name: str
    """``sqlite`` or ``mongodb``."""
    any_loop: bool = False
    """Another thread's event loop may call this very database (see
    :attr:`~fleetbus.workers.store.repositories.Repositories.any_loop`)."""

    @abc.abstractmethod
    def collection(self, schema: Schema) -> Collection:
        """The collection of ``schema``, made (with its indexes) when the database is opened."""

    @abc.abstractmethod
    async def transaction(self, work: Callable[[], Work[T]], *, urgent: bool = False) -> T:
        """Run ``work()``: one transaction on SQLite, its steps in turn on MongoDB (see the
        module's docstring). ``urgent``: someone waits on it (a hazard on its way to the
        wardens): SQLite runs it on the caller's thread when it can. May run ``work()`` again
        after a conflict (it is written to be run again). Nested, it runs in the outer one."""

    @abc.abstractmethod
    async def let_urgent_calls_in(self) -> None:
        """Between two parts of a long unit of work: where urgent calls wait for it (SQLite's
        write lock), end the transaction with what is written, let them go first and begin
        again; each part is then whole on its own. Elsewhere nothing."""

    @abc.abstractmethod
    async def snapshot(self, work: Callable[[], Work[T]], *, urgent: bool = False) -> T:
        """Run ``work()``, which only reads: on SQLite, from one snapshot of the database."""

    @abc.abstractmethod
    async def open(self) -> None:
        """Connect, and make the collections and indexes declared so far (idempotent)."""

    @abc.abstractmethod
    async def close(self) -> None: ...

    @abc.abstractmethod
    def again(self) -> Database:
        """Another connection to the same database, not yet opened, without collections."""


COUNTERS = Schema("counters", {"name": TEXT, "last": INTEGER}, key=("name",))
"""Named counters (:func:`next_number`), and a serial collection's numbering on MongoDB."""


async def next_number(counters: Collection, name: str, by: int = 1) -> int:
    """Take the next ``by`` numbers of the counter ``name`` (the first is 1); the last taken."""
    return await counters.increment({"name": name, "last": by}, "last")


async def prune_oldest(
    log: Collection,
    time: str,
    before: datetime | None,
    keep: int | None,
    limit: int,
    *,
    order: str = SERIAL,
) -> int:
    """Up to ``limit`` of a log's oldest documents: older than ``before`` by ``time``, then beyond
    the newest ``keep`` in ``order`` (a serial log's order of storing, which has no ties)."""
    deleted = 0
    if before is not None:
        deleted += await log.delete({time: Range(lt=before)}, order=[time], limit=limit)
    if keep is not None and deleted < limit:
        beyond = await log.count() - keep
        if beyond > 0:
            doomed = min(beyond, limit - deleted)
            last = await log.find({}, order=[order], skip=doomed - 1, limit=1, fields=[order])
            # by value, not by the documents found: where a delete is not in one transaction with
            # the find (MongoDB), one made newer meanwhile (a numbering observed again) stays
            if last:
                cut = {order: Range(le=last[0][order])}
                deleted += await log.delete(cut, order=[order], limit=doomed)
    return deleted
