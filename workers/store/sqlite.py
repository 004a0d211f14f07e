"""The persistence port on SQLite: a collection is a table, its fields columns, its key the
primary key; a unit of work is one transaction.

Calls run as :class:`~fleetbus.workers.store.sqlite_database.SQLiteDatabase` runs them: on the
store's thread, or (urgent ones) on the caller's. A unit of work (:meth:`SQLiteStore.transaction`)
is a coroutine over the port; here every call of the port inside it runs at once on the unit's
connection, so the coroutine never waits and runs to its end on that thread, inside one
``BEGIN IMMEDIATE`` ... ``COMMIT``.
"""

from __future__ import annotations

import json
import sqlite3
import threading
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, TypeVar

from fleetbus.workers.store.base import from_micros, to_micros
from fleetbus.workers.store.compose import repositories_on
from fleetbus.workers.store.port import (
    BOOL,
    BYTES,
    INTEGER,
    JSON,
    REAL,
    SERIAL,
    TEXT,
    TIME,
    Collection,
    Database,
    Doc,
    Filter,
    Group,
    In,
    Kind,
    Ne,
    NotIn,
    Range,
    Schema,
    Work,
    descending,
)
from fleetbus.workers.store.repositories import Repositories
from fleetbus.workers.store.sqlite_database import SQLiteDatabase, in_transaction

T = TypeVar("T")

COLUMN_TYPES = {
    TEXT.name: "TEXT",
    INTEGER.name: "INTEGER",
    REAL.name: "REAL",
    BOOL.name: "INTEGER",
    JSON.name: "TEXT",
    BYTES.name: "BLOB",
    TIME.name: "INTEGER",
}
#: Up to this many values are bound one by one in ``IN (...)``; more go as one JSON array.
LISTED = 200
RANGES = (("gt", ">"), ("ge", ">="), ("lt", "<"), ("le", "<="))


def _dumps(value: Any) -> str:
    return json.dumps(value, separators=(",", ":"), ensure_ascii=False)


def _encoder(kind: Kind) -> Callable[[Any], Any] | None:
    if kind.name == JSON.name:
        return lambda value: None if value is None else _dumps(value)
    if kind.name == TIME.name:
        return lambda value: None if value is None else to_micros(value)
    if kind.name == BOOL.name:
        return lambda value: None if value is None else int(value)
    return None


def _decoder(kind: Kind) -> Callable[[Any], Any] | None:
    if kind.name == JSON.name:
        return lambda value: None if value is None else json.loads(value)
    if kind.name == TIME.name:
        return lambda value: None if value is None else from_micros(value)
    if kind.name == BOOL.name:
        return lambda value: None if value is None else bool(value)
    return None


def quoted(name: str) -> str:
    return f'"{name}"'


def _has_rowid(schema: Schema) -> bool:
    """Rows are kept in their primary key's B-tree alone, as the event log's are (one tree to
    write, not two); a serial table numbers them by rowid, and one with blobs keeps its rowid
    (rows that large do not belong in a key's tree)."""
    return schema.serial or any(kind.name == BYTES.name for kind in schema.fields.values())


def ddl(schema: Schema) -> str:
    """The table and its indexes (those its primary key does not already give)."""
    table = quoted(schema.name)
    columns = []
    for name, kind in schema.fields.items():
        if schema.serial and name == SERIAL:
            columns.append(f"{quoted(name)} INTEGER PRIMARY KEY AUTOINCREMENT")
            continue
        columns.append(f"{quoted(name)} {COLUMN_TYPES[kind.name]}{'' if kind.optional else ' NOT NULL'}")
    if not schema.serial:
        columns.append(f"PRIMARY KEY ({', '.join(map(quoted, schema.key))})")
    rowid = "" if _has_rowid(schema) else " WITHOUT ROWID"
    statements = [f"CREATE TABLE IF NOT EXISTS {table} ({', '.join(columns)}){rowid}"]
    for index in schema.indexes:
        if not index.unique and schema.key[: len(index.fields)] == index.fields:
            continue  # the primary key's own order
        name = quoted(f"{schema.name}__{'_'.join(index.fields)}")
        unique = "UNIQUE " if index.unique else ""
        fields = ", ".join(map(quoted, index.fields))
        statements.append(f"CREATE {unique}INDEX IF NOT EXISTS {name} ON {table} ({fields})")
    return ";\n".join(statements) + ";\n"


def added_fields(db: sqlite3.Connection, schema: Schema) -> list[str]:
    """Add to an existing table the optional fields its schema gained since it was made (null in
    the rows already there, as MongoDB reads a field its documents lack); the names added."""
    table = quoted(schema.name)
    present = {row[1] for row in db.execute(f"PRAGMA table_info({table})")}
    added = []
    for name, kind in schema.fields.items():
        if name in present:
            continue
        if not kind.optional:
            raise ValueError(
                f"{schema.name}: the table lacks the required field {name!r} "
                "(a field added later must be optional)"
            )
        try:
            db.execute(f"ALTER TABLE {table} ADD COLUMN {quoted(name)} {COLUMN_TYPES[kind.name]}")
        except sqlite3.OperationalError as error:
            if "duplicate column" not in str(error):  # another process added it first
                raise
            continue
        added.append(name)
    return added


def _finish(work: Work[T]) -> T:
    """Run a unit of work's coroutine to its end here: on SQLite the port's calls never wait."""
    try:
        work.send(None)
    except StopIteration as done:
        return done.value  # type: ignore[no-any-return]
    work.close()
    raise RuntimeError("a unit of work on SQLite waited for something other than the store")


class SQLiteStore(SQLiteDatabase, Database):
    """One SQLite file and the tables of the collections declared on it."""

    name = "sqlite"
    any_loop = True

    def __init__(self, path: Path, busy_timeout: float = 2.0) -> None:
        super().__init__(path, busy_timeout)
        self._schemas: dict[str, Schema] = {}
        self._unit = threading.local()
        """The connection of the unit of work running on this thread, if one is."""

    def collection(self, schema: Schema) -> SQLiteCollection:
        if self._schemas.setdefault(schema.name, schema) != schema:
            raise ValueError(f"two schemas named {schema.name}")
        return SQLiteCollection(self, schema)

    def _prepare(self, db: sqlite3.Connection) -> None:
        for schema in self._schemas.values():
            db.executescript(ddl(schema))
            added_fields(db, schema)

    def again(self) -> SQLiteStore:
        return SQLiteStore(self.path, self._busy_timeout)

    def _connection(self) -> sqlite3.Connection | None:
        db: sqlite3.Connection | None = getattr(self._unit, "db", None)
        return db

    async def call(self, work: Callable[[sqlite3.Connection], T], *, write: bool) -> T:
        """One call of the port: at once inside a unit of work; else on its own (a write in a
        transaction of its own)."""
        db = self._connection()
        if db is not None:
            return work(db)
        if write:
            return await self._run(lambda db: in_transaction(db, lambda: work(db)))
        return await self._run(work)

    async def transaction(self, work: Callable[[], Work[T]], *, urgent: bool = False) -> T:
        return await self._unit_of_work(work, urgent, "BEGIN IMMEDIATE")

    async def snapshot(self, work: Callable[[], Work[T]], *, urgent: bool = False) -> T:
        return await self._unit_of_work(work, urgent, "BEGIN")

    async def let_urgent_calls_in(self) -> None:
        db = self._connection()
        if db is not None:
            self.let_small_calls_in(db)

    async def _unit_of_work(self, work: Callable[[], Work[T]], urgent: bool, begin: str) -> T:
        if self._connection() is not None:
            return await work()

        def run(db: sqlite3.Connection) -> T:
            self._unit.db = db
            try:
                db.execute(begin)
                result = _finish(work())
                db.execute("COMMIT")
                return result
            finally:
                self._unit.db = None

        return await self._run(run, small=urgent)


class SQLiteCollection(Collection):
    def __init__(self, store: SQLiteStore, schema: Schema) -> None:
        self._store = store
        self.schema = schema
        self._table = quoted(schema.name)
        self._names = list(schema.fields)
        self._written = [name for name in self._names if not (schema.serial and name == SERIAL)]
        self._encoders = {name: _encoder(kind) for name, kind in schema.fields.items()}
        self._decoders = {name: _decoder(kind) for name, kind in schema.fields.items()}
        self._written_encoders = [(name, self._encoders[name]) for name in self._written]
        columns = ", ".join(map(quoted, self._written))
        self._values = f"({columns}) VALUES ({', '.join('?' * len(self._written))})"
        self._insert = f"INSERT INTO {self._table} {self._values} ON CONFLICT DO NOTHING"
        self._key_columns = ", ".join(map(quoted, schema.key))
        self._by_key = " AND ".join(f"{quoted(name)} = ?" for name in schema.key)
        self._all = ", ".join(map(quoted, self._names))
        # what names a row in a DELETE ... IN (SELECT ...)
        self._row_id = "rowid" if _has_rowid(schema) else self._key_columns

    # encoding

    def _row(self, doc: Mapping[str, Any]) -> list[Any]:
        return [
            doc.get(name) if encode is None else encode(doc.get(name))
            for name, encode in self._written_encoders
        ]

    def _value(self, name: str, value: Any) -> Any:
        """A value to compare a field with, as the column keeps it."""
        if self.schema.kind(name).name == JSON.name:
            raise ValueError(f"{self.schema.name}.{name} is JSON: it cannot be compared")
        encode = self._encoders[name]
        return value if encode is None or value is None else encode(value)

    def _decode(self, names: Sequence[str], row: Sequence[Any]) -> Doc:
        doc = {}
        for name, value in zip(names, row, strict=True):
            decode = self._decoders[name]
            doc[name] = value if decode is None or value is None else decode(value)
        return doc

    def _where(self, where: Filter | None) -> tuple[str, list[Any]]:
        if not where:
            return "", []
        clauses: list[str] = []
        params: list[Any] = []
        for name, match in where.items():
            column = f"{self._table}.{quoted(name)}"
            if isinstance(match, In | NotIn):
                values = [self._value(name, value) for value in match.values]
                listed = self._listed([v for v in values if v is not None], params)
                if isinstance(match, In):
                    null = f" OR {column} IS NULL" if None in values else ""
                    clauses.append(f"({column} IN {listed}{null})")
                else:
                    null = f"{column} IS NOT NULL AND " if None in values else f"{column} IS NULL OR "
                    clauses.append(f"({null}{column} NOT IN {listed})")
            elif isinstance(match, Ne):
                clauses.append(f"{column} IS NOT ?")
                params.append(self._value(name, match.value))
            elif isinstance(match, Range):
                for bound, operator in RANGES:
                    value = getattr(match, bound)
                    if value is not None:
                        clauses.append(f"{column} {operator} ?")
                        params.append(self._value(name, value))
            elif match is None:
                self._value(name, None)
                clauses.append(f"{column} IS NULL")
            else:
                clauses.append(f"{column} = ?")
                params.append(self._value(name, match))
        return " WHERE " + " AND ".join(clauses), params

    @staticmethod
    def _listed(values: list[Any], params: list[Any]) -> str:
        if len(values) <= LISTED:
            params.extend(values)
            return f"({', '.join('?' * len(values))})"
        params.append(json.dumps(values))
        return "(SELECT value FROM json_each(?))"

    def _order(self, order: Sequence[str]) -> str:
        if not order:
            return ""
        terms = []
        for term in order:
            name, down = descending(term)
            self.schema.kind(name)
            terms.append(f"{quoted(name)}{' DESC' if down else ''}")
        return " ORDER BY " + ", ".join(terms)

    def _select(
        self,
        columns: str,
        where: Filter | None,
        order: Sequence[str] = (),
        limit: int | None = None,
        skip: int = 0,
    ) -> tuple[str, list[Any]]:
        clause, params = self._where(where)
        sql = f"SELECT {columns} FROM {self._table}{clause}{self._order(order)}"
        if limit is not None or skip:
            sql += " LIMIT ? OFFSET ?"
            params += [-1 if limit is None else int(limit), int(skip)]
        return sql, params

    # the port

    async def insert(self, docs: Sequence[Doc]) -> list[bool]:
        if not docs:
            return []
        rows = [self._row(doc) for doc in docs]

        def insert(db: sqlite3.Connection) -> list[bool]:
            return [db.execute(self._insert, row).rowcount == 1 for row in rows]

        return await self._store.call(insert, write=True)

    async def get(self, *key: Any) -> Doc | None:
        [found] = await self.get_many([key])
        return found

    async def get_many(self, keys: Sequence[tuple[Any, ...]]) -> list[Doc | None]:
        sql = f"SELECT {self._all} FROM {self._table} WHERE {self._by_key}"
        wanted = [
            [self._value(name, value) for name, value in zip(self.schema.key, key, strict=True)]
            for key in keys
        ]

        def get(db: sqlite3.Connection) -> list[Doc | None]:
            found: list[Doc | None] = []
            for params in wanted:
                row = db.execute(sql, params).fetchone()
                found.append(None if row is None else self._decode(self._names, row))
            return found

        return await self._store.call(get, write=False) if keys else []

    async def find(
        self,
        where: Filter | None = None,
        *,
        order: Sequence[str] = (),
        limit: int | None = None,
        skip: int = 0,
        fields: Sequence[str] | None = None,
    ) -> list[Doc]:
        names = list(fields) if fields is not None else self._names
        for name in names:
            self.schema.kind(name)
        sql, params = self._select(", ".join(map(quoted, names)), where, order, limit, skip)
        return await self._store.call(
            lambda db: [self._decode(names, row) for row in db.execute(sql, params)], write=False
        )

    async def count(self, where: Filter | None = None) -> int:
        sql, params = self._select("count(*)", where)
        count: int = await self._store.call(lambda db: db.execute(sql, params).fetchone()[0], write=False)
        return count

    async def group(
        self, by: str, where: Filter | None = None, *, highest: Sequence[str] = ()
    ) -> dict[Any, Group]:
        names = [by, *highest]
        for name in names:
            self.schema.kind(name)
        columns = ", ".join([quoted(by), "count(*)", *(f"max({quoted(name)})" for name in highest)])
        clause, params = self._where(where)
        sql = f"SELECT {columns} FROM {self._table}{clause} GROUP BY {quoted(by)}"

        def group(db: sqlite3.Connection) -> dict[Any, Group]:
            groups = {}
            for row in db.execute(sql, params):
                values = self._decode(names, [row[0], *row[2:]])
                groups[values.pop(by)] = Group(row[1], values)
            return groups

        return await self._store.call(group, write=False)

    async def first_each(
        self, by: str, values: Sequence[Any], *, order: Sequence[str], where: Filter | None = None
    ) -> dict[Any, Doc]:
        if not values:
            return {}
        wanted = json.dumps([self._value(by, value) for value in dict.fromkeys(values)])
        clause, params = self._where(where)
        of_value = f"{self._table}.{quoted(by)} = wanted.value"
        clause = f"{clause} AND {of_value}" if clause else f" WHERE {of_value}"
        # each value's first row by a correlated subquery: one index seek a value
        found = ", ".join(f"found.{column.strip()}" for column in self._row_id.split(","))
        columns = ", ".join(f"found.{quoted(name)}" for name in self._names)
        sql = (
            f"SELECT {columns} FROM json_each(?) wanted JOIN {self._table} AS found ON ({found}) = "
            f"(SELECT {self._row_id} FROM {self._table}{clause}{self._order(order)} LIMIT 1)"
        )
        rows = await self._store.call(lambda db: db.execute(sql, [wanted, *params]).fetchall(), write=False)
        docs = [self._decode(self._names, row) for row in rows]
        return {doc[by]: doc for doc in docs}

    async def update(
        self, where: Filter, changes: Mapping[str, Any], *, add: Mapping[str, int] | None = None
    ) -> int:
        assignments = [f"{quoted(name)} = ?" for name in changes]
        add = add or {}
        assignments += [f"{quoted(name)} = {quoted(name)} + ?" for name in add]
        values = [self._encoded(name, value) for name, value in changes.items()] + list(add.values())
        clause, params = self._where(where)
        sql = f"UPDATE {self._table} SET {', '.join(assignments)}{clause}"
        changed: int = await self._store.call(
            lambda db: db.execute(sql, values + params).rowcount, write=True
        )
        return changed

    def _encoded(self, name: str, value: Any) -> Any:
        """A value to store in a field."""
        self.schema.kind(name)
        encode = self._encoders[name]
        return value if encode is None else encode(value)

    async def put(
        self, doc: Doc, *, overwrite: Sequence[str] | None = None, where: Filter | None = None
    ) -> bool:
        changed = (
            [name for name in self._written if name not in self.schema.key]
            if overwrite is None
            else overwrite
        )
        if not changed:
            raise ValueError("put overwrites at least one field (insert() keeps what is stored)")
        assignments = ", ".join(f"{quoted(name)} = excluded.{quoted(name)}" for name in changed)
        clause, params = self._where(where)
        sql = (
            f"INSERT INTO {self._table} {self._values} ON CONFLICT ({self._key_columns}) "
            f"DO UPDATE SET {assignments}{clause}"
        )
        row = self._row(doc)
        written: int = await self._store.call(lambda db: db.execute(sql, row + params).rowcount, write=True)
        return written == 1

    async def increment(self, doc: Doc, counter: str, *, overwrite: Sequence[str] = ()) -> int:
        assignments = [f"{quoted(counter)} = {self._table}.{quoted(counter)} + excluded.{quoted(counter)}"]
        assignments += [f"{quoted(name)} = excluded.{quoted(name)}" for name in overwrite]
        sql = (
            f"INSERT INTO {self._table} {self._values} ON CONFLICT ({self._key_columns}) "
            f"DO UPDATE SET {', '.join(assignments)} RETURNING {quoted(counter)}"
        )
        row = self._row(doc)
        value: int = await self._store.call(lambda db: db.execute(sql, row).fetchone()[0], write=True)
        return value

    async def delete(self, where: Filter, *, order: Sequence[str] = (), limit: int | None = None) -> int:
        if order or limit is not None:
            chosen, params = self._select(self._row_id, where, order, limit)
            sql = f"DELETE FROM {self._table} WHERE ({self._row_id}) IN ({chosen})"
        else:
            clause, params = self._where(where)
            sql = f"DELETE FROM {self._table}{clause}"
        deleted: int = await self._store.call(lambda db: db.execute(sql, params).rowcount, write=True)
        return deleted


def sqlite_repositories(path: Path, busy_timeout: float = 2.0) -> Repositories:
    """Every repository over one SQLite file, not yet opened."""
    return repositories_on(SQLiteStore(path, busy_timeout))
