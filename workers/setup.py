"""The administrator's step before the worker and the recorder run with their own accounts alone.

``fleetbus setup`` (and ``fleetbus broker up``) run it once per broker and virtual host; it is
idempotent, so running it again changes nothing that is in place. It makes the ``fleetbus`` and
``fleetbus-recorder`` accounts (their passwords kept in ``$FLEETBUS_DATA_DIR/accounts/``, mode
0600), the service's exchanges and queues for ``FLEETBUS_INGEST_SHARDS`` shards, and the
recorder's queue with its bindings, which ``fleetbus-recorder`` may read but not declare, and its
dead-letter policy. It brings up to date what an earlier version made: an express queue without a
dead-letter exchange (replaced while empty), robots' beacon exchanges of the headers kind.
"""

from __future__ import annotations

import asyncio
import logging
from dataclasses import dataclass

import aio_pika

from broker.accounts import upgrade_beacon_exchanges, vhost_of
from broker.endpoint import BrokerEndpoint
from broker.management import ManagementAPI
from broker.topology import (
    EXPRESS_QUEUE_ARGUMENTS,
    RECORDER_POLICY,
    PolicySpec,
    core_topology,
    declare_with_url,
    recorder_topology,
)
from fleetbus.config import Settings
from schemas.routing import EXPRESS_QUEUE
from workers.recorder.runner import recorder_url
from workers.runner import service_url

log = logging.getLogger("fleetbus.setup")


@dataclass(frozen=True)
class ServiceAccounts:
    service_url: str
    """The workers' account, ``fleetbus``: confined to ``fleetbus.*``."""
    recorder_url: str
    """The recorder's, ``fleetbus-recorder``: reads its one queue, nothing else."""


async def set_up_service(settings: Settings, admin: BrokerEndpoint) -> ServiceAccounts:
    """As the administrator of ``admin``: the service accounts, the topology and the bindings."""
    service = await asyncio.to_thread(service_url, settings, admin)
    recorder = await asyncio.to_thread(recorder_url, settings, admin)
    await replace_outdated_express_queue(admin)
    await asyncio.to_thread(put_policies, admin, [RECORDER_POLICY])
    await declare_with_url(admin.amqp_url, [core_topology(settings.ingest_shards), recorder_topology()])
    with ManagementAPI.from_urls(admin.management_url, admin.amqp_url) as api:
        upgraded = await upgrade_beacon_exchanges(admin.amqp_url, api)
    if upgraded:
        log.info("beacon exchanges now keyed by their robot's name: %s", ", ".join(upgraded))
    return ServiceAccounts(service, recorder)


def put_policies(admin: BrokerEndpoint, policies: list[PolicySpec]) -> None:
    with ManagementAPI.from_urls(admin.management_url, admin.amqp_url) as api:
        vhost = vhost_of(admin.amqp_url)
        for policy in policies:
            api.put_policy(vhost, policy.name, policy.pattern, policy.definition, policy.priority)


class OutdatedQueue(Exception):
    """A queue declared by an older version, with other arguments, still holds messages."""


async def replace_outdated_express_queue(admin: BrokerEndpoint) -> None:
    """The express queue of a version before the broker dead-lettered (no dead-letter exchange):
    deleted when empty, so that it is declared again with its arguments; RabbitMQ refuses to
    declare a queue again with arguments that differ."""
    with ManagementAPI.from_urls(admin.management_url, admin.amqp_url) as api:
        vhost = vhost_of(admin.amqp_url)
        found = [q for q in api.list_queues(vhost) if q.get("name") == EXPRESS_QUEUE]
    if not found or all(
        found[0].get("arguments", {}).get(k) == v for k, v in EXPRESS_QUEUE_ARGUMENTS.items()
    ):
        return
    connection = await aio_pika.connect(admin.amqp_url)
    async with connection:
        channel = await connection.channel()
        queue = await channel.declare_queue(EXPRESS_QUEUE, passive=True)
        held = queue.declaration_result.message_count
        if held:
            raise OutdatedQueue(
                f"{EXPRESS_QUEUE} was declared by an older fleetbus and holds {held} messages: let the "
                "older worker drain it, then run `fleetbus setup` again"
            )
        await queue.delete(if_unused=False, if_empty=True)
