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

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

from fleetbus.broker.uplink import CLASSES, DROP_OLDEST, REFUSE, UplinkBounds
from fleetbus.limits import QueueLimit
from fleetbus.schemas.routing import (
    BEACON_DISCARD_QUEUE,
    DEAD_LETTER_QUEUE,
    DOWNLINK_REJECTED_QUEUE,
    EXPRESS_QUEUE,
    HAZARD_UPLINK_QUEUE,
    OVERFLOW_EXCHANGE,
    OVERFLOW_QUEUE,
    POISON_EXCHANGE,
    RECORDER_QUEUE,
    RPC_QUEUE,
    SITE_HAZARDS_QUEUE,
    SITE_REPORTS_QUEUE,
    UPLINK_QUEUE,
)

if TYPE_CHECKING:  # every process that loads the settings imports this module: httpx is 6 MB
    from fleetbus.broker.management import ManagementAPI

#: Above 0, RabbitMQ's default, so that a catch-all policy of the operator's does not hide these.
PRIORITY = 10
#: Every account's inbox (account names: :data:`fleetbus.schemas.identity.NAME_PATTERN`).
INBOX_PATTERN = r"^[a-z][a-z0-9_-]{1,31}\.inbox$"
#: Each site's downlink queues at central (a site's name is an account's: none starts ``fleetbus``,
#: so a site's own ``fleetbus.downlink`` is not matched).
SITE_DOWNLINK_PATTERN = r"^(?!fleetbus)[a-z][a-z0-9_-]{1,31}\.downlink$"
SITE_MAPS_PATTERN = r"^(?!fleetbus)[a-z][a-z0-9_-]{1,31}\.downlink\.maps$"
#: Every robot's commands queue.
COMMANDS_PATTERN = r"^[a-z][a-z0-9_-]{1,31}\.commands$"
#: Deliveries of one message after which a queue the workers consume sets it aside: the ingest
#: shards' argument, and the other queues' policy (:func:`delivery_policies`).
WORKER_DELIVERY_LIMIT = 50
#: A command lives 30 s (``COMMAND_TTL_MS``): taken this often in that time and never acknowledged,
#: it is one its robot cannot handle.
COMMAND_DELIVERY_LIMIT = 10


@dataclass(frozen=True)
class QueuePolicy:
    name: str
    pattern: str
    definition: dict[str, Any]
    apply_to: str = "queues"


def _exactly(queue: str) -> str:
    return "^" + queue.replace(".", r"\.") + "$"


def _bounded(limit: QueueLimit) -> dict[str, Any]:
    definition: dict[str, Any] = {"overflow": "drop-head", "dead-letter-exchange": OVERFLOW_EXCHANGE}
    if limit.messages is not None:
        definition["max-length"] = limit.messages
    if limit.bytes is not None:
        definition["max-length-bytes"] = limit.bytes
    return definition


def _major(version: str) -> int:
    head = version.split(".", 1)[0]
    return int(head) if head.isdigit() else 0


def _per_type(
    name: str, pattern: str, common: dict[str, Any], quorum: dict[str, Any], version: str, cluster: bool
) -> list[QueuePolicy]:
    """``common`` for the queues ``pattern`` matches, and ``quorum`` besides for the quorum ones.

    RabbitMQ does not apply a policy to a queue whose type ignores one of its keys (a classic
    queue, ``delivery-limit``): it would leave a classic inbox unbounded. So on 4.x the classic and
    the quorum queues get a policy each (``apply-to``); RabbitMQ 3 knows no ``apply-to`` by queue
    type, so there the policy is the one for the type the queues are (``cluster``: quorum)."""
    if _major(version) < 4:
        return [QueuePolicy(name, pattern, {**common, **quorum} if cluster else common)]
    return [
        QueuePolicy(name, pattern, common, apply_to="classic_queues"),
        QueuePolicy(f"{name}-quorum", pattern, {**common, **quorum}, apply_to="quorum_queues"),
    ]


def unlimited_deliveries(version: str) -> dict[str, Any]:
    """The policy key that lets a quorum queue redeliver a message any number of times: RabbitMQ 4
    limits every quorum queue to 20 deliveries unless told ``-1``; RabbitMQ 3 has no limit unless
    given one, and refuses ``-1`` in a policy (as a queue argument it takes it as 0)."""
    return {"delivery-limit": -1} if _major(version) >= 4 else {}


def bound_policies(
    inbox: QueueLimit, dead_letters: QueueLimit, version: str, cluster: bool = False
) -> list[QueuePolicy]:
    """The inboxes and the dead-letter queue (of RabbitMQ ``version``): bounded, and (quorum queues,
    on a cluster) never a drop for how often a message was delivered. A robot whose link drops
    while it holds a notification gets it again however often that happens; ``fleetbus dlq`` reads
    the dead letters and puts them back, which counts as a delivery each time."""
    unlimited = unlimited_deliveries(version)
    return [
        *_per_type("fleetbus-inboxes", INBOX_PATTERN, _bounded(inbox), unlimited, version, cluster),
        *_per_type(
            "fleetbus-dead-letters",
            _exactly(DEAD_LETTER_QUEUE),
            _bounded(dead_letters),
            unlimited,
            version,
            cluster,
        ),
    ]


def central_policies(
    site_reports: QueueLimit, site_downlink: QueueLimit, site_maps: QueueLimit
) -> list[QueuePolicy]:
    """Central's queues of the sites, each dropping (and counting) its oldest when full. The
    reports wait in ``fleetbus.site-reports`` until someone reads them (a dashboard, ``fleetbus
    sites``, the API's alerts): central keeps each site's newest. A site away fills its
    ``<site>.downlink.maps`` with every map version central stores, and needs only the newest.
    Its ``<site>.downlink`` (accounts, removals, missions) gets a large bound: a drop there is
    alerted on, and ``fleetbus sites sync`` sends them again (refusing instead would hold every
    site's missions in the API behind one site that never comes back). Set on a site too, where
    no queue matches (its own ``fleetbus.downlink`` is not a site's: no name starts ``fleetbus``)."""
    return [
        QueuePolicy("fleetbus-site-reports", _exactly(SITE_REPORTS_QUEUE), _bounded(site_reports)),
        QueuePolicy("fleetbus-site-downlink", SITE_DOWNLINK_PATTERN, _bounded(site_downlink)),
        QueuePolicy("fleetbus-site-maps", SITE_MAPS_PATTERN, _bounded(site_maps)),
    ]


def delivery_policies(version: str, cluster: bool = False) -> list[QueuePolicy]:
    """Every other quorum queue's delivery limit (they are quorum queues on a cluster; a classic
    queue has none: the workers keep the express lane's themselves, :mod:`fleetbus.workers.attempts`).

    The queues the workers consume set a message aside once delivered :data:`WORKER_DELIVERY_LIMIT`
    times, as the ingest shards do (their limit is a queue argument): each time the worker, or its
    connection, died while it held that message. It goes to the dead letters (the express lane and
    the sites' hazards by their dead-letter exchange, the rest by ``fleetbus.poison``), where
    ``fleetbus dlq`` shows it with the reason ``delivery_limit``. A command that its robot took
    :data:`COMMAND_DELIVERY_LIMIT` times without acknowledging it goes there too. A command or a
    service request that expired unread (its robot away, the workers behind) is counted with the
    dropped messages (``<queue> expired``): ``fleetbus.poison`` passes it to ``fleetbus.overflow``,
    on a classic queue too. What its limit removes from the recorder's backlog is counted with the
    dropped messages (the recorder's own dead-letter exchange). The overflow queue never drops for
    deliveries: its counter reads no body, so no message can be poison to it."""
    limit = {"delivery-limit": WORKER_DELIVERY_LIMIT}
    poison = {"dead-letter-exchange": POISON_EXCHANGE}
    quorum_only = "quorum_queues" if _major(version) >= 4 else "queues"
    policies = [
        QueuePolicy("fleetbus-express", _exactly(EXPRESS_QUEUE), limit),
        QueuePolicy("fleetbus-beacon-discards", _exactly(BEACON_DISCARD_QUEUE), {**limit, **poison}),
        QueuePolicy("fleetbus-site-hazards", _exactly(SITE_HAZARDS_QUEUE), limit),
        QueuePolicy("fleetbus-recorder", _exactly(RECORDER_QUEUE), limit),
        QueuePolicy("fleetbus-overflow", _exactly(OVERFLOW_QUEUE), unlimited_deliveries(version)),
    ]
    return [
        *(replace(policy, apply_to=quorum_only) for policy in policies if policy.definition),
        # what expires in them is counted whatever their type: a policy for each type on RabbitMQ 4
        *_per_type("fleetbus-requests", _exactly(RPC_QUEUE), poison, limit, version, cluster),
        *_per_type(
            "fleetbus-commands",
            COMMANDS_PATTERN,
            poison,
            {"delivery-limit": COMMAND_DELIVERY_LIMIT},
            version,
            cluster,
        ),
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


def downlink_rejected_policy(limit: int) -> QueuePolicy:
    """A site's ``fleetbus.downlink.rejected``: what ``fleetbus site apply`` could not apply, kept
    for a look. A refused removal comes again with each ``fleetbus sites sync`` while its robot is
    mounted, so the queue keeps the newest ``limit`` and drops (and counts) the oldest."""
    return QueuePolicy(
        "fleetbus-downlink-rejected", _exactly(DOWNLINK_REJECTED_QUEUE), _bounded(QueueLimit(limit))
    )


def apply_policies(api: ManagementAPI, vhost: str, policies: list[QueuePolicy]) -> None:
    """Set (or change) each policy; idempotent."""
    for policy in policies:
        api.put_policy(vhost, policy.name, policy.pattern, policy.definition, PRIORITY, policy.apply_to)
