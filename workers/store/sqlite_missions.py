"""Missions on SQLite, one repository of `sqlite_repositories`; changes are conditional UPDATEs."""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Callable
from datetime import datetime
from typing import Any

from fleetbus.schemas.mission_states import MissionState
from fleetbus.workers.store.base import from_micros, to_micros
from fleetbus.workers.store.missions import Mission, MissionConflict, MissionStore, StateChange, mission_id_of
from fleetbus.workers.store.sqlite_database import OnSQLite, in_transaction

MISSION_SCHEMA = """
CREATE TABLE IF NOT EXISTS missions (
    mission_id TEXT PRIMARY KEY,
    number     INTEGER NOT NULL UNIQUE,
    use_case   TEXT    NOT NULL,
    title      TEXT    NOT NULL,
    owner      TEXT    NOT NULL,
    state      TEXT    NOT NULL,
    plan       TEXT    NOT NULL,
    created_at INTEGER NOT NULL,
    updated_at INTEGER NOT NULL
);
CREATE INDEX IF NOT EXISTS missions_owner ON missions (owner, number);
CREATE TABLE IF NOT EXISTS mission_history (
    id         INTEGER PRIMARY KEY AUTOINCREMENT,
    mission_id TEXT    NOT NULL,
    source     TEXT,
    target     TEXT    NOT NULL,
    by_user    TEXT    NOT NULL,
    at         INTEGER NOT NULL,
    note       TEXT    NOT NULL
);
CREATE INDEX IF NOT EXISTS mission_history_mission ON mission_history (mission_id, id);
"""


def _mission(row: sqlite3.Row) -> Mission:
    return Mission(
        mission_id=row["mission_id"],
        number=row["number"],
        use_case=row["use_case"],
        title=row["title"],
        owner=row["owner"],
        state=MissionState(row["state"]),
        plan=json.loads(row["plan"]),
        created_at=from_micros(row["created_at"]),
        updated_at=from_micros(row["updated_at"]),
    )


def _get(db: sqlite3.Connection, mission_id: str) -> Mission | None:
    row = db.execute("SELECT * FROM missions WHERE mission_id = ?", (mission_id,)).fetchone()
    return _mission(row) if row else None


def _history(db: sqlite3.Connection, change: StateChange) -> None:
    db.execute(
        "INSERT INTO mission_history (mission_id, source, target, by_user, at, note) "
        "VALUES (?, ?, ?, ?, ?, ?)",
        (
            change.mission_id,
            change.source.value if change.source else None,
            change.target.value,
            change.by,
            to_micros(change.at),
            change.note,
        ),
    )


class SQLiteMissions(OnSQLite, MissionStore):
    async def create_mission(
        self, use_case: str, title: str, owner: str, plan: dict[str, Any], at: datetime
    ) -> Mission:
        def create(db: sqlite3.Connection) -> Mission:
            def work() -> Mission:
                (number,) = db.execute("SELECT coalesce(max(number), 0) + 1 FROM missions").fetchone()
                mission_id = mission_id_of(number)
                db.execute(
                    "INSERT INTO missions (mission_id, number, use_case, title, owner, state, plan, "
                    "created_at, updated_at) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                    (
                        mission_id,
                        number,
                        use_case,
                        title,
                        owner,
                        MissionState.PLANNING.value,
                        json.dumps(plan),
                        to_micros(at),
                        to_micros(at),
                    ),
                )
                _history(db, StateChange(mission_id, None, MissionState.PLANNING, owner, at, "created"))
                found = _get(db, mission_id)
                assert found is not None
                return found

            return in_transaction(db, work)

        return await self._run(create)

    async def get_mission(self, mission_id: str) -> Mission | None:
        return await self._run(lambda db: _get(db, mission_id))

    async def missions(self, owner: str | None = None, state: MissionState | None = None) -> list[Mission]:
        clauses, params = [], []
        if owner is not None:
            clauses.append("owner = ?")
            params.append(owner)
        if state is not None:
            clauses.append("state = ?")
            params.append(state.value)
        where = " WHERE " + " AND ".join(clauses) if clauses else ""
        rows = await self._run(
            lambda db: db.execute(f"SELECT * FROM missions{where} ORDER BY number", params).fetchall()
        )
        return [_mission(row) for row in rows]

    async def _conditional(
        self,
        mission_id: str,
        sql: str,
        params: tuple[Any, ...],
        after: Callable[[sqlite3.Connection], None] | None = None,
    ) -> Mission:
        def change(db: sqlite3.Connection) -> Mission:
            def work() -> Mission:
                changed = db.execute(sql, params).rowcount
                mission = _get(db, mission_id)
                if changed == 0 or mission is None:
                    raise MissionConflict(mission_id, mission)
                if after is not None:
                    after(db)
                return mission

            return in_transaction(db, work)

        return await self._run(change)

    async def update_plan(
        self, mission_id: str, plan: dict[str, Any], expected: MissionState, at: datetime
    ) -> Mission:
        return await self._conditional(
            mission_id,
            "UPDATE missions SET plan = ?, updated_at = ? WHERE mission_id = ? AND state = ?",
            (json.dumps(plan), to_micros(at), mission_id, expected.value),
        )

    async def transition_mission(
        self,
        mission_id: str,
        source: MissionState,
        target: MissionState,
        by: str,
        at: datetime,
        note: str = "",
    ) -> Mission:
        return await self._conditional(
            mission_id,
            "UPDATE missions SET state = ?, updated_at = ? WHERE mission_id = ? AND state = ?",
            (target.value, to_micros(at), mission_id, source.value),
            lambda db: _history(db, StateChange(mission_id, source, target, by, at, note)),
        )

    async def put_mission(self, mission: Mission) -> bool:
        def put(db: sqlite3.Connection) -> bool:
            def work() -> bool:
                current = _get(db, mission.mission_id)
                if current is not None and current.updated_at >= mission.updated_at:
                    return False
                db.execute(
                    "INSERT INTO missions (mission_id, number, use_case, title, owner, state, plan, "
                    "created_at, updated_at) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?) "
                    "ON CONFLICT (mission_id) DO UPDATE SET use_case = excluded.use_case, "
                    "title = excluded.title, owner = excluded.owner, state = excluded.state, "
                    "plan = excluded.plan, updated_at = excluded.updated_at",
                    (
                        mission.mission_id,
                        mission.number,
                        mission.use_case,
                        mission.title,
                        mission.owner,
                        mission.state.value,
                        json.dumps(mission.plan),
                        to_micros(mission.created_at),
                        to_micros(mission.updated_at),
                    ),
                )
                if current is None or current.state != mission.state:
                    source = current.state if current else None
                    change = StateChange(
                        mission.mission_id,
                        source,
                        mission.state,
                        "central",
                        mission.updated_at,
                        "from central",
                    )
                    _history(db, change)
                return True

            return in_transaction(db, work)

        return await self._run(put)

    async def mission_history(self, mission_id: str) -> list[StateChange]:
        rows = await self._run(
            lambda db: db.execute(
                "SELECT * FROM mission_history WHERE mission_id = ? ORDER BY id", (mission_id,)
            ).fetchall()
        )
        return [
            StateChange(
                row["mission_id"],
                MissionState(row["source"]) if row["source"] else None,
                MissionState(row["target"]),
                row["by_user"],
                from_micros(row["at"]),
                row["note"],
            )
            for row in rows
        ]
