"""The bus topology as code: what exists, declared idempotently with aio-pika.

:func:`core_topology` is the service's part (ingest, notifications, dead letters);
:func:`account_topology` is what one user or robot owns. Both are plain data, so the worker,
the provisioning commands and the tests declare exactly the same arguments (RabbitMQ refuses a
re-declaration whose arguments differ).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import aio_pika
from aio_pika.abc import AbstractChannel, ExchangeType

from fleetbus.broker.account_roles import Role
from fleetbus.broker.policies import WORKER_DELIVERY_LIMIT
from fleetbus.broker.tls import aio_connect
from fleetbus.schemas.routing import (
    ALL_TOPICS_BINDING,
    BEACON_CHECK_EXCHANGE,
    BEACON_DISCARD_EXCHANGE,
    BEACON_DISCARD_QUEUE,
    BEACON_EXCHANGE,
    BEACON_MATCH,
    DEAD_LETTER_EXCHANGE,
    DEAD_LETTER_QUEUE,
    DELIVERED_BY_NAME,
    EXPRESS_QUEUE,
    EXPRESS_TYPES,
    INGEST_EXCHANGE,
    INGEST_QUEUE,
    NOTIFY_EXCHANGE,
    OVERFLOW_EXCHANGE,
    OVERFLOW_QUEUE,
    POISON_EXCHANGE,
    RECORDED_EXCHANGES,
    RECORDER_DEAD_LETTER_EXCHANGE,
    RECORDER_QUEUE,
    RPC_EXCHANGE,
    RPC_QUEUE,
    SHARD_EXCHANGE,
    SUBSCRIPTIONS,
    UNASSIGNED_EXCHANGE,
    RobotKind,
    beacon_exchange,
    commands_exchange,
    commands_queue,
    events_exchange,
    express_binding_key,
    inbox_queue,
    ingest_shard_queue,
    notification_routing_key,
    requests_exchange,
    stream_queue,
)

#: A robot's or operator's inbox: a classic durable queue. On one node it keeps every persistent
#: message across a SIGKILL and cannot come back without a leader as a quorum queue can
#: (rabbitmq-server #10070), and it hands a notification to its robot about 1 ms sooner (no Raft
#: commit first). The ingest queue, which carries everything, stays a quorum queue. On a cluster
#: the inbox is a quorum queue too (:func:`replicated`).
INBOX_ARGUMENTS: dict[str, Any] = {"x-queue-type": "classic"}

#: A message redelivered this many times (the worker died on it each time) is dead-lettered
#: by the broker itself, so one poison message cannot stop the ingest forever.
INGEST_DELIVERY_LIMIT = WORKER_DELIVERY_LIMIT

#: A command older than this is dropped by the broker: a robot must not act on a stale order.
COMMAND_TTL_MS = 30_000

#: An operator's stream keeps a day of history, at most 200 MB, for ``fleetbus tail --since``.
STREAM_ARGUMENTS = {
    "x-queue-type": "stream",
    "x-max-age": "1D",
    "x-max-length-bytes": 200_000_000,
    "x-stream-max-segment-size-bytes": 10_000_000,
}


@dataclass(frozen=True)
class ExchangeSpec:
    name: str
    type: ExchangeType
    arguments: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class QueueSpec:
    name: str
    arguments: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class BindingSpec:
    source: str
    destination: str
    routing_key: str
    to_exchange: bool = False
    arguments: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Topology:
    exchanges: Sequence[ExchangeSpec] = ()
    queues: Sequence[QueueSpec] = ()
    bindings: Sequence[BindingSpec] = ()


#: The arguments of every ingest shard's queue (shard 0 is the ingest queue of a single worker).
INGEST_QUEUE_ARGUMENTS: dict[str, Any] = {
    "x-queue-type": "quorum",
    # One active consumer at a time keeps per-robot order, whichever worker holds the shard.
    "x-single-active-consumer": True,
    "x-delivery-limit": INGEST_DELIVERY_LIMIT,
    "x-dead-letter-exchange": DEAD_LETTER_EXCHANGE,
}


#: What full queues dropped, until the workers count it: itself bounded, the last stop (no
#: dead-letter exchange), so a long absence of the workers loses counts, never robots' data.
OVERFLOW_QUEUE_ARGUMENTS: dict[str, Any] = {
    "x-queue-type": "classic",
    "x-max-length": 100_000,
    "x-max-length-bytes": 256 * 1024**2,
    "x-overflow": "drop-head",
}


#: The express lane's queue. Classic: it hands a hazard to the worker about 0.5 ms sooner than a
#: quorum queue (no Raft commit first) and keeps every persistent message across a SIGKILL on one
#: node. A classic queue has no delivery limit, so the worker keeps one (:mod:`fleetbus.workers.attempts`).
#: Its dead-letter exchange takes what the worker rejects (``basic.nack``), as the shards' do.
#: On a cluster it is a quorum queue instead (:func:`replicated`), like every queue that holds data.
EXPRESS_QUEUE_ARGUMENTS: dict[str, Any] = {
    "x-queue-type": "classic",
    "x-single-active-consumer": True,
    "x-dead-letter-exchange": DEAD_LETTER_EXCHANGE,
}


#: What fleetbus.poison passes on to the dead letters: a message a delivery limit removed
#: (:func:`fleetbus.broker.policies.delivery_policies`).
POISONED = {"x-match": "all-with-x", "x-first-death-reason": "delivery_limit"}
#: What it passes on to be counted with the dropped messages: a command or request that expired.
EXPIRED = {"x-match": "all-with-x", "x-first-death-reason": "expired"}


def queue_type(cluster: bool) -> dict[str, Any]:
    """The type of every queue that must not lose or reorder what it holds: classic on one node
    (for the reasons given where each is declared), quorum on a cluster, where a classic queue
    lives on one node and is gone while that node is (docs/operations/cluster.md)."""
    return {"x-queue-type": "quorum" if cluster else "classic"}


def replicated(arguments: dict[str, Any], cluster: bool) -> dict[str, Any]:
    """``arguments`` with the queue type :func:`queue_type` gives."""
    return {**arguments, **queue_type(cluster)}


def core_topology(shards: int = 1, *, cluster: bool = False) -> Topology:
    """The service's exchanges and queues, with ``shards`` ingest shard queues.

    Robots' events reach ``fleetbus.ingest.shards``, which routes every robot's hazards and
    localisations to the express queue, and each robot's other types to its one shard (bound by
    its name, :mod:`fleetbus.broker.shards`); a message neither matches goes to shard 0 by the exchange's
    alternate exchange, so nothing is ever routed to no queue. On a ``cluster`` every queue is a
    quorum queue (:func:`queue_type`).
    """
    if shards < 1:
        raise ValueError(f"the ingest needs at least one shard, not {shards}")
    return Topology(
        exchanges=(
            ExchangeSpec(INGEST_EXCHANGE, ExchangeType.TOPIC),
            ExchangeSpec(SHARD_EXCHANGE, ExchangeType.TOPIC, {"alternate-exchange": UNASSIGNED_EXCHANGE}),
            ExchangeSpec(UNASSIGNED_EXCHANGE, ExchangeType.FANOUT),
            ExchangeSpec(NOTIFY_EXCHANGE, ExchangeType.TOPIC),
            ExchangeSpec(RPC_EXCHANGE, ExchangeType.TOPIC),
            ExchangeSpec(DEAD_LETTER_EXCHANGE, ExchangeType.FANOUT),
            ExchangeSpec(BEACON_EXCHANGE, ExchangeType.TOPIC),
            ExchangeSpec(BEACON_DISCARD_EXCHANGE, ExchangeType.FANOUT),
            ExchangeSpec(
                BEACON_CHECK_EXCHANGE, ExchangeType.HEADERS, {"alternate-exchange": BEACON_DISCARD_EXCHANGE}
            ),
            ExchangeSpec(OVERFLOW_EXCHANGE, ExchangeType.FANOUT),
            ExchangeSpec(POISON_EXCHANGE, ExchangeType.HEADERS),
        ),
        queues=(
            *(QueueSpec(ingest_shard_queue(shard), INGEST_QUEUE_ARGUMENTS) for shard in range(shards)),
            QueueSpec(EXPRESS_QUEUE, replicated(EXPRESS_QUEUE_ARGUMENTS, cluster)),
            # Classic, not quorum: listing it (`fleetbus dlq`) gets and requeues messages, and a
            # quorum queue would count each listing as a delivery.
            QueueSpec(DEAD_LETTER_QUEUE, queue_type(cluster)),
            # Requests are worth nothing once their caller gave up (each carries an expiration).
            QueueSpec(RPC_QUEUE, queue_type(cluster)),
            # Drained into the store's discard log by the workers, which is where they are counted.
            QueueSpec(BEACON_DISCARD_QUEUE, queue_type(cluster)),
            # What full queues dropped (broker/policies.py), drained into the store's counts.
            QueueSpec(OVERFLOW_QUEUE, replicated(OVERFLOW_QUEUE_ARGUMENTS, cluster)),
        ),
        bindings=(
            BindingSpec(INGEST_EXCHANGE, SHARD_EXCHANGE, "#", to_exchange=True),
            *(BindingSpec(SHARD_EXCHANGE, EXPRESS_QUEUE, express_binding_key(t)) for t in EXPRESS_TYPES),
            BindingSpec(UNASSIGNED_EXCHANGE, INGEST_QUEUE, ""),
            BindingSpec(RPC_EXCHANGE, RPC_QUEUE, "#"),
            BindingSpec(DEAD_LETTER_EXCHANGE, DEAD_LETTER_QUEUE, ""),
            BindingSpec(BEACON_EXCHANGE, INGEST_EXCHANGE, "#", to_exchange=True),
            BindingSpec(BEACON_CHECK_EXCHANGE, BEACON_EXCHANGE, "", to_exchange=True, arguments=BEACON_MATCH),
            BindingSpec(BEACON_DISCARD_EXCHANGE, BEACON_DISCARD_QUEUE, ""),
            BindingSpec(OVERFLOW_EXCHANGE, OVERFLOW_QUEUE, ""),
            BindingSpec(POISON_EXCHANGE, DEAD_LETTER_EXCHANGE, "", to_exchange=True, arguments=POISONED),
            BindingSpec(POISON_EXCHANGE, OVERFLOW_EXCHANGE, "", to_exchange=True, arguments=EXPIRED),
        ),
    )


#: The recorder's backlog while it is not consuming: beyond this the oldest messages are dropped,
#: so a recorder that is gone can never stop the robots; they are dead-lettered to be counted.
RECORDER_BACKLOG_BYTES = 1024**3

#: What the recorder rejected itself (a message it cannot store even raw) goes to the dead-letter
#: queue, with its body, where `fleetbus dlq` shows it; anything else its queue dead-letters (the
#: oldest messages of a full backlog) goes on, by the exchange's alternate, to be counted.
RECORDER_UNSTORABLE = {
    "x-match": "all-with-x",  # compares x- headers too (RabbitMQ 3.10 and later)
    "x-first-death-queue": RECORDER_QUEUE,
    "x-first-death-reason": "rejected",
}


def recorder_topology(*, cluster: bool = False) -> Topology:
    """The recorder's queue, bound to every exchange of the service with ``#``.

    Bound rather than fed by RabbitMQ's firehose: the copies are persistent and covered by the
    robots' publisher confirms, the bindings survive a broker restart (the firehose does not),
    and reading it takes no permission beyond this one queue (README, "The recorder"). Its own
    dead-letter exchange, not fleetbus.dlx, which the recorder records: a message the recorder
    cannot store must never come back to it.
    """
    return Topology(
        exchanges=(
            ExchangeSpec(
                RECORDER_DEAD_LETTER_EXCHANGE, ExchangeType.HEADERS, {"alternate-exchange": OVERFLOW_EXCHANGE}
            ),
        ),
        queues=(
            QueueSpec(
                RECORDER_QUEUE,
                {
                    **queue_type(cluster),
                    "x-single-active-consumer": True,
                    "x-max-length-bytes": RECORDER_BACKLOG_BYTES,
                    "x-dead-letter-exchange": RECORDER_DEAD_LETTER_EXCHANGE,
                },
            ),
        ),
        bindings=(
            *(BindingSpec(exchange, RECORDER_QUEUE, "#") for exchange in RECORDED_EXCHANGES),
            BindingSpec(RECORDER_DEAD_LETTER_EXCHANGE, DEAD_LETTER_QUEUE, "", arguments=RECORDER_UNSTORABLE),
        ),
    )


def inbox_bindings(owner: str, kind: RobotKind | None, operator: bool) -> list[str]:
    if operator:
        return [ALL_TOPICS_BINDING]
    if kind is None:
        return []
    return [
        notification_routing_key(topic) for topic in SUBSCRIPTIONS[kind] if topic not in DELIVERED_BY_NAME
    ]


def account_topology(
    owner: str, role: Role = Role.ROBOT, *, kind: RobotKind | None = None, cluster: bool = False
) -> Topology:
    """What an account owns: its exchanges (bound into the ingest and the service requests), its
    inbox, and by role a robot's beacon exchange and commands queue, or an operator's commands
    exchange and stream. Mount bindings are not here: the service makes them while it runs."""
    exchange = events_exchange(owner)
    requests = requests_exchange(owner)
    inbox = inbox_queue(owner)
    operator = role is Role.OPERATOR
    exchanges = [ExchangeSpec(exchange, ExchangeType.TOPIC), ExchangeSpec(requests, ExchangeType.TOPIC)]
    queues = [QueueSpec(inbox, replicated(INBOX_ARGUMENTS, cluster))]
    bindings = [
        BindingSpec(exchange, INGEST_EXCHANGE, "#", to_exchange=True),
        BindingSpec(requests, RPC_EXCHANGE, "#", to_exchange=True),
        *(BindingSpec(NOTIFY_EXCHANGE, inbox, key) for key in inbox_bindings(owner, kind, operator)),
    ]
    if role is Role.ROBOT:
        # a topic exchange, so that topic permissions hold its keys to <robot>.*: a robot cannot send
        # a beacon into another robot's lane (a headers exchange's keys are not checked)
        beacons = beacon_exchange(owner)
        exchanges.append(ExchangeSpec(beacons, ExchangeType.TOPIC))
        bindings.append(BindingSpec(beacons, BEACON_CHECK_EXCHANGE, "#", to_exchange=True))
        queues.append(
            QueueSpec(commands_queue(owner), {**queue_type(cluster), "x-message-ttl": COMMAND_TTL_MS})
        )
    if operator:
        exchanges.append(ExchangeSpec(commands_exchange(owner), ExchangeType.TOPIC))
        queues.append(QueueSpec(stream_queue(owner), STREAM_ARGUMENTS))
        bindings.append(BindingSpec(BEACON_EXCHANGE, stream_queue(owner), "#"))
    return Topology(exchanges=tuple(exchanges), queues=tuple(queues), bindings=tuple(bindings))


async def declare(channel: AbstractChannel, topologies: Iterable[Topology]) -> None:
    """Declare every exchange, queue and binding; declaring what exists is a no-op."""
    topologies = list(topologies)
    exchanges: dict[str, aio_pika.abc.AbstractExchange] = {}
    queues: dict[str, aio_pika.abc.AbstractQueue] = {}
    for topology in topologies:
        for spec in topology.exchanges:
            exchanges[spec.name] = await channel.declare_exchange(
                spec.name, spec.type, durable=True, arguments=spec.arguments or None
            )
    for topology in topologies:
        for spec in topology.queues:
            queues[spec.name] = await channel.declare_queue(spec.name, durable=True, arguments=spec.arguments)
    for topology in topologies:
        for binding in topology.bindings:
            source = exchanges.get(binding.source) or await channel.get_exchange(binding.source)
            if binding.to_exchange:
                destination = exchanges.get(binding.destination) or await channel.get_exchange(
                    binding.destination
                )
                await destination.bind(
                    source, routing_key=binding.routing_key, arguments=binding.arguments or None
                )
            else:
                queue = queues.get(binding.destination) or await channel.get_queue(binding.destination)
                await queue.bind(source, routing_key=binding.routing_key, arguments=binding.arguments or None)


async def declare_with_url(amqp_url: str, topologies: Iterable[Topology]) -> None:
    connection = await aio_connect(amqp_url)
    async with connection:
        channel = await connection.channel()
        await declare(channel, topologies)
