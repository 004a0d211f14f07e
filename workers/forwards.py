"""Central's side of the sites' uplinks: who forwarded what, and which services it skips.

An event a site forwarded (the shovel's ``x-shovelled`` header) is validated and stored as any
other: its ``user_id`` is the robot's own, validated by the site's broker and kept across the hop
by the site account's ``impersonator`` tag. The header is the site's claim; central believes it
only for the robots it assigned to that site (:class:`~fleetbus.workers.store.sites.SiteRegistry`),
and the broker lets a site write only to its own robots' exchanges.

:class:`ForwardLog` records each forwarded event once: its site, and ``late`` when central
received it more than ``late_after`` after the robot sent it. :class:`SiteLocalOnly` keeps a
service (the hazard gate) to events of robots that do not live at a site: their site already
announced those hazards to its wardens, whose inboxes are at the site.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from datetime import timedelta

from fleetbus.workers.ingest import BatchService
from fleetbus.workers.store.sites import Forward, SiteRegistry
from fleetbus.workers.validation import Accepted

log = logging.getLogger("fleetbus.sites")


async def sites_of_forwarded(sites: SiteRegistry, accepted: Sequence[Accepted]) -> dict[str, str]:
    """The site of each forwarded event's robot that has one (no store call when none is forwarded)."""
    robots = {item.event.robot_id for item in accepted if item.forwarded}
    return await sites.site_of(robots) if robots else {}


class ForwardLog:
    """After a batch is stored: one record per forwarded event (idempotent on its key)."""

    def __init__(self, sites: SiteRegistry, late_after: timedelta) -> None:
        self._sites = sites
        self._late_after = late_after

    async def handle(self, accepted: Sequence[Accepted]) -> int:
        site_of = await sites_of_forwarded(self._sites, accepted)
        forwards = [
            Forward(
                item.event.robot_id,
                item.event.epoch,
                item.event.seq,
                site_of.get(item.event.robot_id),
                item.event.type.value,
                item.event.sent_at,
                item.record.received_at,
                item.record.received_at - item.event.sent_at > self._late_after,
            )
            for item in accepted
            if item.forwarded
        ]
        for robot in {f.robot_id for f in forwards if f.site is None}:
            log.warning("%s's events claim to come from a site, but it is assigned to none", robot)
        await self._sites.record_forwards(forwards)
        return 0


class SiteLocalOnly:
    """``service`` for every event but those a site forwarded for one of its own robots."""

    def __init__(self, service: BatchService, sites: SiteRegistry) -> None:
        self._service = service
        self._sites = sites

    async def handle(self, accepted: Sequence[Accepted]) -> int:
        site_of = await sites_of_forwarded(self._sites, accepted)
        local = [item for item in accepted if not (item.forwarded and item.event.robot_id in site_of)]
        return await self._service.handle(local) if local else 0
