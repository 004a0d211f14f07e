"""The telemetry sub-service: a battery that drops below the threshold notifies the operators.

Status events themselves are stored like every event (query them with ``fleetbus query status``).
The warning goes out when a robot's battery crosses below the threshold, not on every low
reading: the robot's previous stored status decides.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from datetime import datetime, timezone

from aio_pika.abc import AbstractExchange

from fleetbus.schemas.notifications import Notification
from fleetbus.schemas.routing import EventType, Topic
from fleetbus.workers.notifier import publish_notification
from fleetbus.workers.store.base import EventQuery, EventStore
from fleetbus.workers.validation import Accepted

#: The field of a status event that carries the robot's battery.
BATTERY_FIELD = "battery_percent"


def battery_of(body: Mapping[str, object]) -> float | None:
    """The battery a status event's body reports (None when it does not say)."""
    value = body.get(BATTERY_FIELD)
    return float(value) if isinstance(value, (int, float)) else None


def battery_low(percent: float, threshold: float) -> bool:
    """Whether a battery at ``percent`` is low (``FLEETBUS_BATTERY_LOW_PERCENT``: below it)."""
    return percent < threshold


class BatteryWatch:
    def __init__(
        self, events: EventStore, notify_exchange: AbstractExchange, service_user: str, threshold: float
    ) -> None:
        self._events = events
        self._exchange = notify_exchange
        self._service_user = service_user
        self.threshold = threshold

    async def _was_low_before(self, item: Accepted) -> bool:
        previous = await self._events.find_events(
            EventQuery(
                type=EventType.STATUS.value,
                robot_id=item.event.robot_id,
                until=item.event.sent_at,
                newest_first=True,
                limit=1,
            )
        )
        return bool(previous) and battery_low(previous[0].body[BATTERY_FIELD], self.threshold)

    async def handle(self, accepted: Sequence[Accepted]) -> int:
        sent = 0
        for item in accepted:
            event = item.event
            if event.type is not EventType.STATUS:
                continue
            if not battery_low(event.body.battery_percent, self.threshold):
                continue
            if await self._was_low_before(item):
                continue
            note = Notification(
                topic=Topic.BATTERY,
                event=event,
                received_at=item.record.received_at,
                notified_at=datetime.now(timezone.utc),
            )
            await publish_notification(self._exchange, note, self._service_user)
            sent += 1
        return sent
