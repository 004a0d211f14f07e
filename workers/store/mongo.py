"""The persistence port on MongoDB: a collection is a collection, its key the ``_id``.

A one-field key is the ``_id`` itself; a key of several fields is the ``_id`` as a document of
them (in the key's order), each kept beside it too, for the indexes and sorts that name them. A
unit of work runs its steps in turn: each is one atomic operation on one document. A serial
collection is numbered from a counter (:data:`~fleetbus.workers.store.port.COUNTERS`), one
increment per insert.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any, TypeVar

from pymongo import ASCENDING, DESCENDING, ReturnDocument
from pymongo.errors import BulkWriteError, DuplicateKeyError, PyMongoError

from fleetbus.workers.store.base import StoreUnavailable, from_micros, to_micros
from fleetbus.workers.store.compose import repositories_on
from fleetbus.workers.store.mongo_database import (
    DUPLICATE_KEY,
    MongoDatabase,
    raise_as_store_error,
    translate_unavailable,
)
from fleetbus.workers.store.port import (
    COUNTERS,
    SERIAL,
    TIME,
    Collection,
    Database,
    Doc,
    Filter,
    Group,
    In,
    Ne,
    NotIn,
    Range,
    Schema,
    Work,
    descending,
    next_number,
)
from fleetbus.workers.store.repositories import Repositories

T = TypeVar("T")
ID = "_id"
OPERATORS = {"gt": "$gt", "ge": "$gte", "lt": "$lt", "le": "$lte"}


class MongoStore(MongoDatabase, Database):
    """One MongoDB database (one client) and the collections declared on it."""

    name = "mongodb"

    def __init__(self, url: str, database: str | None = None, server_selection_timeout: float = 5.0) -> None:
        super().__init__(url, database, server_selection_timeout)
        self._server_selection_timeout = server_selection_timeout
        self._schemas: dict[str, Schema] = {}
        self._counters: MongoCollection | None = None

    def collection(self, schema: Schema) -> MongoCollection:
        if self._schemas.setdefault(schema.name, schema) != schema:
            raise ValueError(f"two schemas named {schema.name}")
        return MongoCollection(self, schema)

    def counters(self) -> MongoCollection:
        if self._counters is None:
            self._counters = self.collection(COUNTERS)
        return self._counters

    async def transaction(self, work: Callable[[], Work[T]], *, urgent: bool = False) -> T:
        return await work()

    async def snapshot(self, work: Callable[[], Work[T]], *, urgent: bool = False) -> T:
        return await work()

    async def let_urgent_calls_in(self) -> None:
        """Each step is a transaction of its own already."""

    async def open(self) -> None:
        self._connect()
        try:
            for schema in self._schemas.values():
                collection = self._collection(schema.name)
                for index in schema.indexes:
                    keys = [(_stored_name(schema, name), ASCENDING) for name in index.fields]
                    await collection.create_index(keys, unique=index.unique)
        except PyMongoError as error:
            raise_as_store_error(error, self._safe_url())

    def again(self) -> MongoStore:
        return MongoStore(self.url, self._database_name, self._server_selection_timeout)


def _stored_name(schema: Schema, name: str) -> str:
    """A field's name in the document: a one-field key is the ``_id``."""
    schema.kind(name)
    return ID if schema.key == (name,) else name


@translate_unavailable(Collection)
class MongoCollection(Collection):
    def __init__(self, store: MongoStore, schema: Schema) -> None:
        self._store = store
        self.schema = schema
        self._times = {name for name, kind in schema.fields.items() if kind.name == TIME.name}
        self._single = schema.key[0] if len(schema.key) == 1 else None

    def _collection(self) -> Any:
        return self._store._collection(self.schema.name)

    def _safe_url(self) -> str:
        return self._store._safe_url()

    # encoding

    def _value(self, name: str, value: Any) -> Any:
        return to_micros(value) if value is not None and name in self._times else value

    def _id(self, key: Sequence[Any]) -> Any:
        if self._single is not None:
            return self._value(self._single, key[0])
        return {name: self._value(name, value) for name, value in zip(self.schema.key, key, strict=True)}

    def _document(self, doc: Mapping[str, Any]) -> Doc:
        stored: Doc = {ID: self._id(self.schema.key_of(doc))}
        for name in self.schema.fields:
            if name != self._single:
                stored[name] = self._value(name, doc.get(name))
        return stored

    def _decode(self, stored: Mapping[str, Any], names: Sequence[str]) -> Doc:
        doc = {}
        for name in names:
            value = stored.get(ID if name == self._single else name)
            doc[name] = from_micros(value) if value is not None and name in self._times else value
        return doc

    def _filter(self, where: Filter | None) -> Doc:
        if not where:
            return {}
        query: Doc = {}
        plain = {
            name: match for name, match in where.items() if not isinstance(match, In | NotIn | Ne | Range)
        }
        if self._single is None and all(name in plain for name in self.schema.key):
            query[ID] = self._id([plain[name] for name in self.schema.key])
            where = {name: match for name, match in where.items() if name not in self.schema.key}
        for name, match in where.items():
            stored = _stored_name(self.schema, name)
            if isinstance(match, In):
                query[stored] = {"$in": [self._value(name, value) for value in match.values]}
            elif isinstance(match, NotIn):
                query[stored] = {"$nin": [self._value(name, value) for value in match.values]}
            elif isinstance(match, Ne):
                query[stored] = {"$ne": self._value(name, match.value)}
            elif isinstance(match, Range):
                bounds = {
                    operator: self._value(name, getattr(match, bound))
                    for bound, operator in OPERATORS.items()
                    if getattr(match, bound) is not None
                }
                # a null is in no range (MongoDB's type bracketing says so; not every server does)
                query[stored] = {**bounds, "$ne": None}
            else:
                query[stored] = self._value(name, match)
        return query

    def _sort(self, order: Sequence[str]) -> list[tuple[str, int]]:
        sort = []
        for term in order:
            name, down = descending(term)
            sort.append((_stored_name(self.schema, name), DESCENDING if down else ASCENDING))
        return sort

    def _cursor(
        self,
        where: Filter | None,
        order: Sequence[str] = (),
        limit: int | None = None,
        skip: int = 0,
        fields: Sequence[str] | None = None,
    ) -> Any:
        projection = None if fields is None else [_stored_name(self.schema, name) for name in fields]
        cursor = self._collection().find(self._filter(where), projection)
        if order:
            cursor = cursor.sort(self._sort(order))
        if skip:
            cursor = cursor.skip(skip)
        if limit is not None:
            cursor = cursor.limit(limit)
        return cursor

    # the port

    async def insert(self, docs: Sequence[Doc]) -> list[bool]:
        if not docs:
            return []
        if self.schema.serial:
            last = await next_number(self._store.counters(), f"{SERIAL}:{self.schema.name}", len(docs))
            docs = [{**doc, SERIAL: last - len(docs) + 1 + index} for index, doc in enumerate(docs)]
        inserted = [True] * len(docs)
        try:
            await self._collection().insert_many([self._document(doc) for doc in docs], ordered=False)
        except BulkWriteError as error:
            if error.details.get("writeConcernErrors"):
                # reached the primary but not known durable: not safe to ack (a retry is harmless)
                raise StoreUnavailable(
                    f"MongoDB at {self._safe_url()}: write concern not met: "
                    f"{error.details['writeConcernErrors']}"
                ) from error
            errors = error.details.get("writeErrors", [])
            if any(e.get("code") != DUPLICATE_KEY for e in errors):
                raise
            for e in errors:
                inserted[e["index"]] = False
        return inserted

    async def get(self, *key: Any) -> Doc | None:
        stored = await self._collection().find_one({ID: self._id(key)})
        return None if stored is None else self._decode(stored, list(self.schema.fields))

    async def get_many(self, keys: Sequence[tuple[Any, ...]]) -> list[Doc | None]:
        if not keys:
            return []
        ids = [self._id(key) for key in keys]
        found = {}
        async for stored in self._collection().find({ID: {"$in": ids}}):
            doc = self._decode(stored, list(self.schema.fields))
            found[self.schema.key_of(doc)] = doc
        return [found.get(tuple(key)) for key in keys]

    async def find(
        self,
        where: Filter | None = None,
        *,
        order: Sequence[str] = (),
        limit: int | None = None,
        skip: int = 0,
        fields: Sequence[str] | None = None,
    ) -> list[Doc]:
        names = list(self.schema.fields) if fields is None else list(fields)
        return [
            self._decode(stored, names) async for stored in self._cursor(where, order, limit, skip, fields)
        ]

    async def count(self, where: Filter | None = None) -> int:
        counted: int = await self._collection().count_documents(self._filter(where))
        return counted

    async def group(
        self, by: str, where: Filter | None = None, *, highest: Sequence[str] = ()
    ) -> dict[Any, Group]:
        stage: Doc = {ID: f"${_stored_name(self.schema, by)}", "n": {"$sum": 1}}
        for index, name in enumerate(highest):
            stage[f"h{index}"] = {"$max": f"${_stored_name(self.schema, name)}"}
        groups = {}
        async for row in await self._collection().aggregate(
            [{"$match": self._filter(where)}, {"$group": stage}]
        ):
            stored = {_stored_name(self.schema, name): row[f"h{i}"] for i, name in enumerate(highest)}
            value = self._decode({_stored_name(self.schema, by): row[ID]}, [by])[by]
            groups[value] = Group(row["n"], self._decode(stored, highest))
        return groups

    async def first_each(
        self, by: str, values: Sequence[Any], *, order: Sequence[str], where: Filter | None = None
    ) -> dict[Any, Doc]:
        if not values:
            return {}
        stored_by = _stored_name(self.schema, by)
        match = {**self._filter(where), stored_by: {"$in": [self._value(by, value) for value in values]}}
        # sorted by the index on (by, order...), $first keeps each value's first document
        pipeline = [
            {"$match": match},
            {"$sort": dict([(stored_by, ASCENDING), *self._sort(order)])},
            {"$group": {ID: f"${stored_by}", "first": {"$first": "$$ROOT"}}},
        ]
        names = list(self.schema.fields)
        found = await self._collection().aggregate(pipeline)
        docs = [self._decode(row["first"], names) async for row in found]
        return {doc[by]: doc for doc in docs}

    async def update(
        self, where: Filter, changes: Mapping[str, Any], *, add: Mapping[str, int] | None = None
    ) -> int:
        update: Doc = {}
        if changes:
            update["$set"] = {_stored_name(self.schema, n): self._value(n, v) for n, v in changes.items()}
        if add:
            update["$inc"] = {_stored_name(self.schema, name): by for name, by in add.items()}
        result = await self._collection().update_many(self._filter(where), update)
        matched: int = result.matched_count
        return matched

    async def put(
        self, doc: Doc, *, overwrite: Sequence[str] | None = None, where: Filter | None = None
    ) -> bool:
        stored = self._document(doc)
        changed = (
            [name for name in stored if name != ID and name not in self.schema.key]
            if overwrite is None
            else list(overwrite)
        )
        if not changed:
            raise ValueError("put overwrites at least one field (insert() keeps what is stored)")
        update: Doc = {"$set": {name: stored.pop(name) for name in changed}}
        stored.pop(ID)
        if stored:
            update["$setOnInsert"] = stored
        # when the stored document does not match, the upsert tries to insert a second one
        # under the same _id, which the unique _id refuses
        matching = {**self._filter(where), ID: self._id(self.schema.key_of(doc))}
        try:
            await self._collection().update_one(matching, update, upsert=True)
        except DuplicateKeyError:
            # or another writer inserted it between this upsert's look and its insert (two first
            # writes at once): the document there now may match, and is then written over
            changed_only = {"$set": update["$set"]}
            return bool((await self._collection().update_one(matching, changed_only)).matched_count)
        return True

    async def increment(self, doc: Doc, counter: str, *, overwrite: Sequence[str] = ()) -> int:
        stored = self._document(doc)
        key = stored.pop(ID)
        update: Doc = {"$inc": {counter: stored.pop(counter)}}
        if overwrite:
            update["$set"] = {name: stored.pop(name) for name in overwrite}
        if stored:
            update["$setOnInsert"] = stored
        after = await self._collection().find_one_and_update(
            {ID: key}, update, upsert=True, return_document=ReturnDocument.AFTER
        )
        value: int = after[counter]
        return value

    async def delete(self, where: Filter, *, order: Sequence[str] = (), limit: int | None = None) -> int:
        query = self._filter(where)
        if order or limit is not None:
            ids = [
                stored[ID] async for stored in self._cursor(where, order, limit, fields=[self.schema.key[0]])
            ]
            if not ids:
                return 0
            query = {**query, ID: {"$in": ids}}
        result = await self._collection().delete_many(query)
        deleted: int = result.deleted_count
        return deleted


def mongo_repositories(
    url: str, database: str | None = None, server_selection_timeout: float = 5.0
) -> Repositories:
    """Every repository over one MongoDB database (one client), not yet opened."""
    return repositories_on(MongoStore(url, database, server_selection_timeout))
