"""The coordination tables (robots, hazards) on SQLite, one repository of `sqlite_repositories`."""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Sequence
from datetime import datetime
from typing import Any, TypeVar

from fleetbus.schemas.routing import RobotKind
from fleetbus.workers.store.base import from_micros, to_micros
from fleetbus.workers.store.hazards import (
    MOST_HAZARDS,
    CoordinationStore,
    Hazard,
    HazardState,
    HeldHazards,
    NewHazard,
    RobotState,
    SiteApplied,
    Transition,
    refuse_transition,
)
from fleetbus.workers.store.sqlite_database import OnSQLite, in_transaction

T = TypeVar("T")

HAZARD_SCHEMA = """
CREATE TABLE IF NOT EXISTS robots (
    name               TEXT PRIMARY KEY,
    kind               TEXT,
    localised          INTEGER NOT NULL DEFAULT 0,
    updated_at         INTEGER,
    in_service         INTEGER NOT NULL DEFAULT 1,
    service_changed_by TEXT,
    service_changed_at INTEGER,
    catch_up           INTEGER NOT NULL DEFAULT 0
);
CREATE TABLE IF NOT EXISTS hazard_counters (
    mission_id TEXT PRIMARY KEY,
    last_id    INTEGER NOT NULL
);
CREATE TABLE IF NOT EXISTS hazards (
    mission_id   TEXT    NOT NULL,
    hazard_id    INTEGER NOT NULL,
    robot_id     TEXT    NOT NULL,
    epoch        TEXT    NOT NULL,
    seq          INTEGER NOT NULL,
    event         TEXT    NOT NULL,
    state        TEXT    NOT NULL,
    received_at  INTEGER NOT NULL,
    announced_at INTEGER,
    claimed_by   TEXT,
    claimed_at   INTEGER,
    reached_at   INTEGER,
    cleared_at   INTEGER,
    held_reason  TEXT,
    PRIMARY KEY (mission_id, hazard_id),
    UNIQUE (robot_id, epoch, seq)
);
CREATE INDEX IF NOT EXISTS hazards_state ON hazards (state, mission_id, hazard_id);
CREATE INDEX IF NOT EXISTS hazards_unannounced ON hazards (mission_id, hazard_id) WHERE announced_at IS NULL;
CREATE INDEX IF NOT EXISTS hazards_received ON hazards (received_at);
CREATE INDEX IF NOT EXISTS hazards_state_received ON hazards (state, received_at);
"""

#: Columns added to ``hazards`` after its first version: a file made before gets them on opening
#: (:func:`add_hazard_columns`), with these defaults.
HAZARD_COLUMNS = (
    ("version", "INTEGER NOT NULL DEFAULT 0"),
    ("sent_version", "INTEGER"),
    ("site", "TEXT"),
    ("site_hazard_id", "INTEGER"),
)
UNSENT = "site IS NULL AND (sent_version IS NULL OR sent_version < version)"


def add_hazard_columns(db: sqlite3.Connection) -> None:
    """Add the :data:`HAZARD_COLUMNS` ``hazards`` lacks, and their indexes; idempotent."""
    present = {row[1] for row in db.execute("PRAGMA table_info(hazards)")}
    for name, declaration in HAZARD_COLUMNS:
        if name not in present:
            try:
                db.execute(f"ALTER TABLE hazards ADD COLUMN {name} {declaration}")
            except sqlite3.OperationalError as error:  # the other connection added it first
                if "duplicate column" not in str(error):
                    raise
    db.execute(f"CREATE INDEX IF NOT EXISTS hazards_unsent ON hazards (mission_id, hazard_id) WHERE {UNSENT}")


def _micros(moment: datetime | None) -> int | None:
    return to_micros(moment) if moment else None


def _hazard(row: sqlite3.Row) -> Hazard:
    def moment(name: str) -> datetime | None:
        return from_micros(row[name]) if row[name] is not None else None

    return Hazard(
        mission_id=row["mission_id"],
        hazard_id=row["hazard_id"],
        robot_id=row["robot_id"],
        epoch=row["epoch"],
        seq=row["seq"],
        event=json.loads(row["event"]),
        state=HazardState(row["state"]),
        received_at=from_micros(row["received_at"]),
        announced_at=moment("announced_at"),
        claimed_by=row["claimed_by"],
        claimed_at=moment("claimed_at"),
        reached_at=moment("reached_at"),
        cleared_at=moment("cleared_at"),
        held_reason=row["held_reason"],
        version=row["version"],
        site=row["site"],
        site_hazard_id=row["site_hazard_id"],
    )


def _robot(row: sqlite3.Row) -> RobotState:
    return RobotState(
        row["name"],
        row["kind"],
        bool(row["localised"]),
        from_micros(row["updated_at"]) if row["updated_at"] else None,
        in_service=bool(row["in_service"]),
        service_changed_by=row["service_changed_by"],
        service_changed_at=from_micros(row["service_changed_at"]) if row["service_changed_at"] else None,
        catch_up=bool(row["catch_up"]),
    )


def _robots(db: sqlite3.Connection, kind: str | None = None) -> list[RobotState]:
    sql, params = "SELECT * FROM robots", ()
    if kind is not None:
        sql, params = sql + " WHERE kind = ?", (kind,)
    return [_robot(row) for row in db.execute(sql + " ORDER BY name", params)]


def _one(db: sqlite3.Connection, mission_id: str, hazard_id: int) -> Hazard | None:
    row = db.execute(
        "SELECT * FROM hazards WHERE mission_id = ? AND hazard_id = ?", (mission_id, hazard_id)
    ).fetchone()
    return _hazard(row) if row else None


class SQLiteCoordination(OnSQLite, CoordinationStore):
    async def register_robot(self, name: str, kind: str | None) -> None:
        await self._run(
            lambda db: db.execute(
                "INSERT INTO robots (name, kind) VALUES (?, ?) "
                "ON CONFLICT (name) DO UPDATE SET kind = excluded.kind",
                (name, kind),
            )
        )

    async def set_localised(self, name: str, localised: bool, at: datetime) -> None:
        await self._run(
            lambda db: db.execute(
                "INSERT INTO robots (name, localised, updated_at) VALUES (?, ?, ?) "
                "ON CONFLICT (name) DO UPDATE "
                "SET localised = excluded.localised, updated_at = excluded.updated_at "
                "WHERE robots.updated_at IS NULL OR robots.updated_at <= excluded.updated_at",
                (name, int(localised), to_micros(at)),
            ),
            small=True,
        )

    async def robots(self, kind: str | None = None) -> list[RobotState]:
        return await self._run(lambda db: _robots(db, kind))

    async def set_in_service(self, name: str, in_service: bool, by: str, at: datetime) -> RobotState | None:
        def change(db: sqlite3.Connection) -> RobotState | None:
            def work() -> RobotState | None:
                # owed a catch-up when put back from out of service; nothing owed while out
                db.execute(
                    "UPDATE robots SET catch_up = CASE WHEN ? THEN catch_up OR NOT in_service ELSE 0 END, "
                    "in_service = ?, service_changed_by = ?, service_changed_at = ? WHERE name = ?",
                    (int(in_service), int(in_service), by, to_micros(at), name),
                )
                row = db.execute("SELECT * FROM robots WHERE name = ?", (name,)).fetchone()
                return _robot(row) if row else None

            return in_transaction(db, work)

        return await self._run(change)

    async def caught_up(self, name: str) -> None:
        await self._run(
            lambda db: db.execute("UPDATE robots SET catch_up = 0 WHERE name = ?", (name,)), small=True
        )

    async def remove_robot(self, name: str) -> bool:
        removed: int = await self._run(
            lambda db: db.execute("DELETE FROM robots WHERE name = ?", (name,)).rowcount
        )
        return removed > 0

    async def add_hazard(
        self,
        mission_id: str,
        robot_id: str,
        epoch: str,
        seq: int,
        event: dict[str, Any],
        received_at: datetime,
        held: bool,
    ) -> Hazard:
        new = NewHazard(mission_id, robot_id, epoch, seq, event, received_at)
        return await self._run(lambda db: in_transaction(db, lambda: register_hazard(db, new, held)))

    async def hold_hazards(self, new: Sequence[NewHazard]) -> HeldHazards:
        def held(db: sqlite3.Connection) -> HeldHazards:
            return HeldHazards(_unannounced(db), _robots(db, RobotKind.WARDEN.value))

        def hold(db: sqlite3.Connection) -> HeldHazards:
            if all(_registered(db, hazard) is not None for hazard in new):  # as store_batch does: only read
                return held(db)

            def work() -> HeldHazards:
                for hazard in new:
                    register_hazard(db, hazard, held=True)
                return held(db)

            return in_transaction(db, work)

        return await self._run(hold, small=True)

    async def held_hazards(self, mission_id: str | None = None) -> list[Hazard]:
        return await self._run(lambda db: _held_hazards(db, mission_id))

    async def unannounced_hazards(self) -> list[Hazard]:
        return await self._run(_unannounced)

    async def mark_announced(self, hazards: list[Hazard], at: datetime) -> None:
        keys = [(to_micros(at), h.mission_id, h.hazard_id) for h in hazards]

        def mark(db: sqlite3.Connection) -> None:
            in_transaction(
                db,
                lambda: db.executemany(
                    "UPDATE hazards SET state = CASE state WHEN 'held' THEN 'announced' ELSE state END, "
                    "announced_at = COALESCE(announced_at, ?), held_reason = NULL, version = version + 1 "
                    "WHERE mission_id = ? AND hazard_id = ?",
                    keys,
                ),
            )

        await self._run(mark, small=True)

    async def note_held(self, hazards: list[Hazard], reason: str) -> None:
        keys = [(reason, h.mission_id, h.hazard_id) for h in hazards]

        def note(db: sqlite3.Connection) -> None:
            in_transaction(
                db,
                lambda: db.executemany(
                    "UPDATE hazards SET held_reason = ? "
                    "WHERE mission_id = ? AND hazard_id = ? AND state = 'held'",
                    keys,
                ),
            )

        await self._run(note, small=True)

    async def get_hazard(self, mission_id: str, hazard_id: int) -> Hazard | None:
        return await self._run(lambda db: _one(db, mission_id, hazard_id))

    async def open_hazards(self, mission_id: str | None) -> list[Hazard]:
        sql, params = "SELECT * FROM hazards WHERE state != 'cleared'", ()
        if mission_id is not None:
            sql, params = sql + " AND mission_id = ?", (mission_id,)
        rows = await self._run(
            lambda db: db.execute(sql + " ORDER BY mission_id, hazard_id", params).fetchall()
        )
        return [_hazard(row) for row in rows]

    async def recent_hazards(
        self, limit: int, offset: int = 0, state: HazardState | None = None
    ) -> list[Hazard]:
        where, params = (" WHERE state = ?", (state.value,)) if state is not None else ("", ())
        sql = (
            f"SELECT * FROM hazards{where} ORDER BY received_at DESC, mission_id DESC, hazard_id DESC "
            "LIMIT ? OFFSET ?"
        )
        if offset > MOST_HAZARDS:
            return []
        rows = await self._run(lambda db: db.execute(sql, (*params, limit, offset)).fetchall())
        return [_hazard(row) for row in rows]

    async def hazard_counts(self) -> dict[HazardState, int]:
        sql = "SELECT state, count(*) FROM hazards GROUP BY state"
        rows = await self._run(lambda db: db.execute(sql).fetchall())
        return {HazardState(state): count for state, count in rows}

    async def cleared_hazards(self, limit: int) -> list[Hazard]:
        sql = (
            "SELECT * FROM hazards WHERE state = 'cleared' "
            "ORDER BY cleared_at DESC, mission_id, hazard_id LIMIT ?"
        )
        rows = await self._run(lambda db: db.execute(sql, (limit,)).fetchall())
        return [_hazard(row) for row in rows]

    async def unsent_hazards(self, limit: int) -> list[Hazard]:
        sql = f"SELECT * FROM hazards WHERE {UNSENT} ORDER BY mission_id, hazard_id LIMIT ?"
        rows = await self._run(lambda db: db.execute(sql, (limit,)).fetchall())
        return [_hazard(row) for row in rows]

    async def mark_sent(self, hazards: Sequence[Hazard]) -> None:
        keys = [(h.version, h.mission_id, h.hazard_id, h.version) for h in hazards]

        def mark(db: sqlite3.Connection) -> None:
            in_transaction(
                db,
                lambda: db.executemany(
                    "UPDATE hazards SET sent_version = ? WHERE mission_id = ? AND hazard_id = ? "
                    "AND (sent_version IS NULL OR sent_version < ?)",
                    keys,
                ),
            )

        await self._run(mark, small=True)

    async def apply_site_hazard(self, site: str, hazard: Hazard) -> tuple[SiteApplied, Hazard | None]:
        def work(db: sqlite3.Connection) -> tuple[SiteApplied, Hazard | None]:
            new = NewHazard(
                hazard.mission_id, hazard.robot_id, hazard.epoch, hazard.seq, hazard.event, hazard.received_at
            )
            row = _registered(db, new)
            if row is None:
                mission_id, hazard_id = hazard.mission_id, _next_id(db, hazard.mission_id)
                db.execute(
                    "INSERT INTO hazards (mission_id, hazard_id, robot_id, epoch, seq, event, state, "
                    "received_at, site, version) VALUES (?, ?, ?, ?, ?, ?, 'held', ?, ?, -1)",
                    (
                        mission_id,
                        hazard_id,
                        hazard.robot_id,
                        hazard.epoch,
                        hazard.seq,
                        json.dumps(hazard.event),
                        to_micros(hazard.received_at),
                        site,
                    ),
                )
            elif row["site"] != site:
                return SiteApplied.NOT_THE_SITES, _hazard(row)
            elif row["version"] >= hazard.version:
                return SiteApplied.STALE, _hazard(row)
            else:
                mission_id, hazard_id = row["mission_id"], row["hazard_id"]
            db.execute(
                "UPDATE hazards SET state = ?, announced_at = ?, claimed_by = ?, claimed_at = ?, "
                "reached_at = ?, cleared_at = ?, held_reason = ?, version = ?, site_hazard_id = ? "
                "WHERE mission_id = ? AND hazard_id = ?",
                (
                    hazard.state.value,
                    _micros(hazard.announced_at),
                    hazard.claimed_by,
                    _micros(hazard.claimed_at),
                    _micros(hazard.reached_at),
                    _micros(hazard.cleared_at),
                    hazard.held_reason,
                    hazard.version,
                    hazard.hazard_id,
                    mission_id,
                    hazard_id,
                ),
            )
            return SiteApplied.APPLIED, _one(db, mission_id, hazard_id)

        return await self._run(lambda db: in_transaction(db, lambda: work(db)))

    async def apply_transition(
        self, mission_id: str, hazard_id: int, warden: str, transition: Transition, at: datetime
    ) -> Hazard:
        if transition.stamp is None:  # a release gives the claim up
            changes, values = "claimed_by = NULL, claimed_at = NULL", ()
        elif transition.claimer_only:
            changes, values = f"{transition.stamp} = ?", (to_micros(at),)
        else:
            changes, values = f"claimed_by = ?, {transition.stamp} = ?", (warden, to_micros(at))
        sources = ", ".join("?" for _ in transition.sources)
        # a site's hazard takes its steps at its site (its state here is the site's)
        condition = f"state IN ({sources}) AND site IS NULL AND mission_id = ? AND hazard_id = ?" + (
            " AND claimed_by = ?" if transition.claimer_only else ""
        )
        params = (
            transition.target.value,
            *values,
            *(source.value for source in transition.sources),
            mission_id,
            hazard_id,
        )
        params += (warden,) if transition.claimer_only else ()

        def change(db: sqlite3.Connection) -> Hazard:
            def work() -> Hazard:
                db.execute(
                    f"UPDATE hazards SET state = ?, {changes}, version = version + 1 WHERE {condition}",
                    params,
                )
                hazard = _one(db, mission_id, hazard_id)
                if hazard is None or not transition.done_by(hazard, warden):
                    raise refuse_transition(hazard, mission_id, hazard_id, transition.action, warden)
                return hazard

            return in_transaction(db, work)

        return await self._run(change)


def register_hazard(db: sqlite3.Connection, new: NewHazard, held: bool) -> Hazard:
    """Register ``new`` (inside the caller's transaction); the same event again finds the first."""
    row = _registered(db, new)
    if row:
        return _hazard(row)
    next_id = _next_id(db, new.mission_id)
    state = HazardState.HELD if held else HazardState.ANNOUNCED
    db.execute(
        "INSERT INTO hazards (mission_id, hazard_id, robot_id, epoch, seq, event, state, received_at, "
        "announced_at) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
        (
            new.mission_id,
            next_id,
            new.robot_id,
            new.epoch,
            new.seq,
            json.dumps(new.event),
            state.value,
            to_micros(new.received_at),
            None if held else to_micros(new.received_at),
        ),
    )
    found = _one(db, new.mission_id, next_id)
    assert found is not None
    return found


def _next_id(db: sqlite3.Connection, mission_id: str) -> int:
    """The mission's next hazard id, taken (inside the caller's transaction)."""
    (next_id,) = db.execute(
        "INSERT INTO hazard_counters (mission_id, last_id) VALUES (?, 1) "
        "ON CONFLICT (mission_id) DO UPDATE SET last_id = last_id + 1 RETURNING last_id",
        (mission_id,),
    ).fetchone()
    return int(next_id)


def _registered(db: sqlite3.Connection, hazard: NewHazard) -> sqlite3.Row | None:
    """The hazard registered for ``hazard``'s event, if any."""
    row: sqlite3.Row | None = db.execute(
        "SELECT * FROM hazards WHERE robot_id = ? AND epoch = ? AND seq = ?",
        (hazard.robot_id, hazard.epoch, hazard.seq),
    ).fetchone()
    return row


def _unannounced(db: sqlite3.Connection) -> list[Hazard]:
    """Hazards no warden's inbox has confirmed yet, by mission then id (held ones, and one claimed
    on its way before the worker announcing it could mark it)."""
    # a site's hazards are announced at their site, never here
    sql = "SELECT * FROM hazards WHERE announced_at IS NULL AND site IS NULL ORDER BY mission_id, hazard_id"
    return [_hazard(row) for row in db.execute(sql)]


def _held_hazards(db: sqlite3.Connection, mission_id: str | None = None) -> list[Hazard]:
    """Held hazards (of one mission, or all), in the order they were detected."""
    sql, params = "SELECT * FROM hazards WHERE state = 'held'", ()
    if mission_id is not None:
        sql, params = sql + " AND mission_id = ?", (mission_id,)
    return [_hazard(row) for row in db.execute(sql + " ORDER BY mission_id, hazard_id", params)]
