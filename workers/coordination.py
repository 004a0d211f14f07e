"""The hazard service: ids, the localisation gate, and FIFO announcements to the wardens.

Every hazard is registered as held. After each batch, when every warden of the team reports
itself localised, the held hazards are announced in the order they were detected: each
notification is published (confirmed) before the hazard is marked announced, so a crash in
between announces it again rather than never. The held list lives in the store, so a restart
loses nothing.

The service runs only on the express lane, whose queue has a single active consumer: of all the
workers, one registers hazards and announces them at a time, with no lock. A worker handing the
lane over finishes its batch before the next one gets the queue (``IngestConsumer(exclusive=True)``);
one that dies leaves its unacked messages to the next, which handles them again (idempotent).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from datetime import datetime, timedelta, timezone

from aio_pika.abc import AbstractExchange

from schemas.envelope import EVENT_ADAPTER
from schemas.notifications import Notification
from schemas.routing import EventType, Topic
from workers.notifier import publish_notification
from workers.store.hazards import Hazard, HeldHazards, NewHazard
from workers.store.interface import Store
from workers.validation import Accepted

log = logging.getLogger("fleetbus.hazards")

#: The event types the hazard service acts on: the gate's inputs and the hazards it holds.
GATED = (EventType.LOCALISATION, EventType.HAZARD)

#: A hazard announced this much later than its robot sent it is flagged ``late``.
LATE_AFTER = timedelta(seconds=5)


class HazardCoordinator:
    def __init__(
        self,
        store: Store,
        notify_exchange: AbstractExchange,
        service_user: str,
        late_after: timedelta = LATE_AFTER,
    ) -> None:
        self._store = store
        self._exchange = notify_exchange
        self._service_user = service_user
        self._late_after = late_after

    async def handle(self, accepted: Sequence[Accepted]) -> int:
        """Apply a stored batch (also redelivered ones: every step is idempotent); return announcements."""
        relevant = [item for item in accepted if item.event.type in GATED]
        if not relevant:
            return 0
        hazards: list[NewHazard] = []
        for item in relevant:
            event = item.event
            if event.type is EventType.LOCALISATION:
                await self._store.set_localised(event.robot_id, event.body.localised, event.sent_at)
            else:
                hazards.append(NewHazard.of(item.record))
        # registering (SQLite did it as it stored the batch), reading the held list and the
        # gate: one store call on the hazard's way
        return await self._announce(await self._store.hold_hazards(hazards))

    async def _announce(self, held: HeldHazards) -> int:
        if not held.hazards:
            return 0
        if not held.wardens_localised:
            log.info("holding %d hazards until every warden is localised", len(held.hazards))
            return 0
        now = datetime.now(timezone.utc)
        for hazard in held.hazards:
            await publish_notification(self._exchange, self.notification(hazard, now), self._service_user)
        await self._store.mark_announced(held.hazards, now)
        return len(held.hazards)

    def notification(self, hazard: Hazard, now: datetime) -> Notification:
        """The announcement; ``late`` when it reaches the wardens long after the explorer sent it
        (its robot was cut off, the workers were down, or the wardens were not localised yet)."""
        event = EVENT_ADAPTER.validate_python(hazard.event)
        return Notification(
            topic=Topic.HAZARD,
            event=event,
            received_at=hazard.received_at,
            notified_at=now,
            hazard_id=hazard.hazard_id,
            late=now - event.sent_at > self._late_after,
        )
