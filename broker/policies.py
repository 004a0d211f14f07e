"""The queues' length bounds, as broker policies set by ``fleetbus setup``.

Policies rather than queue arguments: a queue's arguments cannot change once it exists (declaring
it again with others fails with ``PRECONDITION_FAILED``), so arguments would bound new queues
only and every limit change would need each queue deleted. A policy applies to the queues that
exist and to those made later, and changing a limit is running ``fleetbus setup`` again.

Each bound queue drops its oldest messages when full (``drop-head``), never refuses new ones:

- an inbox that refused a notification would nack the worker's publish, and the worker would
  retry it, holding up the ingest of every robot for one robot that is away; the robot's resync
  on reconnect (``hazard.open``, ``map.latest``) brings back what a warden needs;
- a dead-letter queue that refused would leave the worker unable to set a poison message aside,
  so it would hold that batch and stop the ingest; the newest refusals are the ones an operator
  looks into, and the recording keeps every dead letter as type ``dead_letter`` anyway.

What a full queue drops is dead-lettered to ``fleetbus.overflow``, whose queue the workers drain
into the store's counts (``fleetbus stats``, ``fleetbus dlq``): RabbitMQ counts no drops itself.
RabbitMQ applies one policy to a queue, the one of highest priority: a policy of the operator's
own that matches these queues must carry these keys too, or have a lower priority.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from fleetbus.broker.uplink import CLASSES, DROP_OLDEST, REFUSE, UplinkBounds
from fleetbus.schemas.routing import DEAD_LETTER_QUEUE, HAZARD_UPLINK_QUEUE, OVERFLOW_EXCHANGE, UPLINK_QUEUE

if TYPE_CHECKING:  # every process that loads the settings imports this module: httpx is 6 MB
    from fleetbus.broker.management import ManagementAPI

#: Above 0, RabbitMQ's default, so that a catch-all policy of the operator's does not hide these.
PRIORITY = 10
#: Every account's inbox (account names: :data:`fleetbus.schemas.identity.NAME_PATTERN`).
INBOX_PATTERN = r"^[a-z][a-z0-9_-]{1,31}\.inbox$"


@dataclass(frozen=True)
class QueueLimit:
    """A queue's length: the broker drops its oldest messages beyond either."""

    messages: int | None = None
    bytes: int | None = None

    def describe(self) -> str:
        parts = []
        if self.messages is not None:
            parts.append(f"{self.messages:,} messages")
        if self.bytes is not None:
            parts.append(f"{self.bytes / 1e9:g} GB" if self.bytes >= 1e9 else f"{self.bytes / 1e6:g} MB")
        return " or ".join(parts)


@dataclass(frozen=True)
class QueuePolicy:
    name: str
    pattern: str
    definition: dict[str, Any]


def _exactly(queue: str) -> str:
    return "^" + queue.replace(".", r"\.") + "$"


def _bounded(limit: QueueLimit) -> dict[str, Any]:
    definition: dict[str, Any] = {"overflow": "drop-head", "dead-letter-exchange": OVERFLOW_EXCHANGE}
    if limit.messages is not None:
        definition["max-length"] = limit.messages
    if limit.bytes is not None:
        definition["max-length-bytes"] = limit.bytes
    return definition


def bound_policies(inbox: QueueLimit, dead_letters: QueueLimit) -> list[QueuePolicy]:
    return [
        QueuePolicy("fleetbus-inboxes", INBOX_PATTERN, _bounded(inbox)),
        QueuePolicy("fleetbus-dead-letters", _exactly(DEAD_LETTER_QUEUE), _bounded(dead_letters)),
    ]


def uplink_policies(bounds: UplinkBounds) -> list[QueuePolicy]:
    """A site's uplink classes (:mod:`fleetbus.broker.uplink`) and hazard uplink
    (:mod:`fleetbus.broker.sites`), each with its own bound. Hazards, events and hazard states
    are never dropped: full means the broker refuses the publish (``reject-publish``, a nack), so
    the event stays in the robot's outbox, or the hazard's state unsent in the site's store, and
    is sent again, since central has not got it yet. Telemetry drops its oldest, counted like the
    other queues' drops."""
    policies = []
    for uplink in CLASSES:
        definition: dict[str, Any] = {"overflow": uplink.overflow, "max-length": bounds.of(uplink)}
        if uplink.overflow == DROP_OLDEST:
            definition["dead-letter-exchange"] = OVERFLOW_EXCHANGE
        else:
            definition["max-length-bytes"] = bounds.max_bytes
        name = "fleetbus-uplink" if uplink.queue == UPLINK_QUEUE else f"fleetbus-uplink-{uplink.name}"
        policies.append(QueuePolicy(name, _exactly(uplink.queue), definition))
    states = {"overflow": REFUSE, "max-length": bounds.events, "max-length-bytes": bounds.max_bytes}
    policies.append(QueuePolicy("fleetbus-hazard-uplink", _exactly(HAZARD_UPLINK_QUEUE), states))
    return policies


def apply_policies(api: ManagementAPI, vhost: str, policies: list[QueuePolicy]) -> None:
    """Set (or change) each policy; idempotent."""
    for policy in policies:
        api.put_policy(vhost, policy.name, policy.pattern, policy.definition, PRIORITY)
