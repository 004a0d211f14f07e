"""Central's sites on every adapter: robots by site, each forward kept once, the summary per site."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone

from fleetbus.workers.store.repositories import Repositories
from fleetbus.workers.store.sites import Forward, SiteSummary
from tests.store.second import second_connection

T0 = datetime(2026, 11, 27, 6, 0, 0, tzinfo=timezone.utc)


def forward(robot: str, seq: int, site: str | None, late: bool = False) -> Forward:
    sent = T0 + timedelta(seconds=seq)
    return Forward(robot, "e1", seq, site, "hazard", sent, sent + timedelta(seconds=30 if late else 1), late)


async def test_a_robot_lives_at_one_site_and_moves_with_set_robots(store: Repositories) -> None:
    await store.sites.set_robots("base1", ["explorer1", "warden1"])
    await store.sites.set_robots("base2", [])
    assert await store.sites.sites() == {"base1": ("explorer1", "warden1"), "base2": ()}
    await store.sites.set_robots("base2", ["warden1"])
    assert await store.sites.sites() == {"base1": ("explorer1",), "base2": ("warden1",)}
    assert await store.sites.site_of(["explorer1", "warden1", "guide1"]) == {
        "explorer1": "base1",
        "warden1": "base2",
    }
    await store.sites.set_robots("base1", [])
    assert await store.sites.site_of(["explorer1"]) == {}
    await store.sites.remove_site("base2")
    assert await store.sites.sites() == {"base1": ()}


async def test_each_forward_is_kept_once_and_summed_by_site(store: Repositories) -> None:
    await store.sites.set_robots("base1", ["explorer1"])
    first = [forward("explorer1", seq, "base1", late=seq >= 2) for seq in range(4)]
    await store.sites.record_forwards(first)
    await store.sites.record_forwards([*first[2:], forward("intruder", 0, None)])  # a redelivery
    other = second_connection(store)  # what `fleetbus sites` sees
    await other.open()
    try:
        assert await other.sites.forwards("explorer1") == first
        assert [f.site for f in await other.sites.forwards()] == ["base1"] * 4 + [None]
        assert await other.sites.summaries() == [
            SiteSummary("base1", ("explorer1",), 4, 2, first[-1].sent_at, first[-1].received_at)
        ]
    finally:
        await other.close()


async def test_each_site_keeps_its_newest_report(store: Repositories) -> None:
    from fleetbus.schemas.site_reports import SiteReport

    def report(site: str, seconds: int, waiting: int) -> SiteReport:
        return SiteReport(
            site=site,
            at=T0 + timedelta(seconds=seconds),
            waiting=waiting,
            uplink="running",
            downlink="running",
        )

    assert await store.sites.reports() == {}
    assert await store.sites.put_report(report("base1", 10, 5))
    assert await store.sites.put_report(report("base2", 1, 0))
    assert not await store.sites.put_report(report("base1", 5, 99)), "an older report arriving late"
    assert await store.sites.put_report(report("base1", 20, 7))
    assert await store.sites.reports() == {"base1": report("base1", 20, 7), "base2": report("base2", 1, 0)}
