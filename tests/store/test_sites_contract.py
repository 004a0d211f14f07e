"""Central's sites on every adapter: robots by site (a list changed by compare-and-set on its revision),
each forward kept once, the summary per site; on a site, the newest revision of central's word on a robot."""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from datetime import datetime, timedelta, timezone
from typing import Any

import pytest

from fleetbus.workers.sites import revise
from fleetbus.workers.store.repositories import Repositories
from fleetbus.workers.store.sites import (
    Forward,
    ListChange,
    SiteList,
    SiteRegistry,
    SiteSummary,
    StaleRevision,
)
from tests.store.second import second_connection

T0 = datetime(2026, 11, 27, 6, 0, 0, tzinfo=timezone.utc)


def forward(robot: str, seq: int, site: str | None, late: bool = False) -> Forward:
    sent = T0 + timedelta(seconds=seq)
    return Forward(robot, "e1", seq, site, "hazard", sent, sent + timedelta(seconds=30 if late else 1), late)


async def test_a_robot_lives_at_one_site_and_moves_with_set_robots(store: Repositories) -> None:
    assert await store.sites.robots_of("base1") is None
    [made] = await store.sites.set_robots("base1", ["warden1", "explorer1"], revision=0)
    assert made == ListChange("base1", made.revision, ("explorer1", "warden1"), ("explorer1", "warden1"), ())
    [base2] = await store.sites.set_robots("base2", [])
    assert await store.sites.sites() == {"base1": ("explorer1", "warden1"), "base2": ()}
    # a change computed from a list read before another change is refused, and changes nothing
    other = second_connection(store)  # another process changing the same site
    await other.open()
    try:
        three = ["explorer1", "guide1", "warden1"]
        [newer] = await other.sites.set_robots("base1", three, revision=made.revision)
        with pytest.raises(StaleRevision):
            await store.sites.set_robots("base1", ["explorer1"], revision=made.revision)
    finally:
        await other.close()
    assert newer.revision > made.revision
    assert await store.sites.robots_of("base1") == SiteList(newer.robots, newer.revision)
    assert newer.robots == ("explorer1", "guide1", "warden1")
    # a robot moving changes both lists, each to a newer revision
    moved = await store.sites.set_robots("base2", ["warden1"], revision=base2.revision)
    assert [(c.site, c.robots, c.joined, c.left) for c in moved] == [
        ("base2", ("warden1",), ("warden1",), ()),
        ("base1", ("explorer1", "guide1"), (), ("warden1",)),
    ]
    assert moved[0].revision > base2.revision and moved[1].revision > newer.revision
    await store.sites.set_robots("base1", ["explorer1"])
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


async def test_the_sums_go_on_from_each_batch_and_outlive_the_pruned_log(store: Repositories) -> None:
    await store.sites.set_robots("base1", ["explorer1"])
    first = [forward("explorer1", seq, "base1", late=seq == 0) for seq in range(3)]
    await store.sites.record_forwards(first)  # the site's first sums: read from the log once
    later = [forward("explorer1", seq, "base1", late=True) for seq in range(3, 5)]
    await store.sites.record_forwards([*later, first[1]])  # one of them again: counted once
    expected = SiteSummary("base1", ("explorer1",), 5, 3, later[-1].sent_at, later[-1].received_at)
    assert await store.sites.summaries() == [expected]
    # the log is pruned by when central received each forward; the sums stay
    assert await store.housekeeping.prune_forwards(later[0].received_at, None, 10) == 3
    assert [f.seq for f in await store.sites.forwards("explorer1")] == [3, 4]
    assert await store.housekeeping.prune_forwards(None, 1, 10) == 1
    assert [f.seq for f in await store.sites.forwards("explorer1")] == [4]
    assert await store.sites.summaries() == [expected]


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


async def test_a_site_keeps_the_newest_revision_of_centrals_word_on_each_robot(store: Repositories) -> None:
    assert await store.sites.note_revision("guide1", 4)
    assert await store.sites.note_revision("guide1", 4), "the same message again"
    assert not await store.sites.note_revision("guide1", 3), "an older one, after"
    assert await store.sites.note_revision("explorer1", 1), "each robot its own"
    assert await store.sites.note_revision("guide1", 5)
    assert not await store.sites.note_revision("guide1", 4)


class _Raced:
    """The sites as a change reads them, with another change made right after its read."""

    def __init__(self, sites: SiteRegistry, meanwhile: Callable[[], Awaitable[object]]) -> None:
        self._sites = sites
        self._meanwhile: list[Callable[[], Awaitable[object]]] = [meanwhile]

    async def robots_of(self, site: str) -> SiteList | None:
        listed = await self._sites.robots_of(site)
        if self._meanwhile:
            await self._meanwhile.pop()()
        return listed

    def __getattr__(self, name: str) -> Any:
        return getattr(self._sites, name)


async def test_a_change_of_a_sites_robots_never_undoes_one_made_meanwhile(store: Repositories) -> None:
    [first] = await store.sites.set_robots("base1", ["explorer1", "warden1"])
    other = second_connection(store)  # a `--remove` in another process, between the add's read and write
    await other.open()

    async def removal() -> object:
        return await other.sites.set_robots("base1", ["explorer1"], revision=first.revision)

    try:
        raced = _Raced(store.sites, removal)
        [added] = await revise(raced, "base1", lambda listed: {*listed, "guide1"})  # type: ignore[arg-type]
    finally:
        await other.close()
    assert (added.robots, added.joined, added.left) == (("explorer1", "guide1"), ("guide1",), ())
    assert await store.sites.robots_of("base1") == SiteList(("explorer1", "guide1"), added.revision)
