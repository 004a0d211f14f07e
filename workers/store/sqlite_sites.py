"""Central's sites on SQLite, one repository of `sqlite_repositories`."""

from __future__ import annotations

import sqlite3
from collections.abc import Collection, Sequence
from datetime import datetime, timezone

from fleetbus.schemas.site_reports import SiteReport
from fleetbus.workers.store.base import from_micros, to_micros
from fleetbus.workers.store.sites import Forward, SiteRegistry, SiteSummary
from fleetbus.workers.store.sqlite_database import OnSQLite, in_transaction

SITE_SCHEMA = """
CREATE TABLE IF NOT EXISTS sites (
    name       TEXT    PRIMARY KEY,
    added_at   INTEGER NOT NULL
) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS site_robots (
    robot_id   TEXT    PRIMARY KEY,
    site       TEXT    NOT NULL
) WITHOUT ROWID;
CREATE INDEX IF NOT EXISTS site_robots_site ON site_robots (site);
CREATE TABLE IF NOT EXISTS site_forwards (
    robot_id    TEXT    NOT NULL,
    epoch       TEXT    NOT NULL,
    seq         INTEGER NOT NULL,
    site        TEXT,
    type        TEXT    NOT NULL,
    sent_at     INTEGER NOT NULL,
    received_at INTEGER NOT NULL,
    late        INTEGER NOT NULL,
    PRIMARY KEY (robot_id, epoch, seq)
) WITHOUT ROWID;
CREATE INDEX IF NOT EXISTS site_forwards_site ON site_forwards (site, sent_at);
CREATE TABLE IF NOT EXISTS site_reports (
    site       TEXT    PRIMARY KEY,
    at         INTEGER NOT NULL,
    report     TEXT    NOT NULL
) WITHOUT ROWID;
"""


def _forward(row: tuple[object, ...]) -> Forward:
    robot_id, epoch, seq, site, type_, sent_at, received_at, late = row
    return Forward(
        str(robot_id),
        str(epoch),
        int(seq),  # type: ignore[call-overload]
        None if site is None else str(site),
        str(type_),
        from_micros(int(sent_at)),  # type: ignore[call-overload]
        from_micros(int(received_at)),  # type: ignore[call-overload]
        bool(late),
    )


class SQLiteSites(OnSQLite, SiteRegistry):
    async def set_robots(self, site: str, robots: Collection[str]) -> None:
        now = to_micros(datetime.now(timezone.utc))

        def work(db: sqlite3.Connection) -> None:
            db.execute("INSERT INTO sites VALUES (?, ?) ON CONFLICT (name) DO NOTHING", (site, now))
            db.execute("DELETE FROM site_robots WHERE site = ?", (site,))
            db.executemany("INSERT OR REPLACE INTO site_robots VALUES (?, ?)", [(r, site) for r in robots])

        await self._run(lambda db: in_transaction(db, lambda: work(db)))

    async def remove_site(self, site: str) -> None:
        def work(db: sqlite3.Connection) -> None:
            db.execute("DELETE FROM site_robots WHERE site = ?", (site,))
            db.execute("DELETE FROM sites WHERE name = ?", (site,))

        await self._run(lambda db: in_transaction(db, lambda: work(db)))

    async def sites(self) -> dict[str, tuple[str, ...]]:
        def read(db: sqlite3.Connection) -> dict[str, tuple[str, ...]]:
            result: dict[str, list[str]] = {name: [] for (name,) in db.execute("SELECT name FROM sites")}
            for robot, site in db.execute("SELECT robot_id, site FROM site_robots ORDER BY robot_id"):
                result.setdefault(site, []).append(robot)
            return {name: tuple(result[name]) for name in sorted(result)}

        return await self._run(read)

    async def site_of(self, robots: Collection[str]) -> dict[str, str]:
        names = sorted(set(robots))
        if not names:
            return {}
        sql = f"SELECT robot_id, site FROM site_robots WHERE robot_id IN ({','.join('?' * len(names))})"
        return await self._run(lambda db: dict(db.execute(sql, names).fetchall()), small=True)

    async def record_forwards(self, forwards: Sequence[Forward]) -> None:
        rows = [
            (
                f.robot_id,
                f.epoch,
                f.seq,
                f.site,
                f.type,
                to_micros(f.sent_at),
                to_micros(f.received_at),
                int(f.late),
            )
            for f in forwards
        ]
        if not rows:
            return
        sql = "INSERT INTO site_forwards VALUES (?, ?, ?, ?, ?, ?, ?, ?) ON CONFLICT DO NOTHING"
        await self._run(lambda db: in_transaction(db, lambda: db.executemany(sql, rows)))

    async def forwards(self, robot_id: str | None = None) -> list[Forward]:
        where, params = (" WHERE robot_id = ?", [robot_id]) if robot_id is not None else ("", [])
        sql = f"SELECT * FROM site_forwards{where} ORDER BY robot_id, epoch, seq"
        return await self._run(lambda db: [_forward(tuple(row)) for row in db.execute(sql, params)])

    async def summaries(self) -> list[SiteSummary]:
        known = await self.sites()

        def read(db: sqlite3.Connection) -> dict[str, tuple[int, int, int, int]]:
            sql = (
                "SELECT site, count(*), sum(late), max(sent_at), max(received_at) FROM site_forwards "
                "WHERE site IS NOT NULL GROUP BY site"
            )
            return {site: (n, late, sent, received) for site, n, late, sent, received in db.execute(sql)}

        counts = await self._run(read)
        summaries = []
        for site, robots in known.items():
            n, late, sent, received = counts.get(site, (0, 0, None, None))  # type: ignore[arg-type]
            summaries.append(
                SiteSummary(
                    site,
                    robots,
                    n,
                    late or 0,
                    from_micros(sent) if sent is not None else None,
                    from_micros(received) if received is not None else None,
                )
            )
        return summaries

    async def put_report(self, report: SiteReport) -> bool:
        sql = (
            "INSERT INTO site_reports VALUES (?, ?, ?) ON CONFLICT (site) DO UPDATE SET "
            "at = excluded.at, report = excluded.report WHERE excluded.at > site_reports.at"
        )
        params = (report.site, to_micros(report.at), report.model_dump_json())
        changed = await self._run(lambda db: in_transaction(db, lambda: db.execute(sql, params).rowcount))
        return bool(changed)

    async def reports(self) -> dict[str, SiteReport]:
        rows = await self._run(lambda db: db.execute("SELECT site, report FROM site_reports").fetchall())
        return {str(site): SiteReport.model_validate_json(str(body)) for site, body in rows}
