"""Mounts, check-ins and the channel change log on SQLite, one repository of `sqlite_repositories`.

Each booking runs in one ``BEGIN IMMEDIATE`` transaction: the checks and the insert cannot be
interleaved with another writer's.
"""

from __future__ import annotations

import sqlite3
from collections.abc import Collection
from datetime import datetime

from fleetbus.workers.store.base import from_micros, to_micros
from fleetbus.workers.store.channels import Booked, ChannelAction, ChannelChange, ChannelStore, CheckIn, Mount
from fleetbus.workers.store.sqlite_database import OnSQLite, in_transaction

CHANNEL_SCHEMA = """
CREATE TABLE IF NOT EXISTS mounts (
    robot      TEXT PRIMARY KEY,
    operator   TEXT    NOT NULL,
    mission_id TEXT    NOT NULL,
    mounted_at INTEGER NOT NULL
);
CREATE INDEX IF NOT EXISTS mounts_operator ON mounts (operator);
CREATE TABLE IF NOT EXISTS check_ins (
    operator      TEXT PRIMARY KEY,
    mission_id    TEXT    NOT NULL,
    checked_in_at INTEGER NOT NULL
);
CREATE TABLE IF NOT EXISTS channel_changes (
    id         INTEGER PRIMARY KEY AUTOINCREMENT,
    at         INTEGER NOT NULL,
    actor      TEXT    NOT NULL,
    action     TEXT    NOT NULL,
    mission_id TEXT,
    operator   TEXT,
    robot      TEXT,
    detail     TEXT    NOT NULL
);
CREATE INDEX IF NOT EXISTS channel_changes_mission ON channel_changes (mission_id, id);
"""


def _mount(row: sqlite3.Row) -> Mount:
    return Mount(row["robot"], row["operator"], row["mission_id"], from_micros(row["mounted_at"]))


def recording_missions(db: sqlite3.Connection, robots: Collection[str]) -> dict[str, str]:
    """For each of ``robots`` being recorded now: its mission (a robot mounted by a checked-in operator)."""
    names = sorted(set(robots))
    if not names:
        return {}
    marks = ",".join("?" * len(names))
    rows = db.execute(
        "SELECT m.robot, m.mission_id FROM mounts m JOIN check_ins c "
        f"ON c.operator = m.operator AND c.mission_id = m.mission_id WHERE m.robot IN ({marks})",
        names,
    )
    return {row["robot"]: row["mission_id"] for row in rows}


def _check_in(row: sqlite3.Row) -> CheckIn:
    return CheckIn(row["operator"], row["mission_id"], from_micros(row["checked_in_at"]))


def _operator_booking(db: sqlite3.Connection, operator: str) -> str | None:
    """The mission the operator is booked by (through a mount or its check-in), if any."""
    row = db.execute(
        "SELECT mission_id FROM check_ins WHERE operator = ? "
        "UNION SELECT mission_id FROM mounts WHERE operator = ? LIMIT 1",
        (operator, operator),
    ).fetchone()
    return row[0] if row else None


def _refuse_other_mission(db: sqlite3.Connection, operator: str, mission_id: str) -> None:
    booked = _operator_booking(db, operator)
    if booked is not None and booked != mission_id:
        raise Booked(f"operator {operator} is booked by mission {booked}")


class SQLiteChannels(OnSQLite, ChannelStore):
    async def mount(self, robot: str, operator: str, mission_id: str, at: datetime) -> Mount:
        def book(db: sqlite3.Connection) -> Mount:
            def work() -> Mount:
                row = db.execute("SELECT * FROM mounts WHERE robot = ?", (robot,)).fetchone()
                if row is not None:
                    existing = _mount(row)
                    if (existing.operator, existing.mission_id) == (operator, mission_id):
                        return existing
                    raise Booked(
                        f"robot {robot} is mounted by {existing.operator} for mission {existing.mission_id}"
                    )
                _refuse_other_mission(db, operator, mission_id)
                db.execute(
                    "INSERT INTO mounts (robot, operator, mission_id, mounted_at) VALUES (?, ?, ?, ?)",
                    (robot, operator, mission_id, to_micros(at)),
                )
                return Mount(robot, operator, mission_id, at)

            return in_transaction(db, work)

        return await self._run(book)

    async def unmount(self, robot: str, operator: str | None = None) -> Mount | None:
        def remove(db: sqlite3.Connection) -> Mount | None:
            def work() -> Mount | None:
                row = db.execute("SELECT * FROM mounts WHERE robot = ?", (robot,)).fetchone()
                if row is None or (operator is not None and row["operator"] != operator):
                    return None
                db.execute("DELETE FROM mounts WHERE robot = ?", (robot,))
                return _mount(row)

            return in_transaction(db, work)

        return await self._run(remove)

    async def mounts(
        self, operator: str | None = None, mission_id: str | None = None, robot: str | None = None
    ) -> list[Mount]:
        clauses = [
            (c, v) for c, v in (("operator", operator), ("mission_id", mission_id), ("robot", robot)) if v
        ]
        where = " WHERE " + " AND ".join(f"{c} = ?" for c, _ in clauses) if clauses else ""
        rows = await self._run(
            lambda db: db.execute(
                f"SELECT * FROM mounts{where} ORDER BY robot", [v for _, v in clauses]
            ).fetchall()
        )
        return [_mount(row) for row in rows]

    async def check_in(self, operator: str, mission_id: str, at: datetime) -> CheckIn:
        def book(db: sqlite3.Connection) -> CheckIn:
            def work() -> CheckIn:
                row = db.execute("SELECT * FROM check_ins WHERE operator = ?", (operator,)).fetchone()
                if row is not None and row["mission_id"] == mission_id:
                    return _check_in(row)
                _refuse_other_mission(db, operator, mission_id)
                db.execute(
                    "INSERT INTO check_ins (operator, mission_id, checked_in_at) VALUES (?, ?, ?)",
                    (operator, mission_id, to_micros(at)),
                )
                return CheckIn(operator, mission_id, at)

            return in_transaction(db, work)

        return await self._run(book)

    async def check_out(self, operator: str, mission_id: str) -> bool:
        return await self._run(
            lambda db: (
                db.execute(
                    "DELETE FROM check_ins WHERE operator = ? AND mission_id = ?", (operator, mission_id)
                ).rowcount
                == 1
            )
        )

    async def check_ins(self, mission_id: str | None = None, operator: str | None = None) -> list[CheckIn]:
        clauses = [(c, v) for c, v in (("mission_id", mission_id), ("operator", operator)) if v]
        where = " WHERE " + " AND ".join(f"{c} = ?" for c, _ in clauses) if clauses else ""
        rows = await self._run(
            lambda db: db.execute(
                f"SELECT * FROM check_ins{where} ORDER BY operator", [v for _, v in clauses]
            ).fetchall()
        )
        return [_check_in(row) for row in rows]

    async def recording_missions(self, robots: Collection[str]) -> dict[str, str]:
        return await self._run(lambda db: recording_missions(db, robots))

    async def record_change(self, change: ChannelChange) -> None:
        await self._run(
            lambda db: db.execute(
                "INSERT INTO channel_changes (at, actor, action, mission_id, operator, robot, detail) "
                "VALUES (?, ?, ?, ?, ?, ?, ?)",
                (
                    to_micros(change.at),
                    change.actor,
                    change.action.value,
                    change.mission_id,
                    change.operator,
                    change.robot,
                    change.detail,
                ),
            )
        )

    async def channel_changes(
        self, mission_id: str | None = None, limit: int | None = None
    ) -> list[ChannelChange]:
        where, params = (" WHERE mission_id = ?", [mission_id]) if mission_id else ("", [])
        sql = f"SELECT * FROM channel_changes{where} ORDER BY id DESC"
        if limit is not None:
            sql += f" LIMIT {int(limit)}"
        rows = await self._run(lambda db: db.execute(sql, params).fetchall())
        return [
            ChannelChange(
                from_micros(row["at"]),
                row["actor"],
                ChannelAction(row["action"]),
                row["mission_id"],
                row["operator"],
                row["robot"],
                row["detail"],
            )
            for row in reversed(rows)
        ]
