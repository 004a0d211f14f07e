"""At central: apply the sites' hazard states (``fleetbus.site-hazards``) to central's registry.

A site is the authority for its team's hazards; it sends each new state
(:class:`~fleetbus.schemas.site_hazards.SiteHazardState`) to its ``<site>.hazards`` exchange
here, which only its account may write: the exchange a message came by names its site. Central
keeps the newest version (:meth:`~fleetbus.workers.store.hazards.SiteHazardSync.apply_site_hazard`),
so a repeated or overtaken state changes nothing, and then shows the hazard like its own, with
its site.

Refused, with the reason recorded, into the dead letters (the worker goes on): a message that
does not parse, one that came by no site's exchange, one about a robot that is not the site's,
and one about a hazard central has as its own or as another site's. Each message is acked only
once the store has applied it.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Awaitable, Callable
from typing import TypeVar

from aio_pika.abc import AbstractChannel, AbstractIncomingMessage, AbstractQueue
from pydantic import ValidationError

from fleetbus.broker.retry import GaveUp, Stopped, async_retrying, run_retrying
from fleetbus.schemas.routing import site_of_hazards_exchange
from fleetbus.schemas.site_hazards import SiteHazardState
from fleetbus.workers.dead_letters import move_to_dead_letters, rejection_of
from fleetbus.workers.queue_consumer import QueueConsumer
from fleetbus.workers.store.base import StoreUnavailable
from fleetbus.workers.store.hazards import Hazard, HazardState, SiteApplied, SiteHazardSync
from fleetbus.workers.store.rejections import RejectionLog
from fleetbus.workers.store.sites import SiteRegistry

log = logging.getLogger("fleetbus.sites")

T = TypeVar("T")

#: How long one message waits for the store before it goes back to the queue.
STORE_DEADLINE_S = 5.0

# the reasons a site's hazard state is dead-lettered with
MALFORMED = "site-hazard-malformed"
NOT_FROM_A_SITE = "site-hazard-not-from-a-site"
NOT_THE_SITES_ROBOT = "site-hazard-not-the-sites-robot"
NOT_THE_SITES_HAZARD = "site-hazard-not-the-sites"


class Refused(Exception):
    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(detail)
        self.reason = reason


def hazard_of(state: SiteHazardState) -> Hazard:
    """The hazard as its site has it (its id and version there)."""
    return Hazard(**state.model_dump(exclude={"state"}), state=HazardState(state.state))


class SiteHazards(QueueConsumer):
    def __init__(
        self,
        channel: AbstractChannel,
        queue: AbstractQueue,
        hazards: SiteHazardSync,
        sites: SiteRegistry,
        rejections: RejectionLog,
    ) -> None:
        super().__init__(channel, queue)
        self._hazards = hazards
        self._sites = sites
        self._rejections = rejections
        self.counts: Counter[str] = Counter()
        """How many messages were applied, stale, or refused (by reason)."""

    async def _store(self, what: str, operation: Callable[[], Awaitable[T]]) -> T:
        retrying = async_retrying(
            f"the store ({what})",
            on=StoreUnavailable,
            deadline=STORE_DEADLINE_S,
            stop=self._stopping,
            logger=log,
        )
        return await run_retrying(retrying, operation)

    async def apply(self, message: AbstractIncomingMessage) -> SiteApplied:
        """Apply one message; raises :class:`Refused`."""
        try:
            state = SiteHazardState.model_validate_json(message.body)
        except ValidationError as error:
            raise Refused(MALFORMED, str(error)) from None
        site = site_of_hazards_exchange(message.exchange or "")
        if site is None:
            raise Refused(NOT_FROM_A_SITE, f"came by {message.exchange!r}, no site's hazards exchange")
        robot = state.robot_id
        robots_site = (await self._store("a robot's site", lambda: self._sites.site_of([robot]))).get(robot)
        if robots_site != site:
            raise Refused(
                NOT_THE_SITES_ROBOT,
                f"site {site} sent the state of a hazard of {robot}, a robot of "
                + (f"site {robots_site}" if robots_site else "no site"),
            )
        done, hazard = await self._store(
            "a site's hazard", lambda: self._hazards.apply_site_hazard(site, hazard_of(state))
        )
        if done is SiteApplied.NOT_THE_SITES:
            owner = f"site {hazard.site}" if hazard and hazard.site else "central"
            raise Refused(
                NOT_THE_SITES_HAZARD,
                f"site {site} sent the state of {robot}'s hazard event {state.epoch}/{state.seq}, "
                f"which is {owner}'s hazard",
            )
        return done

    async def _on_message(self, message: AbstractIncomingMessage) -> None:
        try:
            done = await self.apply(message)
        except Refused as refused:
            await self._refuse(message, refused)
            return
        except (GaveUp, Stopped) as error:
            log.warning("%s; the site's hazard state will be redelivered", error)
            await message.nack(requeue=True)
            return
        self.counts[done.value] += 1
        await message.ack()

    async def _refuse(self, message: AbstractIncomingMessage, refused: Refused) -> None:
        self.counts[refused.reason] += 1
        log.warning("a site's hazard state refused (%s): %s", refused.reason, refused)
        rejection = rejection_of(message, refused.reason, str(refused))
        try:
            await self._store("a rejection", lambda: self._rejections.record_rejections([rejection]))
        except (GaveUp, Stopped) as error:
            log.warning("%s; the refused hazard state will be redelivered", error)
            await message.nack(requeue=True)
            return
        await move_to_dead_letters(message)
