"""On a site: send central each new state of the site's hazards.

Every change of a hazard's state (registered held, announced, claimed, released, reached,
cleared) gives it a new version in the store. About every second the worker puts the hazards
whose newest version is unsent into ``fleetbus.hazard-uplink`` on the site's own broker
(persistent, confirmed), in order, then marks those versions sent. The queue keeps them while
central is away; the shovel ``fleetbus-hazard-uplink`` moves them to central, acking each only
once central confirmed it (:mod:`fleetbus.broker.sites`), and central keeps the newest version of
each (:mod:`fleetbus.workers.site_hazards`). A state that changes twice before it goes is sent
once, as it is then.

Where there is no such queue (not a site, or before ``fleetbus site up``) the broker returns the
first message and nothing is marked: the worker looks again every :data:`NOT_A_SITE_EVERY_S`.
Several workers of one site may send the same version: central applies it once.
"""

from __future__ import annotations

import asyncio
import dataclasses
import logging

import aio_pika
import aiormq.abc
from aio_pika.abc import AbstractChannel

from fleetbus.broker.retry import pause
from fleetbus.schemas.routing import HAZARD_UPLINK_QUEUE
from fleetbus.schemas.site_hazards import SITE_HAZARD_TYPE, SiteHazardState
from fleetbus.workers.notifier import CONFIRM_TIMEOUT_S
from fleetbus.workers.store.hazards import Hazard, SiteHazardSync

log = logging.getLogger("fleetbus.sites")

EVERY_S = 1.0
NOT_A_SITE_EVERY_S = 30.0
#: Versions sent in one round at most (after an outage of the store's own, the rest follow).
BATCH = 500


def state_message(hazard: Hazard) -> SiteHazardState:
    """What central is told of ``hazard`` as the site's store has it now: every field the message
    has, taken from the hazard as a whole."""
    fields = dataclasses.asdict(hazard) | {"state": hazard.state.value}
    return SiteHazardState(**{name: fields[name] for name in SiteHazardState.model_fields})


class HazardUplink:
    def __init__(
        self,
        channel: AbstractChannel,
        hazards: SiteHazardSync,
        every_s: float = EVERY_S,
        not_a_site_every_s: float = NOT_A_SITE_EVERY_S,
    ) -> None:
        self._channel = channel
        self._hazards = hazards
        self._every_s = every_s
        self._not_a_site_every_s = not_a_site_every_s
        self._stopping = asyncio.Event()
        self._task: asyncio.Task[None] | None = None
        self._a_site = False
        """The queue took the last version offered: send whole batches."""
        self.not_a_site = False
        """The broker returned the last version offered (it has no hazard uplink queue): this
        store's hazards go to no central. False until known."""
        self.sent = 0

    def start(self) -> None:
        self._task = asyncio.create_task(self._run(), name="fleetbus-hazard-uplink")

    async def stop(self) -> None:
        self._stopping.set()
        if self._task is not None:
            await asyncio.gather(self._task, return_exceptions=True)

    async def send_unsent(self) -> int | None:
        """Send the unsent versions (up to :data:`BATCH`) and mark them sent; how many, or None
        when the broker has no hazard uplink queue (this is not a site)."""
        # where the broker returned the last one, one is offered first (central has many unsent)
        unsent = await self._hazards.unsent_hazards(BATCH if self._a_site else 1)
        sent: list[Hazard] = []
        try:
            for hazard in unsent:
                self._a_site = await self._put(hazard)
                self.not_a_site = not self._a_site
                if not self._a_site:
                    return None
                sent.append(hazard)
        finally:
            if sent:
                await self._hazards.mark_sent(sent)
                self.sent += len(sent)
        return len(sent)

    async def _put(self, hazard: Hazard) -> bool:
        """Put one version in the queue (confirmed); False when the broker returned it."""
        message = aio_pika.Message(
            state_message(hazard).model_dump_json().encode(),
            content_type="application/json",
            delivery_mode=aio_pika.DeliveryMode.PERSISTENT,
            # its own id: aiormq matches a returned message to its publish by it
            message_id=f"{hazard.mission_id}:{hazard.hazard_id}@{hazard.version}",
            type=SITE_HAZARD_TYPE,
        )
        result = await self._channel.default_exchange.publish(
            message, routing_key=HAZARD_UPLINK_QUEUE, mandatory=True, timeout=CONFIRM_TIMEOUT_S
        )
        return not isinstance(result, aiormq.abc.DeliveredMessage)

    async def _run(self) -> None:
        while not self._stopping.is_set():
            wait = self._every_s
            try:
                if await self.send_unsent() is None:
                    wait = self._not_a_site_every_s
            except Exception as error:  # the broker or the store away: the next round tries again
                log.warning(
                    "hazard states not sent to central this round (%s: %s)", type(error).__name__, error
                )
            await pause(wait, self._stopping)
