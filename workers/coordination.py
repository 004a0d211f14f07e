"""The hazard service: ids, the localisation gate, and FIFO announcements to the wardens.

Every hazard is registered as held. After each batch, when the gate is open (:mod:`fleetbus.workers.team`:
at least one warden in service, and every warden in service localised), the held hazards are
announced in the order they were detected: a copy to each warden in service, by
its inbox's name and ``mandatory`` (the broker returns a copy that reached no queue), then one
on ``fleetbus.notify`` for operators and the recorder, naming the wardens that took it. A hazard is
marked announced only once some warden's inbox took it (confirmed); if none did, it and those
after it stay held, with the reason. A crash in between announces it again rather than never.
The held list lives in the store, so a restart loses nothing.

A warden put back in service is owed the open hazards it missed: they go to it first, in order,
before anything newer. Team changes arrive on the express lane too (:class:`TeamChanges`).

Only the wardens' copies are on a hazard's way. The operators' copy and the mark are finished
behind it (:meth:`HazardCoordinator.take_finishing`): the express lane starts on the next batch
while the broker confirms them, and acks a batch only once they are done. The operators' copy
goes to every queue bound to ``fleetbus.notify``, the recorder's among them, which takes every
event of the team: after an outage it confirmed in 300 to 430 ms, and each hazard behind waited
for it. Until marked, an announced hazard is in flight in this process and not announced again;
should the process end first, the store still holds it as held and the next consumer announces
it again (at least once, as before).

The service runs only on the express lane, whose queue has a single active consumer: of all the
workers, one registers hazards and announces them at a time, with no lock. A worker handing the
lane over finishes its batch before the next one gets the queue (``IngestConsumer(exclusive=True)``);
one that dies leaves its unacked messages to the next, which handles them again (idempotent).
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Awaitable, Callable, Sequence
from datetime import datetime, timedelta, timezone

from aio_pika.abc import AbstractExchange, AbstractIncomingMessage
from pydantic import ValidationError

from fleetbus.schemas.envelope import EVENT_ADAPTER
from fleetbus.schemas.notifications import Notification
from fleetbus.schemas.routing import ANNOUNCED_TO_HEADER, EventType, Topic, inbox_queue
from fleetbus.schemas.team import TEAM_CHANGE_TYPE, TeamChange
from fleetbus.workers.notifier import deliver_to_inbox, publish_notification
from fleetbus.workers.store.hazards import (
    CoordinationStore,
    Hazard,
    HazardState,
    HeldHazards,
    NewHazard,
    RobotState,
)
from fleetbus.workers.store.team import Localisation
from fleetbus.workers.team import gate, why_closed
from fleetbus.workers.validation import Accepted

log = logging.getLogger("fleetbus.hazards")

#: The event types the hazard service acts on: the gate's inputs and the hazards it holds.
GATED = (EventType.LOCALISATION, EventType.HAZARD)

#: A hazard announced this much later than its robot sent it is flagged ``late``.
LATE_AFTER = timedelta(seconds=5)


class HazardCoordinator:
    def __init__(
        self,
        hazards: CoordinationStore,
        notify_exchange: AbstractExchange,
        default_exchange: AbstractExchange,
        service_user: str,
        late_after: timedelta = LATE_AFTER,
    ) -> None:
        self._hazards = hazards
        self._exchange = notify_exchange
        self._inboxes = default_exchange
        self._service_user = service_user
        self._late_after = late_after
        self._in_flight: set[tuple[str, str, int]] = set()
        """Hazards announced to the wardens whose operators' copy and mark are not done yet."""
        self._finishing: list[Callable[[], Awaitable[None]]] = []

    async def handle(self, accepted: Sequence[Accepted]) -> int:
        """Apply a stored batch (also redelivered ones: every step is idempotent); return announcements."""
        relevant = [item for item in accepted if item.event.type in GATED]
        if not relevant:
            return 0
        hazards: list[NewHazard] = []
        localisations: list[Localisation] = []
        stored_at = {item.record.key: item.stored_at for item in relevant}
        for item in relevant:
            event = item.event
            if event.type is EventType.LOCALISATION:
                localisations.append(Localisation(event.robot_id, event.body.localised, event.sent_at))
            else:
                hazards.append(NewHazard.of(item.record))
        await self._hazards.set_localisations(localisations)
        # registering (the one place a hazard is registered, on every backend), reading the held
        # list and the gate: one store call on the hazard's way
        return await self._announce(await self._hazards.hold_hazards(hazards), stored_at)

    async def reconsider(self) -> int:
        """After a team change: catch up wardens put back in service, announce if the gate opened."""
        return await self._announce(await self._hazards.hold_hazards(()))

    async def _announce(
        self, held: HeldHazards, stored_at: dict[tuple[str, str, int], datetime | None] | None = None
    ) -> int:
        """``stored_at``: when the hazards of the batch being handled were stored, by their key."""
        state = gate(held.wardens)
        sent = await self._catch_up([w for w in held.wardens if w.catch_up and w.in_service])
        if not held.hazards:
            return sent
        if not state.open:
            log.info("holding %d hazards: %s", len(held.hazards), why_closed(state))
            return sent
        now = datetime.now(timezone.utc)
        hazards = [hazard for hazard in held.hazards if _key(hazard) not in self._in_flight]
        notes = [
            # held, or claimed on its way (a worker died between a warden's copy and the mark)
            self.notification(
                hazard,
                now,
                HazardState.ANNOUNCED if hazard.state is HazardState.HELD else hazard.state,
                (stored_at or {}).get(_key(hazard)),
            )
            for hazard in hazards
        ]
        # all of them on their way at once, in order (one channel keeps the order of its publishes);
        # the broker's answers are read in that order
        answers = await asyncio.gather(*(self._to_wardens(note, state.wardens) for note in notes))
        copies: list[tuple[Notification, list[str]]] = []
        for index, (note, reached) in enumerate(zip(notes, answers, strict=True)):
            if not reached:
                reason = (
                    f"the announcement at {now:%H:%M:%S} UTC reached no warden: the broker returned it, "
                    f"no inbox for {', '.join(state.wardens)}"
                )
                first = hazards[index]
                log.warning("hazard %s:%d stays held: %s", first.mission_id, first.hazard_id, reason)
                await self._hazards.note_held(hazards[index:], reason)
                hazards = hazards[:index]
                break
            copies.append((note, reached))
        if hazards:
            self._in_flight |= {_key(hazard) for hazard in hazards}
            self._finishing.append(lambda: self._finish(copies, hazards, now))
        return sent + len(hazards)

    async def _to_wardens(self, note: Notification, wardens: list[str]) -> list[str]:
        """Put ``note`` in each of ``wardens``' inboxes; return those whose inbox took it."""
        took = await asyncio.gather(
            *(deliver_to_inbox(self._inboxes, note, warden, self._service_user) for warden in wardens)
        )
        return [warden for warden, ok in zip(wardens, took, strict=True) if ok]

    async def _finish(
        self, copies: list[tuple[Notification, list[str]]], hazards: list[Hazard], now: datetime
    ) -> None:
        """The operators' copies (naming the wardens that took each), confirmed, then the mark;
        idempotent, so it may be tried again after a failure."""
        await asyncio.gather(
            *(
                publish_notification(self._exchange, note, self._service_user, {ANNOUNCED_TO_HEADER: reached})
                for note, reached in copies
            )
        )
        await self._hazards.mark_announced(hazards, now)
        self._in_flight -= {_key(hazard) for hazard in hazards}

    def take_finishing(self) -> list[Callable[[], Awaitable[None]]]:
        """What the batches handled since the last call left to finish, in order: each must have
        succeeded (tried again until it does) before those batches are acked."""
        finishing, self._finishing = self._finishing, []
        return finishing

    async def _catch_up(self, wardens: list[RobotState]) -> int:
        """Send each warden put back in service the open hazards announced meanwhile that are open
        to it (:meth:`~fleetbus.workers.store.hazards.Hazard.open_to`), in order."""
        sent = 0
        if not wardens:
            return sent
        now = datetime.now(timezone.utc)
        announced = [h for h in await self._hazards.open_hazards(None) if h.state is not HazardState.HELD]
        for warden in wardens:
            missed = [h for h in announced if h.open_to(warden.name)]
            for hazard in missed:
                note = self.notification(hazard, now, hazard.state)
                if not await deliver_to_inbox(self._inboxes, note, warden.name, self._service_user):
                    log.warning(
                        "%s is back in service but has no inbox (%s)", warden.name, inbox_queue(warden.name)
                    )
                    break
                sent += 1
            await self._hazards.caught_up(warden.name)
            log.info("%s back in service: sent it %d open hazards", warden.name, len(missed))
        return sent

    def notification(
        self,
        hazard: Hazard,
        now: datetime,
        state: HazardState = HazardState.ANNOUNCED,
        stored_at: datetime | None = None,
    ) -> Notification:
        return hazard_notification(hazard, now, state, self._late_after, stored_at)


def _key(hazard: Hazard) -> tuple[str, str, int]:
    return (hazard.robot_id, hazard.epoch, hazard.seq)


def hazard_notification(
    hazard: Hazard,
    now: datetime,
    state: HazardState,
    late_after: timedelta | None,
    stored_at: datetime | None = None,
) -> Notification:
    """What a warden is told of ``hazard`` as ``state``. An announcement is ``late`` when it reaches
    the wardens more than ``late_after`` after the explorer sent it (its robot was cut off, the
    workers were down, or the wardens were not localised yet); ``None``: not an announcement."""
    event = EVENT_ADAPTER.validate_python(hazard.event)
    return Notification(
        topic=Topic.HAZARD,
        event=event,
        received_at=hazard.received_at,
        stored_at=stored_at,
        notified_at=now,
        hazard_id=hazard.hazard_id,
        hazard_state=state.value,
        claimed_by=hazard.claimed_by,
        late=late_after is not None and now - event.sent_at > late_after,
    )


class TeamChanges:
    """The express lane's control messages: the team changes of :mod:`fleetbus.broker.team_changes`."""

    def __init__(self, coordinator: HazardCoordinator) -> None:
        self._coordinator = coordinator

    def accepts(self, message: AbstractIncomingMessage) -> bool:
        # the default exchange: no robot may publish there (a robot's events come by its own exchange)
        return message.exchange == "" and message.type == TEAM_CHANGE_TYPE

    async def handle(self, messages: Sequence[AbstractIncomingMessage]) -> int:
        for message in messages:
            try:
                change = TeamChange.model_validate_json(message.body)
                log.info("team change: %s %s (by %s)", change.robot, change.change.value, change.by)
            except ValidationError as error:
                log.warning(
                    "a team change that does not parse (%s); the team is read again all the same", error
                )
        # what changed is in the store already: one look covers every change of the batch
        return await self._coordinator.reconsider()
