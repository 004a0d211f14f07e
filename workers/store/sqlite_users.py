"""Users on SQLite, one repository of `sqlite_repositories`."""

from __future__ import annotations

import sqlite3
from datetime import datetime

from fleetbus.schemas.roles import UserRole
from fleetbus.workers.store.base import from_micros, to_micros
from fleetbus.workers.store.sqlite_database import OnSQLite, in_transaction
from fleetbus.workers.store.users import NoSuchUser, User, UserExists, UserStore

USER_SCHEMA = """
CREATE TABLE IF NOT EXISTS users (
    name          TEXT PRIMARY KEY,
    role          TEXT    NOT NULL,
    password_hash TEXT,
    broker_secret TEXT,
    kind          TEXT,
    created_at    INTEGER NOT NULL,
    created_by    TEXT    NOT NULL,
    updated_at    INTEGER NOT NULL
);
"""


def _user(row: sqlite3.Row) -> User:
    return User(
        name=row["name"],
        role=UserRole(row["role"]),
        password_hash=row["password_hash"],
        broker_secret=row["broker_secret"],
        kind=row["kind"],
        created_at=from_micros(row["created_at"]),
        created_by=row["created_by"],
        updated_at=from_micros(row["updated_at"]),
    )


def _get(db: sqlite3.Connection, name: str) -> User | None:
    row = db.execute("SELECT * FROM users WHERE name = ?", (name,)).fetchone()
    return _user(row) if row else None


class SQLiteUsers(OnSQLite, UserStore):
    async def add_user(self, user: User) -> None:
        row = (
            user.name,
            user.role.value,
            user.password_hash,
            user.broker_secret,
            user.kind,
            to_micros(user.created_at),
            user.created_by,
            to_micros(user.updated_at),
        )

        def add(db: sqlite3.Connection) -> None:
            inserted = db.execute(
                "INSERT INTO users (name, role, password_hash, broker_secret, kind, created_at, created_by, "
                "updated_at) VALUES (?, ?, ?, ?, ?, ?, ?, ?) ON CONFLICT (name) DO NOTHING",
                row,
            ).rowcount
            if inserted == 0:
                raise UserExists(f"user {user.name!r} exists")

        await self._run(add)

    async def get_user(self, name: str) -> User | None:
        return await self._run(lambda db: _get(db, name))

    async def users(self, role: UserRole | None = None) -> list[User]:
        sql, params = "SELECT * FROM users", ()
        if role is not None:
            sql, params = sql + " WHERE role = ?", (role.value,)
        rows = await self._run(lambda db: db.execute(sql + " ORDER BY name", params).fetchall())
        return [_user(row) for row in rows]

    async def update_user(
        self,
        name: str,
        at: datetime,
        *,
        role: UserRole | None = None,
        password_hash: str | None = None,
        broker_secret: str | None = None,
    ) -> User:
        changes = {
            "role": role.value if role else None,
            "password_hash": password_hash,
            "broker_secret": broker_secret,
        }
        given = {column: value for column, value in changes.items() if value is not None}
        assignments = ", ".join(f"{column} = ?" for column in [*given, "updated_at"])
        params = (*given.values(), to_micros(at), name)

        def update(db: sqlite3.Connection) -> User:
            def work() -> User:
                db.execute(f"UPDATE users SET {assignments} WHERE name = ?", params)
                user = _get(db, name)
                if user is None:
                    raise NoSuchUser(f"no user {name!r}")
                return user

            return in_transaction(db, work)

        return await self._run(update)

    async def remove_user(self, name: str) -> bool:
        return await self._run(
            lambda db: db.execute("DELETE FROM users WHERE name = ?", (name,)).rowcount == 1
        )
