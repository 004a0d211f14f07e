"""The sequence ledger (gaps, duplicates) on SQLite, one repository of `sqlite_repositories`.

One row per robot and epoch holds the high-water mark, one per open gap its range.
"""

from __future__ import annotations

import sqlite3
from collections.abc import Mapping, Sequence
from datetime import datetime

from fleetbus.workers.store.base import from_micros, to_micros
from fleetbus.workers.store.ledger import (
    Duplicate,
    Gap,
    RobotEpoch,
    SequenceLedger,
    apply_seqs,
    seen_numbers,
)
from fleetbus.workers.store.sqlite_database import OnSQLite, in_transaction

LEDGER_SCHEMA = """
CREATE TABLE IF NOT EXISTS robot_sequences (
    robot_id   TEXT    NOT NULL,
    epoch      TEXT    NOT NULL,
    high_water INTEGER NOT NULL,
    PRIMARY KEY (robot_id, epoch)
) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS sequence_gaps (
    robot_id    TEXT    NOT NULL,
    epoch       TEXT    NOT NULL,
    first_seq   INTEGER NOT NULL,
    last_seq    INTEGER NOT NULL,
    detected_at INTEGER NOT NULL,
    PRIMARY KEY (robot_id, epoch, first_seq)
) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS duplicates (
    robot_id    TEXT    NOT NULL,
    epoch       TEXT    NOT NULL,
    seq         INTEGER NOT NULL,
    message_id  TEXT    NOT NULL,
    seen_at     INTEGER NOT NULL,
    redelivered INTEGER NOT NULL
);
CREATE INDEX IF NOT EXISTS duplicates_robot_time ON duplicates (robot_id, seen_at);
"""


def _gap(row: sqlite3.Row) -> Gap:
    return Gap(
        row["robot_id"], row["epoch"], row["first_seq"], row["last_seq"], from_micros(row["detected_at"])
    )


def observe(db: sqlite3.Connection, seen: Mapping[RobotEpoch, Sequence[int]], at: datetime) -> None:
    """Within the caller's transaction."""
    for numbering, seqs in seen.items():
        if seqs:
            _observe(db, RobotEpoch(*numbering), seqs, at)


def observed(db: sqlite3.Connection, wanted: Mapping[RobotEpoch, Sequence[int]]) -> set[tuple[str, str, int]]:
    """Within the caller's transaction: the (robot, epoch, seq) keys of ``wanted`` the ledger has seen."""
    keys: set[tuple[str, str, int]] = set()
    for numbering, seqs in wanted.items():
        row = db.execute(
            "SELECT high_water FROM robot_sequences WHERE robot_id = ? AND epoch = ?", numbering
        ).fetchone()
        if row is None or min(seqs) > row[0]:
            continue
        gaps = [
            _gap(r)
            for r in db.execute("SELECT * FROM sequence_gaps WHERE robot_id = ? AND epoch = ?", numbering)
        ]
        keys.update((*numbering, seq) for seq in seen_numbers(row[0], gaps, seqs))
    return keys


def _observe(db: sqlite3.Connection, numbering: RobotEpoch, seqs: Sequence[int], at: datetime) -> None:
    row = db.execute(
        "SELECT high_water FROM robot_sequences WHERE robot_id = ? AND epoch = ?", numbering
    ).fetchone()
    high_water = row[0] if row else None
    low = min(seqs)
    touched: list[Gap] = []
    if high_water is not None and low <= high_water:
        touched = [
            _gap(r)
            for r in db.execute(
                "SELECT * FROM sequence_gaps "
                "WHERE robot_id = ? AND epoch = ? AND last_seq >= ? AND first_seq <= ?",
                (*numbering, low, min(max(seqs), high_water)),
            )
        ]
    change = apply_seqs(numbering, high_water, touched, seqs, at)
    db.executemany(
        "DELETE FROM sequence_gaps WHERE robot_id = ? AND epoch = ? AND first_seq = ?",
        [(gap.robot_id, gap.epoch, gap.first) for gap in change.touched],
    )
    db.executemany(
        "INSERT INTO sequence_gaps (robot_id, epoch, first_seq, last_seq, detected_at) "
        "VALUES (?, ?, ?, ?, ?)",
        [(gap.robot_id, gap.epoch, gap.first, gap.last, to_micros(gap.detected_at)) for gap in change.gaps],
    )
    db.execute(
        "INSERT INTO robot_sequences (robot_id, epoch, high_water) VALUES (?, ?, ?) "
        "ON CONFLICT (robot_id, epoch) DO UPDATE SET high_water = max(high_water, excluded.high_water)",
        (*numbering, change.high_water),
    )


class SQLiteLedger(OnSQLite, SequenceLedger):
    async def observe_sequences(self, seen: Mapping[RobotEpoch, Sequence[int]], at: datetime) -> None:
        work = {numbering: list(seqs) for numbering, seqs in seen.items() if seqs}
        if not work:
            return
        await self._run(lambda db: in_transaction(db, lambda: observe(db, work, at)))

    async def record_duplicates(self, duplicates: Sequence[Duplicate]) -> None:
        rows = [
            (d.robot_id, d.epoch, d.seq, d.message_id, to_micros(d.seen_at), int(d.redelivered))
            for d in duplicates
        ]
        if not rows:
            return

        def record(db: sqlite3.Connection) -> None:
            in_transaction(
                db,
                lambda: db.executemany(
                    "INSERT INTO duplicates (robot_id, epoch, seq, message_id, seen_at, redelivered) "
                    "VALUES (?, ?, ?, ?, ?, ?)",
                    rows,
                ),
            )

        await self._run(record)

    async def gaps(self, robot_id: str | None = None) -> list[Gap]:
        where, params = (" WHERE robot_id = ?", (robot_id,)) if robot_id else ("", ())
        sql = f"SELECT * FROM sequence_gaps{where} ORDER BY robot_id, epoch, first_seq"
        return await self._run(lambda db: [_gap(row) for row in db.execute(sql, params)])

    async def duplicates(self, robot_id: str | None = None, limit: int | None = None) -> list[Duplicate]:
        where, params = (" WHERE robot_id = ?", (robot_id,)) if robot_id else ("", ())
        sql = f"SELECT * FROM duplicates{where} ORDER BY seen_at DESC, robot_id, epoch DESC, seq DESC"
        if limit is not None:
            sql += f" LIMIT {int(limit)}"
        return await self._run(
            lambda db: [
                Duplicate(
                    row["robot_id"],
                    row["epoch"],
                    row["seq"],
                    row["message_id"],
                    from_micros(row["seen_at"]),
                    bool(row["redelivered"]),
                )
                for row in db.execute(sql, params)
            ]
        )

    async def high_water(self, robot_id: str, epoch: str) -> int | None:
        row = await self._run(
            lambda db: db.execute(
                "SELECT high_water FROM robot_sequences WHERE robot_id = ? AND epoch = ?", (robot_id, epoch)
            ).fetchone()
        )
        return row[0] if row else None
